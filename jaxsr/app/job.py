"""A recording opened, checked and matched with its model (`prepare_upscale`): the first half of `jaxsr upscale`,
everything that can fail before the network runs. The result, `UpscaleJob`, streams the network's output frame
by frame (`UpscaleJob.iter_frames`); `jaxsr.app.write_upscaled` writes it.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
from typing import Callable, Iterator

import numpy as np

from ..config import TRAINED_RANGE_M, DepthScale, Gate, Optics, Sensor
from ..inference import (DEFAULT_PRECISION, QuietFrame, filled_where_holes, iter_ambient_only, iter_network_inputs,
                         iter_quiet, iter_returns_kept, iter_super_resolve, lr_blocks, no_return_where,
                         overrule_no_return)
from ..inference.confidence import (EVIDENCE_FRAMES, NO_RETURN_AT, ConfidenceCoefficients, coefficients_for,
                                    confidence_frame, iter_count_windows, no_return_by_probability)
from ..nn.model import Model
from ..runtime import enable_compilation_cache
from ..sensor.gates import data_span, gate_depth, gate_warnings
from ..sensor.peaks import HOLE_PIXELS, QUIET_POOLS
from ..sensor.timetags import TIME_TAG_FORMATS, TimeTags, gate_of_tags, read_time_tags, time_tag_warnings
from .memory import HISTOGRAM_CHUNK, check_result_memory
from .models import DEPTH_ENSEMBLE, finish_model, has_head, plan_model, trained_snr_range
from .photons import (AMBIENT_FRAMES, HEAD_FRAMES, PhotonDecision, decide_photon_rules, few_photons_warnings,
                      photon_levels, rule_warnings, snr_warnings)
from .recordings import (Recording, check_frames, clipped_recording, guess_units, normalised_frames,
                         open_recording, time_tag_recording, to_units)
from .specs import ModelChoice, PhotonRules, Reading, is_auto

__all__ = ["UpscaleJob", "prepare_upscale", "no_return_interior", "ensemble_depth", "HISTOGRAM_CHUNK"]



@dataclasses.dataclass(frozen=True)
class UpscaleJob:
    """A recording checked and ready to super-resolve (`prepare_upscale`): every frame checked, the model chosen.

    recording: the opened `jaxsr.app.recordings.Recording` (kind "depth" or "histograms", time tags already
    histogrammed); model: the `Model`, in the temporal form it runs in; model_id: its name, which --model takes
    back (tr4, the path given; "model" for a `Model` given loaded); model_name: the model as people read it
    (tr4, a path, "tr1 (auto: motion ...)", with the photon rules that apply); label: its name for pictures
    (without the rules' words, which would not fit a panel); units: of the input depth and of array outputs
    (`jaxsr.app.recordings.DEPTH_UNITS`); gate: the histogram gate (None for depth); scale: the `DepthScale`
    between metres and the network's [0, 1]; warnings: sentences on what the bundled models never saw in this
    gate and scale, and on negative counts clipped; source: the input as named in messages and metadata;
    negative_counts: with `Reading.clip_negative`, (negative counts clipped at 0, pixels holding one), else None;
    precision: how the network's convolutions multiply; photons: the `PhotonDecision` (ambient-only test and
    keep rule) that applies; ensemble_model: the second network whose depth is averaged with the model's on the
    returns (`jaxsr.app.DEPTH_ENSEMBLE`), None where the model runs alone."""

    recording: Recording
    model: Model
    model_name: str
    label: str
    units: str
    gate: Gate | None
    scale: DepthScale
    warnings: tuple[str, ...]
    source: str
    precision: str = DEFAULT_PRECISION
    negative_counts: tuple[int, int] | None = None
    photons: PhotonDecision = PhotonDecision(None, "", None)
    model_id: str = ""
    input_path: str | None = None  # the input where it was given as a path (never written over)
    ensemble_model: Model | None = None
    # fresh streams of the network's input, and of the photon tests' flags per frame ((h, w) bool; the keep rule's
    # a QuietFrame) (None: no test)
    _lr_stream: Callable[[], Iterator[np.ndarray]] = dataclasses.field(default=None, repr=False, compare=False)
    _ambient_stream: Callable[[], Iterator[np.ndarray]] | None = dataclasses.field(default=None, repr=False,
                                                                                   compare=False)
    _keep_stream: Callable[[], Iterator[QuietFrame]] | None = dataclasses.field(default=None, repr=False,
                                                                               compare=False)
    # a fresh stream of the ensemble model's input (None: no ensemble model)
    _ensemble_lr_stream: Callable[[], Iterator[np.ndarray]] | None = dataclasses.field(default=None, repr=False,
                                                                                    compare=False)
    # a fresh stream of the recording's (h, w, K) histogram frames (None: depth frames, no confidence)
    _count_stream: Callable[[], Iterator[np.ndarray]] | None = dataclasses.field(default=None, repr=False,
                                                                                 compare=False)
    confidence_coefficients: ConfidenceCoefficients | None = dataclasses.field(default=None, repr=False)

    @property
    def frames(self) -> int:
        """Frames in the recording, T."""
        return self.recording.frames

    @property
    def scale_factor(self) -> int:
        """The model's upscaling factor r."""
        return int(self.model.architecture.scale(self.model.config))

    @property
    def hr_shape(self) -> tuple[int, int]:
        """(H, W) of an output frame: the LR frame times the model's scale."""
        r = self.scale_factor
        return (int(self.recording.shape[0]) * r, int(self.recording.shape[1]) * r)

    @property
    def ambient_alpha(self) -> float | None:
        """The ambient-only test's false-alarm rate (None: no test)."""
        return self.photons.ambient_alpha

    @property
    def keep_returns(self) -> float | None:
        """The keep rule's false-alarm rate (None: the model's own decision)."""
        return self.photons.keep_returns

    @property
    def note(self) -> str:
        """One line for people: what is read and with which model (`jaxsr upscale` prints it before the work)."""
        return (f"{self.frames} frames {self.recording.kind} {tuple(self.recording.shape)} from {self.source}, "
                f"input units {self.units}, model {self.model_name}{self.how}")

    @property
    def how(self) -> str:
        """How the network runs, as `note` ends: ", sequence form" where it runs in it, and ", precision bfloat16"
        (or float32) where it is not the default; "" otherwise."""
        return (", sequence form" if self.model.sequence_form else "") + (
            "" if self.precision == "default" else f", precision {self.precision}")

    @property
    def fps(self) -> float | None:
        """The recording's frames per second where its file says (an .npz from `jaxsr simulate`), else None."""
        return self.recording.fps

    @property
    def d_range(self) -> tuple[float, float]:
        """(first, last) metres of the sensor's true range that the network's [0, 1] covers: the depth scale's
        offset (the gate's start) and offset + span. Every picture, video and point cloud is drawn over it."""
        return float(self.scale.offset), float(self.scale.offset + self.scale.span)

    def depth_range(self, frames: int = HEAD_FRAMES) -> tuple[float, float]:
        """(first, last) metres of the depth the recording's first `frames` frames show (their returns' 1st and
        99th percentiles of the LR input, widened to whole metres and kept inside `d_range`): the colour scale of
        pictures where none is given. `d_range` where no return is seen."""
        head = [f[..., 0] if f.ndim == 3 else f for f in itertools.islice(self.lr_frames(), frames)]
        normalised = np.stack(head)
        returns = normalised[normalised < 1.0]
        if returns.size == 0:
            return self.d_range
        lo, hi = (float(v) for v in to_units(np.percentile(returns, [1, 99]).astype(np.float32), "m", self.scale))
        first, last = self.d_range
        lo, hi = max(first, np.floor(lo)), min(last, np.ceil(hi))
        return (lo, hi) if hi > lo else self.d_range

    def lr_frames(self) -> Iterator[np.ndarray]:
        """A fresh stream of the network's input: (h, w) float32 LR normalised depth frames, one per frame
        ((h, w, C) for a model reading photons too: depth in channel 0, `jaxsr.nn.network_inputs`)."""
        return self._lr_stream()

    @property
    def has_confidence(self) -> bool:
        """True where the output comes with a confidence and a depth std (photon histograms and time tags)."""
        return self._count_stream is not None and self.confidence_coefficients is not None

    def iter_outputs(self, *, batch_size: int | None = None, lr_frames=None):
        """The network's output with its confidence, streamed: (depth, confidence, depth_std) per frame, each (H,
        W) float32: the HR normalised depth (unclipped) with the photon rules applied, P(return) in [0, 1] and the
        depth's standard deviation in metres (NaN where no return is output); confidence and depth_std None for
        depth frames (`has_confidence`). lr_frames: the LR stream to run (default `lr_frames()`)."""
        if not self.has_confidence:
            yield from ((hr, None, None) for hr in self.iter_normalised(batch_size=batch_size, lr_frames=lr_frames))
            return
        lr = self.lr_frames() if lr_frames is None else lr_frames
        head = self.model.has_no_return_head
        raw = iter_super_resolve(self.model, lr, batch_size=batch_size, precision=self.precision, raw=head)
        quiet = self._keep_stream() if self._keep_stream is not None else None
        ambient = self._ambient_stream() if self._ambient_stream is not None else None
        sensor = Sensor(gate=Gate.spanning(TRAINED_RANGE_M, self.gate.bins))  # its bins: the evidence's grid
        bins_per_unit = float(self.scale.span) / float(self.gate.bin_width)
        threshold = float(self.model.config.no_return_logit) if head else 0.0
        windows = iter_count_windows(self._count_stream(), EVIDENCE_FRAMES)
        ensemble = self._ensemble_outputs(batch_size)
        for out, window in zip(raw, windows, strict=True):
            flags = next(quiet) if quiet is not None else None
            depth, logit = (out[..., 0], out[..., 1]) if head else (out, None)
            p, sigma = confidence_frame(window, depth, self.confidence_coefficients, sensor, head_logit=logit,
                                        bins_per_unit=bins_per_unit)
            if self.photons.by_probability:  # where the photons show a return, its depth stays
                hr = no_return_by_probability(depth, p, threshold)
                if flags is not None:
                    hr = np.where(lr_blocks(flags.quiet, self.scale_factor), hr, depth)
            elif flags is not None:
                hr = overrule_no_return(out, flags.quiet, threshold)
            elif head:
                hr = np.where(logit > np.float32(threshold), np.float32(1.0), depth)
            else:
                hr = depth
            if ambient is not None:
                hr = no_return_where(hr, next(ambient))
            hr = ensemble_depth(hr, next(ensemble))
            if flags is not None:  # a black surface that returns enclose: the depth of the surfaces around it
                hr = filled_where_holes(hr, flags.black, self.scale)
            std = np.where(hr < NO_RETURN_AT, sigma * np.float32(self.gate.bin_width), np.float32(np.nan))
            yield hr, p, std.astype(np.float32)

    def iter_normalised(self, *, batch_size: int | None = None, lr_frames=None) -> Iterator[np.ndarray]:
        """The network's output, streamed: (H, W) float32 HR normalised depth (unclipped), one per frame, with the
        photon rules applied. lr_frames: the LR stream to run (default `lr_frames()`)."""
        if self.has_confidence and self.photons.by_probability:  # the decision needs the confidence
            return (hr for hr, _, _ in self.iter_outputs(batch_size=batch_size, lr_frames=lr_frames))
        lr = self.lr_frames() if lr_frames is None else lr_frames
        keep = self._keep_stream() if self._keep_stream is not None else None
        if keep is not None:
            keep, holes = itertools.tee(keep)
            out = iter_returns_kept(self.model, lr, (q.quiet for q in keep), batch_size=batch_size,
                                    precision=self.precision)
        else:
            out = iter_super_resolve(self.model, lr, batch_size=batch_size, precision=self.precision)
        if self._ambient_stream is not None:
            out = (no_return_where(hr, flags) for hr, flags in zip(out, self._ambient_stream(), strict=True))
        if self.ensemble_model is not None:
            out = (ensemble_depth(hr, other) for hr, other in zip(out, self._ensemble_outputs(batch_size),
                                                                   strict=True))
        if keep is None:
            return out
        return (filled_where_holes(hr, q.black, self.scale) for hr, q in zip(out, holes, strict=True))

    def _ensemble_outputs(self, batch_size: int | None) -> Iterator[np.ndarray | None]:
        """The ensemble model's HR output frame by frame, from the recording's own frames whatever LR stream the
        model is given (None for each frame where there is no ensemble model)."""
        if self.ensemble_model is None:
            return itertools.repeat(None)
        return iter_super_resolve(self.ensemble_model, self._ensemble_lr_stream(), batch_size=batch_size,
                                  precision=self.precision)

    def iter_frames(self, *, batch_size: int | None = None, units: str | None = None) -> Iterator[np.ndarray]:
        """The super-resolved recording, streamed: (H, W) float32 frames in `units` (default the job's: "m",
        radial metres with inf for no return, or "mm", "cm", "km" likewise, or "normalised", clipped to [0, 1])."""
        units = self.units if units is None else units
        for hr in self.iter_normalised(batch_size=batch_size):
            yield to_units(hr, units, self.scale)


def ensemble_depth(hr: np.ndarray, other: np.ndarray | None) -> np.ndarray:
    """`hr` (HR normalised depth, the no-return decision made) with the mean of its depth and `other`'s (another
    network's output) where both hold a return (below `NO_RETURN_AT`): two networks that err in different places
    err less together; the decision stays `hr`'s. `hr` itself for None."""
    if other is None:
        return hr
    both = (hr < NO_RETURN_AT) & (other < NO_RETURN_AT)
    return np.where(both, np.float32(0.5) * (hr + other), hr).astype(np.float32)


def _as_choice(model) -> ModelChoice:
    return model if isinstance(model, ModelChoice) else ModelChoice(model)


def prepare_upscale(input, *, model="default", read: Reading = Reading(), photons: PhotonRules = PhotonRules(),
                    max_memory=None, outputs=None) -> UpscaleJob:
    """Open and check a recording and choose its model, as `jaxsr upscale` does before any output is written.

    input: a path (.npy / .npz array of depth (T, h, w) or photon counts (T, h, w, bins); a folder or glob pattern
    of EXR, PFM, TIFF or 16-bit PNG depth frames; with `Reading(kind="timetags")` a .mat cell array or .npz table
    of photon time tags), or an opened `Recording`, a NumPy array (T, h, w) / (T, h, w, bins), or
    `jaxsr.sensor.TimeTags`. model: a `ModelChoice`, or what its `model` takes (a name, path or `Model`). read,
    photons: what is read and the photon rules (`Reading`, `PhotonRules`). max_memory: the budget an .npz's array
    and time tags' histograms are checked against before they are read (bytes or a size such as "16GB"); with
    `outputs` (the checked `Outputs` the job will write, `check_outputs`), so is the least memory their result
    needs (`jaxsr.app.memory.result_memory`: a result held whole, or drawn), from the recording's sizes before any
    of its frames is read. Checks, in order: the model, then the input, its memory and every one of its frames
    (frames of any size h, w >= 4).

    Returns an `UpscaleJob`. Raises ValueError, FileNotFoundError (a missing input or model) with the messages
    `jaxsr upscale` prints, TypeError for an input or model of another type (None among them).
    """
    choice = _as_choice(model)
    for spec, kind in ((read, Reading), (photons, PhotonRules)):
        if not isinstance(spec, kind):
            raise TypeError(f"expected a jaxsr.app.{kind.__name__}, got {type(spec).__name__}")
    planned = plan_model(choice)
    if photons.keep_returns is not None and not is_auto(photons.keep_returns) and not has_head(
            choice, planned, "histograms"):  # before the input is read
        raise ValueError("keep_returns (--keep-returns) overrules a no-return head's decision and this model has no "
                         "head: give one that has (tr4-ambient, tr0-ambient, tr4-photons, tr0-photons)")
    rec, gate, source, tag_notes = _open(input, read, max_memory)
    if outputs is not None:  # from the sizes alone, before a pass over the frames
        scale = 4 if planned.model is None else int(planned.model.architecture.scale(planned.model.config))
        check_result_memory(rec, scale, in_memory=outputs.in_memory, looks=outputs.writing.looks,
                            max_memory=max_memory)
    if rec.kind == "histograms":
        job = _histogram_job(rec, gate, source, tag_notes, choice, planned, read, photons)
    else:
        job = _depth_job(rec, source, choice, planned, read, photons)
    return dataclasses.replace(job, input_path=str(input) if isinstance(input, (str, os.PathLike)) else None)


def _depth_job(rec, source, choice, planned, read: Reading, photons: PhotonRules) -> UpscaleJob:
    """The job of depth frames: no photons, so no photon model and no photon rule (a rate is refused)."""
    _refuse_photon_model(planned)
    for what, setting in (("ambient_alpha (--ambient-alpha)", photons.ambient_alpha),
                          ("keep_returns (--keep-returns)", photons.keep_returns)):
        if not is_auto(setting) and setting is not None:
            raise ValueError(f"{what} tests the photons behind each pixel: give photon histograms or time tags, not "
                             "depth frames")
    units = guess_units(rec) if read.units is None else read.units
    r = 4 if planned.model is None else int(planned.model.architecture.scale(planned.model.config))
    sensor = Sensor(optics=Optics.of_hr(Sensor().hr_shape, r))
    check_frames(rec, units)

    def lr_stream():
        return normalised_frames(rec, units, sensor)

    enable_compilation_cache()
    model, name, description, _ = finish_model(choice, planned, "depth", lambda: _head(lr_stream(), HEAD_FRAMES))
    # inside a region of no return (a pixel and its 8 neighbours), the output is no return too: a network reading
    # depth alone shows some of a sky band as depth, and nothing there says a surface is
    interior = None if model.has_no_return_head else (lambda: (no_return_interior(f) for f in lr_stream()))
    return UpscaleJob(rec, model, description, description, units, None, sensor.depth, (),
                      source, choice.precision, model_id=name, _lr_stream=lr_stream, _ambient_stream=interior)


def no_return_interior(lr) -> np.ndarray:
    """(h, w) LR normalised depth -> (h, w) bool: no return (1.0) at the pixel and at each of its 8 neighbours
    (edge-replicated at the frame's border)."""
    padded = np.pad(np.asarray(lr) >= 1.0, 1, mode="edge")
    h, w = np.shape(lr)
    return np.logical_and.reduce([padded[i:i + h, j:j + w] for i in range(3) for j in range(3)])


def _histogram_job(rec, gate, source, tag_notes, choice, planned, read: Reading, photons: PhotonRules) -> UpscaleJob:
    """The job of photon histograms (time tags already histogrammed): the gate's depth scale, the photon levels
    and the rules they decide, and streams of the network's input and the rules' flags."""
    units = "m" if read.units is None else read.units
    found = check_frames(rec, units, gate, clip_negative=read.clip_negative)  # (0, 0) unless clip_negative
    counts = clipped_recording(rec) if read.clip_negative else rec
    # the depth span: the sensor's (--sensor), given (--span), the gate's, or by default the depth the first
    # frames' returns reach
    returns = head_returns(counts, gate, HEAD_FRAMES)
    sensor = read.sensor_of_gate(gate, data_span(returns, gate))
    scale = sensor.depth  # what network_inputs, the output's metres and the confidence's bins all read
    refit = ("a sensor file's depth scale spans its gate, as a model fine-tuned on it reads it; for another model give "
             "the gate's flags in place of --sensor and leave --span out to fit it" if read.sensor is not None
             else "leave --span out to fit it")
    warnings = tag_notes + tuple(gate_warnings(gate, scale, returns=returns, refit=refit))
    if found[0]:
        warnings += (_clipped_note(*found),)
    # what the photons say, read once (not after clipping: the clipped counts' ambient is no longer the sensor's)
    levels = None if read.clip_negative else photon_levels(counts, gate.bins)

    def lr_stream(channels):
        return iter_network_inputs(counts, sensor, channels, chunk=HISTOGRAM_CHUNK)

    enable_compilation_cache()
    model, model_id, name, ensemble_model = finish_model(
        choice, planned, "histograms", lambda: _head(lr_stream(("depth",)), HEAD_FRAMES),
        *((float("nan"), float("nan")) if levels is None else (levels.signal, levels.snr)))
    head_frames = min(HEAD_FRAMES, rec.frames)
    if levels is not None:
        if model.has_no_return_head:
            named = ModelChoice(model_id) if choice.is_auto else choice  # the model auto picked, by name
            warnings += snr_warnings(trained_snr_range(named, "histograms"), levels.snr, head_frames,
                                     choice.no_return_logit)
        elif not model.reads_photons:
            warnings += few_photons_warnings(levels.signal, head_frames)
    warnings += rule_warnings(photons, clip_negative=read.clip_negative)
    decision = decide_photon_rules(photons, levels, marks_no_return=model.has_no_return_head, frames=rec.frames)
    label = name
    if ensemble_model is not None:
        name = (f"{name}, its returns' depth averaged with {DEPTH_ENSEMBLE.model}'s ({levels.signal:.0f} signal "
                f"photons per LR pixel at SNR {levels.snr:.3g}: {DEPTH_ENSEMBLE.min_signal:g} or more at "
                f"{DEPTH_ENSEMBLE.min_snr:g} or more)")
    if decision.ambient_alpha is not None:
        name = f"{name}, no return where ambient alone (alpha {float(decision.ambient_alpha):g}{decision.ambient_why})"
    elif decision.ambient_why:
        name = f"{name}{decision.ambient_why}"
    if decision.by_probability:
        name = (f"{name}, no return where P(return) < {_probability_at(model.config.no_return_logit):.3g} (the head's "
                f"logit and the pixel's photons over {EVIDENCE_FRAMES} frames)")
    if decision.keep_returns is not None:
        pools = " and ".join(f"{k} x {k}" for k in QUIET_POOLS)
        name = (f"{name}, {'that' if decision.by_probability else 'its'} no return kept only where the pixel's photons "
                f"over {AMBIENT_FRAMES} frames, and those of the quiet pixels in the {pools} around it, pass for "
                f"ambient alone (alpha {float(decision.keep_returns):g}) in a region that reaches the frame's edge or "
                f"holds more than {HOLE_PIXELS} LR pixels, a smaller one that is black taking the depth of the "
                "surfaces around it")

    def flags(alpha, pixels):
        return lambda: iter_ambient_only(counts, sensor, alpha=alpha, pixels=pixels, frames=AMBIENT_FRAMES)

    return UpscaleJob(
        rec, model, name, label, units, gate, scale, warnings, source, choice.precision,
        found if read.clip_negative else None, decision, model_id, ensemble_model=ensemble_model,
        _lr_stream=lambda: lr_stream(model.channels),
        _ensemble_lr_stream=None if ensemble_model is None else (lambda: lr_stream(ensemble_model.channels)),
        _ambient_stream=None if decision.ambient_alpha is None else flags(decision.ambient_alpha, 3),
        # each pixel's own photons, then those of the quiet pixels around it (a dim wall's return shows in their
        # pool), and no hole: a quiet region that returns enclose keeps a return, the depth of the surfaces around it
        # where it is black (its photons fewer than the ambient light around it), else the network's
        _keep_stream=None if decision.keep_returns is None else (
            lambda: iter_quiet(counts, sensor, alpha=decision.keep_returns, frames=AMBIENT_FRAMES)),
        _count_stream=lambda: iter(counts),
        confidence_coefficients=coefficients_for(model_id, model.has_no_return_head))


def _probability_at(no_return_logit: float) -> float:
    """The P(return) below which a pixel is no return at a no-return threshold (a logit of P(no return))."""
    return float(np.exp(-np.logaddexp(0.0, float(no_return_logit))))  # 1 / (1 + e^logit), no overflow


def head_returns(counts, gate: Gate, frames: int) -> np.ndarray:
    """Radial metres of the returns the first `frames` frames of (h, w, bins) counts show (their centre of mass
    over the gate), flattened; no return (inf) left out. Negative counts (background-subtracted) count as 0."""
    out = [np.asarray(gate_depth(np.maximum(np.asarray(f, np.float32), 0.0), gate)).ravel()
           for f in itertools.islice(counts, frames)]
    depth = np.concatenate(out) if out else np.zeros(0)
    return depth[np.isfinite(depth)]


def _refuse_photon_model(planned) -> None:
    """Depth frames cannot feed a model that reads the photons behind each depth."""
    if planned.model is not None and planned.model.reads_photons:
        raise ValueError(f"model {planned.name} reads {', '.join(planned.model.channels)} per pixel, which depth "
                         "frames do not hold: give it photon histograms or time tags, or choose a depth model "
                         "(tr0..tr4)")


def _head(frames, n):
    """The first n frames of an iterable, stacked."""
    return np.stack(list(itertools.islice(frames, n)))


def _plural(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _clipped_note(counts: int, pixels: int) -> str:
    """The warning on negative counts clipped (--clip-negative): how many, in how many pixels."""
    return (f"{_plural(counts, 'negative count')} in {_plural(pixels, 'pixel')} clipped at 0 (--clip-negative: "
            "background-subtracted histograms)")


def array_recording(arr: np.ndarray, kind: str | None) -> Recording:
    """A NumPy array as a recording: (T, h, w) depth or (T, h, w, bins) counts, one (h, w) frame allowed."""
    if arr.dtype.kind not in "iuf":
        raise ValueError(f"array input holds {arr.dtype} values; expected real numbers")
    if arr.ndim == 2 and kind != "histograms":
        arr = arr[None]
    kind = kind or {3: "depth", 4: "histograms"}.get(arr.ndim)
    if kind is None or arr.ndim != {"depth": 3, "histograms": 4}[kind]:
        raise ValueError(f"array input: expected depth (T, h, w) or histograms (T, h, w, bins), got shape {arr.shape}")
    if arr.shape[0] < 1:
        raise ValueError("array input: the recording has no frames")
    return Recording(kind, arr.shape[0], arr.shape[1:], lambda: iter(arr), "array", array=arr)


def _open(input, read: Reading, max_memory):
    """(recording, gate, source, warnings) for the input: time tags histogrammed over their gate (the warnings
    on photons dropped or a likely wrong time unit), histograms with theirs, or depth (None for the gate; the
    gate's options and clip_negative refused there)."""
    if input is None or isinstance(input, (list, tuple, bytes)):
        raise TypeError("input: expected a path, a Recording, a NumPy array (T, h, w) or (T, h, w, bins) or "
                        f"TimeTags, got {type(input).__name__}" + (" (np.asarray makes an array of a list)"
                                                                    if isinstance(input, (list, tuple)) else ""))
    if isinstance(input, np.ndarray) and input.dtype.kind not in "iuf":
        raise ValueError(f"array input holds {input.dtype} values; expected real numbers (complex values are not "
                         "depth nor counts)")
    width, start = read.bin_width, read.gate_start
    if read.kind == "timetags" or isinstance(input, TimeTags):
        if isinstance(input, TimeTags):
            tags = input
        else:
            if not str(input).lower().endswith(TIME_TAG_FORMATS):
                raise ValueError(f"{input}: time tags are read from a MATLAB .mat cell array (v4-v7) or an .npz "
                                 "table ('pixel', 'time', 'shape')")
            tags = read_time_tags(input, variable=read.variable, time_unit_s=read.time_unit, max_memory=max_memory)
        if (width is None) != (start is None):
            raise ValueError("give both --bin-width and --gate-start, or neither (the gate then spans the photons)")
        if read.clip_negative:
            raise ValueError("--clip-negative applies to histograms only (counts of time tags are never negative)")
        if read.sensor is not None:
            gate = read.sensor.gate
        else:
            gate = gate_of_tags(tags, bins=read.n_bins) if width is None else Gate(read.n_bins, width, start)
        outside = "drop" if read.drop_outside else "error"
        rec = time_tag_recording(tags, gate, outside=outside, max_memory=max_memory)
        source = str(input) if not isinstance(input, TimeTags) else tags.source
        return rec, gate, source, tuple(time_tag_warnings(tags, gate, outside=outside))
    if read.tag_options:
        raise ValueError(f"{', '.join(read.tag_options)} applies to time tags only (--kind timetags)")
    if isinstance(input, Recording):
        rec, source = input, str(input.source)
        if read.kind is not None and read.kind != rec.kind:
            raise ValueError(f"{source}: a {rec.kind} recording, not {read.kind}")
    elif isinstance(input, np.ndarray):
        rec, source = array_recording(input, read.kind), "array"
    else:
        rec, source = open_recording(input, kind=read.kind, max_memory=max_memory), str(input)
    if rec.kind == "depth":
        read.refuse_for_depth()
        return rec, None, source, ()
    # the array says how many bins; --bins and --sensor check it
    return rec, read.sensor_for(None if read.bins is not None else int(rec.shape[-1])).gate, source, ()
