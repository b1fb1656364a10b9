"""Super-resolve a whole recording in one call, as `jaxsr upscale` does: open it (depth, histograms or photon
time tags, `jaxsr.io.recordings`), check every frame, choose the model (a fixed one or `--model auto`), put the
input on the network's scale (gate, depth scale, units), stream it through the network and write the result
atomically (an .npy / .npz array or a folder of frame files) with an optional preview strip.

`upscale` is the whole command; `prepare_upscale` and `write_upscaled` are its two halves (a checked job that
yields HR frames, and the writer), for scripts that want the frames themselves or want to report between the
checks and the long work.

Frames stream from the input through the model to the output, so a long recording needs memory for a batch, not
for the whole sequence (an .npz output holds the result; an .npy output is written through a memory map).
Histograms and photon time tags are read over a gate (`bins`, `bin_width`, `gate_start`) and put on the
network's scale with the gate's start as its 0 m and `span` metres (default the trained 35 m) as its 1.0; where
that takes the models outside what they were trained on, `warnings` says so. Outputs never replace an existing
file or write into a non-empty folder unless `overwrite`.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import itertools
import os
from pathlib import Path
from typing import Callable, Iterator, NamedTuple

import numpy as np
from tqdm.auto import tqdm

from ..checks import memory_budget, one_positive_number, require_memory
from ..config import PRECISIONS, DepthScale, Gate, PhotonRegime, SensorConfig
from ..io.checkpoint import load_model, read_metadata, resolve_model_path
from ..io.files import atomic_folder, atomic_path, reserve_space
from ..io.formats import PNG_MAX_M, write_depth, write_sequence
from ..io.pointcloud import DEFAULT_FOV_DEG, PointCloudWriter, check_points_folder
from ..io.previews import write_comparison
from ..io.recordings import (
    ARRAY_FORMATS,
    DEPTH_UNITS,
    Recording,
    check_frames,
    check_output,
    check_preview,
    clipped_recording,
    gate_frames,
    guess_units,
    normalised_frames,
    open_recording,
    time_tag_recording,
    to_units,
)
from ..io.video import DEFAULT_FPS, DepthVideoWriter, check_video
from ..nn.duf import with_no_return_logit
from ..nn.model import Model
from ..runtime import enable_compilation_cache
from ..sensor.gates import gate_warnings
from ..sensor.peaks import check_false_alarm_rate, frame_levels
from ..sensor.quantities import parse_span, parse_time_unit, range_metres
from ..sensor.timetags import TIME_TAG_FORMATS, TimeTags, gate_of_tags, read_time_tags, time_tag_warnings
from .adaptive import resolve_model
from .video import (DEFAULT_FORM, DEFAULT_PRECISION, DEFAULT_TILE, FORMS, _default_batch_size, check_keep_returns,
                    check_precision, iter_ambient_only, iter_returns_kept, no_return_where,
                    in_form, iter_network_inputs, iter_super_resolve)

__all__ = ["HEAD_FRAMES", "DEFAULT_MODELS", "AUTO_KEEP_RETURNS", "AUTO_AMBIENT_ALPHA", "AUTO_AMBIENT_MIN_SNR",
           "AUTO_AMBIENT_MIN_SIGNAL_SNR", "AUTO_AMBIENT_MIN_FRAMES", "auto_ambient_alpha",
           "FEW_PHOTONS", "PhotonLevels", "photon_levels", "FRAME_FORMATS", "UpscaleJob", "UpscaleResult",
           "prepare_upscale", "write_upscaled", "upscale", "upscale_memory"]

HEAD_FRAMES = 64  # frames model="auto" measures the motion on, and the frame SNR is estimated from
# ambient_alpha="auto" (the default for histograms and time tags): the ambient-only test at this false-alarm rate
# where the recording's estimated frame SNR is at least AUTO_AMBIENT_MIN_SNR, or its signal photons per pixel and
# frame times that SNR (signal^2 / ambient photons: how far one pixel's return stands out of its ambient light) at
# least AUTO_AMBIENT_MIN_SIGNAL_SNR (experiments/results/upscale_defaults.md)
AUTO = "auto"
AUTO_AMBIENT_ALPHA = 1e-3
AUTO_AMBIENT_MIN_SNR = 1.0
AUTO_AMBIENT_MIN_SIGNAL_SNR = 5.0
# frames the SNR is read from before "auto" trusts it: fewer read high at a few photons (at SNR 0.8 and 3 photons,
# 0.91-0.99 from 16 frames, 1.09-1.29 from 8, 3.2-4.0 from one), and the rule was measured on 64
AUTO_AMBIENT_MIN_FRAMES = 16
# below this many estimated signal photons per LR pixel and frame, a model reading depth alone is told that the
# photon model may serve better (experiments/results/upscale_defaults.md: +5.8 dB on the simulated test scenes
# there, but not on every real recording, so it stays a hint)
FEW_PHOTONS = 3.0
# model="default": the bundled model that fits the input. Depth gives only the centre of mass, which the paper's
# TR4 reads; histograms and time tags also give the photons behind it, which tr4-ambient reads: ahead of TR4 in
# every simulated regime and by 2 dB on average on two real recordings (docs/results/photon-regimes.md, the default)
DEFAULT_MODELS = {"depth": "tr4", "histograms": "tr4-ambient"}
# keep_returns="auto": for a model with a no-return head on histograms and time tags, its no return kept only where
# the pixel's own photons pass for ambient light alone at this rate. On the real tower recording it turned
# tr4-ambient's head alone (+2.4 to -10.4 dB against bicubic on a dim building at 1-8 photons) into +3.5 to +4.7 dB,
# for 0.1-0.5 dB in simulation at 100-1000 photons (the sky at the edges of sky regions shown as depth)
AUTO_KEEP_RETURNS = 1e-3
FRAME_FORMATS = ("exr", "pfm", "tif", "png")  # frame files of a folder OUTPUT
KINDS = ("depth", "histograms", "timetags")
# Memory of `write_upscaled` (`upscale_memory`), measured on XLA:CPU with peak resident sizes (2026, 2 cores):
# JAX, a model and the interpreter before any frame (0.36-0.49 GB);
BASE_BYTES = 0.5e9
# histogram frames turned into the network's input per compiled call (`iter_network_inputs`), and the copies
# each float32 frame of counts makes there (6x: 16 frames of 2000 bins took 1.6 GB);
HISTOGRAM_CHUNK, HISTOGRAM_COPIES = 16, 6
AMBIENT_FRAMES = 9  # frames the no-return tests of `ambient_alpha` and `keep_returns` sum (`iter_ambient_only`'s)
# a DUF network's features per LR pixel of a tile and frame of the batch, in bytes per channel: float32 twice
# over the window (the dense blocks' activations and their batch norm) and once in the head (TR0 5.3 kB, TR4
# 20 kB per pixel measured; this gives 5.3 and 25). Another architecture counts as TR4.
NETWORK_BYTES_TR4 = 25e3


@dataclasses.dataclass(frozen=True)
class UpscaleJob:
    """A recording checked and ready to super-resolve (`prepare_upscale`): every frame checked, the model loaded.

    recording: the opened `jaxsr.io.recordings.Recording` (kind "depth" or "histograms", time tags already
    histogrammed); model: the `Model`; model_name: the model as people read it (tr4, a path, or
    "tr1 (auto: motion ...)"); units: "m", "mm", "cm", "km" or "normalised" (`DEPTH_UNITS`), of the input depth
    and of array outputs; gate: the histogram gate (None for depth); scale: the `DepthScale` between metres and
    the network's [0, 1]; warnings: sentences on what the bundled models never saw in this gate and scale, and on
    negative counts clipped; source: the input as named in messages and in an .npz output's metadata;
    negative_counts: with `clip_negative`, (negative counts clipped at 0, pixels holding one), else None;
    precision: how the network's convolutions multiply (`jaxsr.config.PRECISIONS`). The model is held in the
    temporal form it runs in (`form` of `prepare_upscale`: `model.config.temporal`). ambient_alpha: the
    false-alarm rate `prepare_upscale`'s `ambient_alpha` set or picked (None: no test); with one, the output is
    also no return where `jaxsr.inference.iter_ambient_only` flags a pixel. label: the model's name for pictures
    (previews, videos: `model_name` without the ambient test's note, which would not fit a panel). keep_returns:
    the false-alarm rate of `prepare_upscale`'s `keep_returns` (None: the model's own decision); with one, the
    output is no return only where the model's head says so and the pixel's photons agree (`overrule_no_return`)."""

    recording: Recording
    model: object
    model_name: str
    units: str
    gate: Gate | None
    scale: DepthScale
    warnings: tuple[str, ...]
    source: str
    _lr_stream: Callable[[], Iterator[np.ndarray]] = dataclasses.field(repr=False, compare=False)
    negative_counts: tuple[int, int] | None = None
    precision: str = DEFAULT_PRECISION
    # with ambient_alpha: a fresh stream of (h, w) bool per frame, no return where ambient light alone is seen
    _ambient_stream: Callable[[], Iterator[np.ndarray]] | None = dataclasses.field(default=None, repr=False,
                                                                                   compare=False)
    ambient_alpha: float | None = None
    label: str = ""
    # with keep_returns: a fresh stream of (h, w) bool per frame, True where a pixel's own photons over 9 frames
    # pass for ambient light alone (the only pixels where the model's no return is kept)
    _keep_stream: Callable[[], Iterator[np.ndarray]] | None = dataclasses.field(default=None, repr=False,
                                                                                compare=False)
    keep_returns: float | None = None

    @property
    def frames(self) -> int:
        """Frames in the recording, T."""
        return self.recording.frames

    @property
    def hr_shape(self) -> tuple[int, int]:
        """(H, W) of an output frame: the LR frame times the model's scale."""
        r = _scale(self.model)
        return (int(self.recording.shape[0]) * r, int(self.recording.shape[1]) * r)

    @property
    def note(self) -> str:
        """One line for people: what is read and with which model (`jaxsr upscale` prints it before the work)."""
        return (f"{self.frames} frames {self.recording.kind} {tuple(self.recording.shape)} from {self.source}, "
                f"input units {self.units}, model {self.model_name}{self.how}")

    @property
    def how(self) -> str:
        """How the network runs, as `note` ends: ", sequence form" for a DUF model in the sequence form, and
        ", precision bfloat16" (or float32) where it is not the default; "" otherwise."""
        seq = getattr(self.model.config, "temporal", None) == "sequence"
        return (", sequence form" if seq else "") + ("" if self.precision == "default" else
                                                       f", precision {self.precision}")

    @property
    def fps(self) -> float | None:
        """The recording's frames per second where its file says (an .npz from `jaxsr simulate`), else None."""
        return getattr(self.recording, "fps", None)

    @property
    def d_range(self) -> tuple[float, float]:
        """(first, last) metres of the sensor's true range that the network's [0, 1] covers: the depth scale's
        offset (the gate's start) and offset + span. Every picture, video and point cloud is drawn over it."""
        return float(self.scale.offset), float(self.scale.offset + self.scale.span)

    def lr_frames(self) -> Iterator[np.ndarray]:
        """A fresh stream of the network's input: (h, w) float32 LR normalised depth frames, one per frame
        ((h, w, C) for a model reading photons too: depth in channel 0, `jaxsr.nn.network_inputs`)."""
        return self._lr_stream()

    def iter_normalised(self, *, batch_size: int | None = None, lr_frames=None) -> Iterator[np.ndarray]:
        """The network's output, streamed: (H, W) float32 HR normalised depth (unclipped), one per frame.
        lr_frames: the LR stream to run (default `lr_frames()`)."""
        lr = self.lr_frames() if lr_frames is None else lr_frames
        if self._keep_stream is not None:
            return iter_returns_kept(self.model, lr, self._keep_stream(), batch_size=batch_size,
                                     precision=self.precision)
        out = iter_super_resolve(self.model, lr, batch_size=batch_size, precision=self.precision)
        if self._ambient_stream is None:
            return out
        return (no_return_where(hr, flags) for hr, flags in zip(out, self._ambient_stream(), strict=True))

    def iter_frames(self, *, batch_size: int | None = None, units: str | None = None) -> Iterator[np.ndarray]:
        """The super-resolved recording, streamed: (H, W) float32 frames in `units` (default the job's: "m",
        radial metres with inf for no return, or "mm", "cm", "km" likewise, or "normalised", clipped to [0, 1])."""
        units = self.units if units is None else units
        for hr in self.iter_normalised(batch_size=batch_size):
            yield to_units(hr, units, self.scale)


@dataclasses.dataclass(frozen=True)
class UpscaleResult:
    """What `upscale` / `write_upscaled` did. output: the file or folder written (None when kept in memory);
    depth: the (T, H, W) float32 result in `units` when no output was written, else None; frames: T; shape:
    (T, H, W); kind: "depth" or "histograms"; units: of the output's values (an array's: the input's units; a
    folder of frames: always "m"); model: the model as people read it; gate, scale: the histogram gate and depth
    scale (gate None for depth); preview: the PNG written, or None; warnings: sentences on what the models never
    saw and on what the writing found; notes: every line `jaxsr upscale` prints to stderr (warnings as "warning:
    ...", then what was read with which model, then warnings on what the writing found); video: the side-by-side
    video written, or None; points: the folder of PLY point clouds, or None; negative_counts: with
    `clip_negative`, (negative counts clipped at 0, pixels holding one), else None; input_units: the input's
    units (`UpscaleJob.units`), where they differ from `units`; ambient_alpha: the ambient-only test's
    false-alarm rate (`UpscaleJob.ambient_alpha`, None: no test); keep_returns: `upscale`'s keep_returns rate
    (`UpscaleJob.keep_returns`; in the summary only when set)."""

    output: Path | None
    depth: np.ndarray | None
    frames: int
    shape: tuple[int, int, int]
    kind: str
    units: str
    model: str
    gate: Gate | None
    scale: DepthScale
    preview: Path | None
    warnings: tuple[str, ...]
    notes: tuple[str, ...]
    video: Path | None = None
    points: Path | None = None
    negative_counts: tuple[int, int] | None = None
    input_units: str | None = None
    ambient_alpha: float | None = None
    keep_returns: float | None = None

    def summary(self) -> dict:
        """The JSON summary `jaxsr upscale` prints: frames, output, shape, units (of the output; input_units too
        where the input's differ), model, for histograms the gate, the depth scale (metres) and the ambient-only
        test's rate (null: none) and `keep_returns`' where set, the video and point clouds' folder where written,
        and with --clip-negative the negative counts clipped and the pixels holding them."""
        out = {"frames": self.frames, "output": None if self.output is None else str(self.output),
               "shape": list(self.shape), "units": self.units, "model": self.model}
        if self.input_units is not None:
            out["input_units"] = self.input_units
        if self.video is not None:
            out["video"] = str(self.video)
        if self.points is not None:
            out["points"] = str(self.points)
        if self.kind == "histograms":
            out.update(gate={"bins": self.gate.bins, "bin_width_m": float(self.gate.bin_width),
                             "start_m": float(self.gate.start)},
                       scale={"offset_m": float(self.scale.offset), "span_m": float(self.scale.span)})
        if self.negative_counts is not None:
            out["negative_counts_clipped"] = dict(zip(("counts", "pixels"), self.negative_counts))
        if self.kind == "histograms":
            out["ambient_alpha"] = self.ambient_alpha
        if self.keep_returns is not None:
            out["keep_returns"] = self.keep_returns
        return out


def _scale(model) -> int:
    """The model's upscaling factor r (x4 for the paper's models)."""
    return int(model.architecture.scale(model.config))


def _positive(value, what: str, parse, unit: str):
    """None, a string parsed by `parse` (a quantity with its unit), or a finite number > 0 in `unit`."""
    if value is None:
        return None
    if isinstance(value, str):
        try:
            return parse(value)
        except ValueError as e:
            raise ValueError(f"{what}: {e}") from None
    return one_positive_number(value, what, f"one value > 0 in {unit}")


def _span(value) -> float | str | None:
    """The span option: None, "gate", or a range > 0 (metres, or a string with its unit)."""
    return value if value == "gate" else _positive(value, "span", parse_span, "metres or 'gate'")


def _array_recording(arr: np.ndarray, kind: str | None) -> Recording:
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


def _open(input, kind, *, bins, bin_width, gate_start, span, time_unit, variable, drop_outside, clip_negative,
          max_memory):
    """(recording, gate, source, warnings) for the input: time tags histogrammed over their gate (the warnings
    on photons dropped or a likely wrong time unit), histograms with theirs, or depth (gate options and
    clip_negative refused there)."""
    if input is None:
        raise TypeError("input: expected a path, a Recording, a NumPy array (T, h, w) or (T, h, w, bins) or "
                        "TimeTags, got None")
    if kind is not None and kind not in KINDS:
        raise ValueError(f"kind (--input) is one of {', '.join(KINDS)}, got {kind!r}")
    width, start = range_metres(bin_width, "bin_width"), range_metres(gate_start, "gate_start")
    gate_options = any(v is not None for v in (bins, bin_width, gate_start, span))
    bins = 16 if bins is None else int(bins)
    if bins < 2:
        raise ValueError(f"bins: expected an integer >= 2, got {bins}")
    if start is not None and start < 0:  # before the laser pulse: depth would come out negative
        raise ValueError(f"gate_start (--gate-start): expected a range >= 0 from the laser pulse, got {start:g} m")
    tag_only = [o for o, v in (("--time-unit", time_unit), ("--variable", variable),
                               ("--drop-outside", drop_outside or None)) if v is not None]
    if kind == "timetags" or isinstance(input, TimeTags):
        if isinstance(input, TimeTags):
            tags = input
        else:
            if not str(input).lower().endswith(TIME_TAG_FORMATS):
                raise ValueError(f"{input}: time tags are read from a MATLAB .mat cell array (v4-v7) or an .npz "
                                 "table ('pixel', 'time', 'shape')")
            tags = read_time_tags(input, variable=variable, time_unit_s=time_unit, max_memory=max_memory)
        if (width is None) != (start is None):
            raise ValueError("give both --bin-width and --gate-start, or neither (the gate then spans the photons)")
        if clip_negative:
            raise ValueError("--clip-negative applies to histograms only (counts of time tags are never negative)")
        gate = gate_of_tags(tags, bins=bins) if width is None else Gate(bins, width, start)
        outside = "drop" if drop_outside else "error"
        rec = time_tag_recording(tags, gate, outside=outside, max_memory=max_memory)
        source = str(input) if not isinstance(input, TimeTags) else tags.source
        return rec, gate, source, tuple(time_tag_warnings(tags, gate, outside=outside))
    if tag_only:
        raise ValueError(f"{', '.join(tag_only)} applies to --input timetags only")
    if isinstance(input, Recording):
        rec, source = input, str(input.source)
        if kind is not None and kind != rec.kind:
            raise ValueError(f"{source}: a {rec.kind} recording, not {kind}")
    elif isinstance(input, np.ndarray):
        rec, source = _array_recording(input, kind), "array"
    else:
        rec, source = open_recording(input, kind=kind, max_memory=max_memory), str(input)
    if rec.kind == "depth" and (gate_options or drop_outside):
        raise ValueError("--bins, --bin-width, --gate-start and --span apply to histograms and time tags only")
    if rec.kind == "depth" and clip_negative:
        raise ValueError("--clip-negative applies to histograms only (negative depth is no return)")
    default = Gate()
    gate = Gate(bins, default.bin_width if width is None else width, 0.0 if start is None else start)
    return rec, gate, source, ()


def _fixed_model(model, min_fps):
    """(the model named by `model`, loaded and checked now, its name); (None, "auto") for auto and (None,
    "default") for the default, which need the input first (their bundled weights are looked up now)."""
    if not isinstance(model, (str, os.PathLike, Model)):
        raise TypeError(f"model: expected 'default', 'tr0'..'tr4', 'auto', a checkpoint path or a loaded jaxsr.Model, "
                        f"got {type(model).__name__} {model!r:.60}")
    if isinstance(model, str) and model == "default":
        for name in set(DEFAULT_MODELS.values()):
            resolve_model_path(name)
        if min_fps is not None:
            raise ValueError("--min-fps applies to --model auto only (a fixed model runs at its own speed)")
        return None, "default"
    if isinstance(model, Model):  # already loaded
        if min_fps is not None:
            raise ValueError("--min-fps applies to --model auto only (a fixed model runs at its own speed)")
        return model, "model"
    if model == "auto":
        resolve_model_path("tr0")
        return None, "auto"
    if min_fps is not None:
        raise ValueError("--min-fps applies to --model auto only (a fixed model runs at its own speed)")
    return load_model(model), str(model)


def _head(frames, n):
    """The first n frames of an iterable, stacked."""
    head = []
    for f in frames:
        head.append(f)
        if len(head) == n:
            break
    return np.stack(head)


def prepare_upscale(input, *, model="default", kind: str | None = None, bins: int | None = None, bin_width=None,
                    gate_start=None, span=None, time_unit=None, variable: str | None = None,
                    drop_outside: bool = False, units: str | None = None, min_fps: float | None = None,
                    clip_negative: bool = False, max_memory=None, precision: str = DEFAULT_PRECISION,
                    form: str = DEFAULT_FORM, no_return_logit=None, ambient_alpha=AUTO,
                    keep_returns=AUTO) -> UpscaleJob:
    """Open and check a recording and choose its model, as `jaxsr upscale` does before any output is written.

    input: a path (.npy / .npz array of depth (T, h, w) or photon counts (T, h, w, bins); a folder or glob pattern
    of EXR, PFM, TIFF or 16-bit PNG depth frames; with kind="timetags" a .mat cell array or .npz table of photon
    time tags), or an opened `jaxsr.io.recordings.Recording`, a NumPy array (T, h, w) / (T, h, w, bins), or
    `jaxsr.sensor.TimeTags`. The keyword options are `upscale`'s (see there). Checks, in order: the model (and
    precision and form), then the input and every one of its frames (frames of any size h, w >= 4); an .npz's
    array and time tags' histograms are checked against the memory budget (`max_memory`) before they are read.

    Returns an `UpscaleJob` (its `iter_frames()` streams the result). Raises ValueError, FileNotFoundError (a
    missing input or model) with the messages `jaxsr upscale` prints, TypeError for an input or model of another
    type (None among them).
    """
    fixed, name = _fixed_model(model, min_fps)
    _check_precision_form(fixed, precision, form)
    _check_no_return_logit(fixed, name, no_return_logit)
    _check_ambient_setting(ambient_alpha)  # before the input is read
    if not _is_auto(keep_returns):  # a rate (photons only): "auto" and "default" must not pick a model without a
        # head for histograms, and an "auto" ambient rate gives way to it
        check_keep_returns(keep_returns, None if _is_auto(ambient_alpha) else ambient_alpha,
                           all(_heads(fixed, name, "histograms")))
    span = _span(span)
    time_unit = _positive(time_unit, "time_unit", parse_time_unit, "seconds")
    rec, gate, source, tag_notes = _open(input, kind, bins=bins, bin_width=bin_width, gate_start=gate_start,
                                         span=span, time_unit=time_unit, variable=variable, drop_outside=drop_outside,
                                         clip_negative=clip_negative, max_memory=max_memory)
    if name == "default":  # the bundled model that fits the input
        name = DEFAULT_MODELS[rec.kind]
        fixed = load_model(name)
    inputs = tuple(getattr(getattr(fixed, "config", None), "inputs", ("depth",)))
    if rec.kind != "histograms" and inputs != ("depth",):
        raise ValueError(f"model {name} reads {', '.join(inputs)} per pixel, which depth frames do not hold: give it "
                         "photon histograms or time tags, or choose a depth model (tr0..tr4)")
    r = 4 if fixed is None else _scale(fixed)
    sensor = SensorConfig() if r == 4 else SensorConfig(scale=r)
    if units is not None and units not in DEPTH_UNITS:
        raise ValueError(f"units is one of {', '.join(map(repr, DEPTH_UNITS))}, got {units!r}")
    warnings, negatives = (), None
    if rec.kind == "histograms":
        scale = DepthScale.for_gate(gate, gate.length if span == "gate" else span)
        warnings = tag_notes + tuple(gate_warnings(gate, scale))
        units = "m" if units is None else units
        found = check_frames(rec, units, gate, clip_negative=clip_negative)  # (0, 0) unless clip_negative
        negatives = found if clip_negative else None
        if found[0]:
            warnings += (_clipped_note(*found),)
        counts = clipped_recording(rec) if clip_negative else rec
        # what the photons say, read once (not after --clip-negative: the clipped counts' ambient is no longer
        # the sensor's)
        levels = None if clip_negative else photon_levels(counts, gate.bins)
        marks_no_return = getattr(getattr(fixed, "config", None), "no_return_head", False)
        if levels is not None:
            if marks_no_return:
                warnings += _snr_warnings(_trained_snr_range(None if isinstance(model, Model) else name), levels.snr,
                                          min(HEAD_FRAMES, rec.frames), no_return_logit)
            elif inputs == ("depth",) and getattr(getattr(fixed, "architecture", None), "inputs", "") != "histograms":
                # a model reading depth alone (fixed None: "auto", which picks among TR0-TR4)
                warnings += _few_photons_warnings(levels.signal, min(HEAD_FRAMES, rec.frames))
        if clip_negative and ambient_alpha is not None and not _is_auto(ambient_alpha):
            warnings += (("--ambient-alpha on background-subtracted counts: the test assumes raw counts, whose "
                          "ambient light it looks for, and was measured on those only"),)
        if clip_negative and keep_returns is not None and not _is_auto(keep_returns):
            warnings += (("--keep-returns on background-subtracted counts: its test assumes raw counts, whose "
                          "ambient light it looks for, and was measured on those only"),)
        ambient_alpha, ambient_why = _ambient_choice(ambient_alpha, levels, marks_no_return, rec.frames)
        if _is_auto(keep_returns):  # on for a head, unless the counts are background-subtracted or an ambient
            # rate decides no return instead
            keep_returns = (AUTO_KEEP_RETURNS if marks_no_return and levels is not None and ambient_alpha is None
                            else None)

        def lr_stream():
            return gate_frames(iter_network_inputs(counts, SensorConfig(bins=gate.bins), inputs, chunk=HISTOGRAM_CHUNK),
                               gate, scale)

        def ambient_stream():
            return iter_ambient_only(counts, SensorConfig(bins=gate.bins), alpha=ambient_alpha, frames=AMBIENT_FRAMES)

        def keep_stream():  # each pixel's own photons (pixels=1): a return in the block keeps the block's depth
            return iter_ambient_only(counts, SensorConfig(bins=gate.bins), alpha=keep_returns, pixels=1,
                                     frames=AMBIENT_FRAMES)
    else:
        for what, setting in (("ambient_alpha (--ambient-alpha)", ambient_alpha),
                              ("keep_returns (--keep-returns)", keep_returns)):
            if not _is_auto(setting) and setting is not None:
                raise ValueError(f"{what} tests the photons behind each pixel: give photon histograms or time "
                                 "tags, not depth frames")
        keep_returns = None
        scale = DepthScale(0.0, float(sensor.d_max))
        units = guess_units(rec) if units is None else units
        check_frames(rec, units, gate)

        def lr_stream():
            return normalised_frames(rec, units, sensor)

        gate, ambient_alpha, ambient_why = None, None, ""
    enable_compilation_cache()
    if fixed is None:
        fixed, name = resolve_model("auto", _head(lr_stream(), HEAD_FRAMES), min_fps=min_fps)
    if no_return_logit is not None:
        fixed = with_no_return_logit(fixed, no_return_logit)
        name = f"{name} at no-return logit {float(no_return_logit):g}"
    fixed = in_form(fixed, form, "form (--form)", frames=rec.frames)
    precision = check_precision(fixed, precision, "precision (--precision)")
    label = name
    if ambient_alpha is not None:
        name = f"{name}, no return where ambient alone (alpha {float(ambient_alpha):g}{ambient_why})"
    elif ambient_why:
        name = f"{name}{ambient_why}"
    if keep_returns is not None:
        name = (f"{name}, its no return kept only where the pixel's photons over {AMBIENT_FRAMES} frames pass for "
                f"ambient alone (alpha {float(keep_returns):g})")
    return UpscaleJob(rec, fixed, name, units, gate, scale, warnings, source, lr_stream, negatives, precision,
                      ambient_stream if ambient_alpha is not None else None, ambient_alpha, label,
                      keep_stream if keep_returns is not None else None, keep_returns)


def _trained_snr_range(spec) -> tuple[float, float]:
    """The frame SNRs a photon model was trained on: its card's regime where `spec` names a file that has a valid
    one (None: a model given loaded), else the wide photon regime's (`jaxsr.config.PhotonRegime`), the bundled
    models'."""
    default = tuple(PhotonRegime().snr_range)
    if not isinstance(spec, (str, os.PathLike)):
        return default
    card = read_metadata(resolve_model_path(spec)).get("card")
    regime = card.get("regime") if isinstance(card, dict) else None
    found = regime.get("snr_range") if isinstance(regime, dict) else None
    try:
        lo, hi = (float(x) for x in found)
    except (TypeError, ValueError):  # absent or malformed: a card is metadata, not a reason to fail
        return default
    return (lo, hi) if 0 < lo <= hi < float("inf") else default


# `_snr_warnings` speaks beyond this factor outside the trained SNRs: `frame_snr` reads up to 1.5-3x high from a few
# frames of few bins (noise in the peak's window) and low for moving scenes, so the edge itself is no evidence
SNR_WARNING_MARGIN = 2.0


class PhotonLevels(NamedTuple):
    """What a recording's photons say about it (`photon_levels`): its frame SNR (`jaxsr.sensor.frame_snr`) and
    its signal photons per LR pixel with a return and frame (`jaxsr.sensor.signal_photons`); NaN where no
    return is seen."""

    snr: float
    signal: float


def photon_levels(counts, bins: int) -> PhotonLevels:
    """The `PhotonLevels` of a recording's first HEAD_FRAMES frames of (h, w, bins) counts (any iterable of
    frames), summed frame by frame: one frame's memory, not HEAD_FRAMES'."""
    head, frames = None, 0
    for frame in itertools.islice(counts, HEAD_FRAMES):
        head = np.asarray(frame, np.float32) if head is None else head + frame
        frames += 1
    snr, signal = frame_levels(head, SensorConfig(bins=bins))  # of the sum: one frame's worth of signal
    return PhotonLevels(snr, signal / frames)


def auto_ambient_alpha(snr: float, signal: float = float("nan"), *, min_snr: float = AUTO_AMBIENT_MIN_SNR,
                       min_signal_snr: float = AUTO_AMBIENT_MIN_SIGNAL_SNR) -> float | None:
    """The false-alarm rate `ambient_alpha="auto"` picks for a recording whose frame SNR and signal photons per
    LR pixel and frame (`photon_levels`) are `snr` and `signal`: AUTO_AMBIENT_ALPHA where the SNR is at least
    AUTO_AMBIENT_MIN_SNR or signal x SNR (signal^2 / ambient photons) at least AUTO_AMBIENT_MIN_SIGNAL_SNR; None
    (no test) elsewhere and where no return is seen (NaN). Below both, the summed photons of a faint return no
    longer stand out from the ambient light, and the test cost the paper's TR4 PSNR on the test scenes; from
    either up it cost at most 0.33 dB there, and gained up to 0.8 dB on sky at many photons and low SNR
    (experiments/results/upscale_defaults.md). min_snr, min_signal_snr: the two thresholds (the study that
    chose them scores others)."""
    tested = snr >= min_snr or signal * snr >= min_signal_snr  # NaN compares False
    return AUTO_AMBIENT_ALPHA if tested else None


def _is_auto(setting) -> bool:
    return isinstance(setting, str) and setting == AUTO


def _check_ambient_setting(setting) -> None:
    """Refuse an `ambient_alpha` that is not "auto", None or a false-alarm rate in range."""
    if isinstance(setting, str) and setting != AUTO:
        raise ValueError(f"ambient_alpha (--ambient-alpha) is 'auto', None (off) or a false-alarm rate such as 0.001, "
                         f"got {setting!r}")
    if setting is not None and not _is_auto(setting):
        check_false_alarm_rate("ambient_alpha (--ambient-alpha)", setting)


def _ambient_choice(setting, levels: PhotonLevels | None, marks_no_return: bool,
                    frames: int) -> tuple[float | None, str]:
    """`ambient_alpha` as set (None, a rate) or, for "auto", `auto_ambient_alpha` of the recording's levels;
    and the words that say why, for the model's name ("" where set). "auto" is off where the rule was not measured
    to hold: background-subtracted counts (`levels` None: their ambient light is gone), a model with a no-return
    head (it marks no return itself, and the test cost tr4-photons 4.9 dB at worst), fewer than
    AUTO_AMBIENT_MIN_FRAMES frames (the SNR reads high)."""
    if not _is_auto(setting):
        return setting, ""
    if levels is None:
        return None, " (ambient test off: background-subtracted counts)"
    if marks_no_return:
        return None, " (ambient test off: the model marks no return itself)"
    if frames < AUTO_AMBIENT_MIN_FRAMES:
        return None, (f" (ambient test off: {frames} frames, too few to read the SNR; --ambient-alpha 0.001 "
                      "sets it)")
    if np.isnan(levels.snr):
        return None, " (ambient test off: no return seen)"
    shown = ("no ambient light seen" if np.isinf(levels.snr) else
             f"frame SNR about {levels.snr:.2g}, {levels.signal:.3g} signal photons per pixel and frame")
    alpha = auto_ambient_alpha(levels.snr, levels.signal)
    if alpha is None:
        return None, (f" (ambient test off: {shown}, SNR below {AUTO_AMBIENT_MIN_SNR:g} and signal x SNR below "
                      f"{AUTO_AMBIENT_MIN_SIGNAL_SNR:g})")
    return alpha, f"; auto: {shown}"


def _few_photons_warnings(signal: float, frames: int) -> tuple[str, ...]:
    """A hint where a model reading depth alone gets a recording of fewer than FEW_PHOTONS signal photons per
    pixel and frame (`photon_levels`), where the paper's models fall below bicubic."""
    if not signal < FEW_PHOTONS:  # NaN (no return seen): nothing to say
        return ()
    return ((f"about {signal:.2g} signal photons per pixel and frame (first {frames} frames): below "
             f"{FEW_PHOTONS:g} a model reading depth alone falls behind; tr4-ambient, the default model of "
             "histograms and time tags (--model default), also reads the photons behind each depth (check a frame, "
             "--preview; docs/results/real-photons.md)"),)


def _snr_warnings(trained: tuple[float, float], snr: float, frames: int, no_return_logit=None) -> tuple[str, ...]:
    """A warning where the recording's frame SNR (`photon_levels`) lies well outside (SNR_WARNING_MARGIN) the SNRs
    a model with a no-return head was trained on: its threshold is then a guess; with a threshold given
    (`no_return_logit`), the SNR alone is said."""
    lo, hi = trained
    if np.isnan(snr) or lo / SNR_WARNING_MARGIN <= snr <= hi * SNR_WARNING_MARGIN:  # NaN: no return seen, nothing to say
        return ()
    shown = "no ambient light seen" if snr == float("inf") else f"about {snr:.3g}"
    if no_return_logit is not None:
        advice = f"its no-return threshold is set to {float(no_return_logit):g}: check a frame (--preview)"
    elif snr > hi:
        advice = ("with little ambient light its no-return head may mark dim returns as no return; a higher "
                  "--no-return-logit (such as 2) keeps them and shows more sky as depth")
    else:
        advice = ("with this much ambient light it may show sky as depth; a lower --no-return-logit marks more "
                  "pixels as no return")
    return ((f"the recording's frame SNR (signal / ambient photons, first {frames} frames) is {shown}, well "
             f"outside the {lo:g}-{hi:g} this model was trained on: {advice} (docs/network.md, choosing the "
             "threshold)"),)


def _check_no_return_logit(model, name: str, logit) -> None:
    """Refuse a no-return threshold before the input is read: for a model without a no-return head, and for
    "auto" and "default" while none of the models they pick has one."""
    if logit is None:
        return
    if model is not None:
        with_no_return_logit(model, logit)  # raises for a model without the head, or a logit not finite
        return
    if not any(_heads(None, name)):
        raise ValueError(f"no_return_logit (--no-return-logit) applies to models with a no-return head; --model {name} "
                         f"picks {' or '.join(_picks(name))}, which have none: name one that has, such as tr4-ambient")


def _picks(name: str, kind: str | None = None) -> list[str]:
    """The bundled models that "auto" or "default" may pick (for input of `kind`, where given)."""
    if name == "auto":
        return [f"tr{k}" for k in range(5)]
    return [DEFAULT_MODELS[kind]] if kind else sorted(set(DEFAULT_MODELS.values()))


def _heads(model, name: str, kind: str | None = None) -> list[bool]:
    """Whether the model has a no-return head: [that of `model`], or for "auto" and "default" (model None) one
    per model they may pick (for input of `kind`, where given), read from the bundled files' metadata."""
    if model is not None:
        return [bool(getattr(getattr(model, "config", None), "no_return_head", False))]
    return [read_metadata(resolve_model_path(p))["config"].get("no_return_head", False) for p in _picks(name, kind)]


def _check_precision_form(model, precision, form) -> None:
    """Refuse an unknown precision or form before the input is read (they are checked against the model once it is
    known: a baseline takes neither bfloat16 nor a DUF form)."""
    if not isinstance(precision, str) or precision not in PRECISIONS:
        raise ValueError(f"precision (--precision) is one of {', '.join(map(repr, PRECISIONS))}, got {precision!r}")
    if not isinstance(form, str) or form not in FORMS:
        raise ValueError(f"form (--form) is one of {', '.join(map(repr, FORMS))}, got {form!r}")
    if isinstance(model, Model):
        check_precision(model, precision, "precision (--precision)")
        in_form(model, form, "form (--form)")


def _plural(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _clipped_note(counts: int, pixels: int) -> str:
    """The warning on negative counts clipped (--clip-negative): how many, in how many pixels."""
    return (f"{_plural(counts, 'negative count')} in {_plural(pixels, 'pixel')} clipped at 0 (--clip-negative: "
            "background-subtracted histograms)")


def _reference(reference, job: UpscaleJob):
    """The reference (ground truth) for the video, opened and checked against the job: (recording, units).
    A path (as INPUT's depth formats), a `Recording` or a NumPy array (T, H, W) of HR depth in metres or
    normalised on the job's scale; T frames of the output's (H, W)."""
    if isinstance(reference, Recording):
        rec = reference
    elif isinstance(reference, np.ndarray):
        rec = _array_recording(reference, "depth")
    else:
        rec = open_recording(reference, kind="depth")
    where = f"reference {getattr(rec, 'source', 'array')}"
    if rec.kind != "depth":
        raise ValueError(f"{where}: the reference is depth (T, H, W), not {rec.kind}")
    if rec.frames != job.frames or tuple(rec.shape) != job.hr_shape:
        raise ValueError(f"{where}: {rec.frames} frames of {tuple(rec.shape)}; the output has {job.frames} frames "
                         f"of {job.hr_shape}")
    return rec, guess_units(rec, ask="give the reference as float metres or normalised depth")


def _metres(frame, units, scale):
    """A reference frame in `units` -> radial metres, inf for no return (normalised: on the job's scale)."""
    frame = np.asarray(frame, np.float32)
    if units == "normalised":
        return to_units(np.where(np.isnan(frame), 1.0, frame), "m", scale)
    return np.where(np.isnan(frame) | (frame < 0), np.inf, frame).astype(np.float32)


def write_upscaled(job: UpscaleJob, output, *, frame_format: str | None = None, batch_size: int | None = None,
                   preview=None, video=None, fps: float | None = None, reference=None, points=None,
                   fov_deg: float = DEFAULT_FOV_DEG, points_colour: str | None = "depth", overwrite: bool = False,
                   progress: bool = False, max_memory=None) -> UpscaleResult:
    """Run a prepared job (`prepare_upscale`) and write its result, as `jaxsr upscale` does.

    output: an .npy file (written through a memory map), an .npz (`jaxsr.io.write_sequence`, with units, model,
    input and scale as metadata), a folder (one `frame_format` file per frame, frame_000000.exr ..., always
    metres; missing parent folders are created; frame_format: "exr" by default, "pfm", "tif" or "png", refused
    for any other output, and "png" for a range starting beyond its 65.535 m, deeper pixels counted in a
    warning), or None (the (T, H, W) result is returned in `depth`).
    Everything is written atomically (a folder into a hidden `.NAME.WRITER-PID.XXXXXXXX.partial` sibling, renamed
    when complete; `jaxsr.io.atomic_folder`); an interrupted or failed run leaves nothing. preview: a .png strip
    of the middle frame, input | output.
    video (--video): an .mp4 or .gif of every frame, input (nearest-neighbour upscaled) | output | reference
    (`jaxsr.io.write_depth_video`), at `fps` frames/s (--fps; default the recording's where its file says, else
    25); reference (--reference): HR depth (T, H, W) to show beside them, a path as INPUT's depth formats or an
    array, in metres or normalised on the job's scale. points (--points): a folder of PLY point clouds, one per
    frame (`jaxsr.io.write_point_clouds`), over a horizontal field of view of `fov_deg` degrees (--fov; default
    the sensor model's 30), coloured by depth (points_colour "depth") or not (None). Previews, videos and point
    clouds show the sensor's true range in metres (`UpscaleJob.d_range`: the gate's start included).
    overwrite (--force): replace an existing output, preview and video, or write into a non-empty folder.
    batch_size: frames per compiled call (default: see `iter_super_resolve`; at most the recording's frames).
    progress: a tqdm progress bar. max_memory (--max-memory): the memory the work may take, bytes or a size such as
    "16GB" (default `jaxsr.checks.memory_budget`: a share of this machine's RAM); `upscale_memory` estimates it
    before any work, and a job beyond it is refused (ValueError: the estimate and what would need less).

    Returns an `UpscaleResult`. Raises FileExistsError, IsADirectoryError, NotADirectoryError, FileNotFoundError,
    `jaxsr.io.NotWritableError` or ValueError for an output, preview, video, reference or point clouds' folder
    that cannot be written or read, or a symbolic link among them (checked before any work).
    """
    batch_size = _batch_size(job, batch_size)
    _check_look_options(video, fps, reference, points, points_colour)
    out = None if output is None else check_output(output, force=overwrite)
    frame_format = _frame_format(frame_format, out, job)
    preview = None if preview is None else check_preview(preview, force=overwrite, output=out)
    video = None if video is None else check_video(video, force=overwrite, output=out)
    points = None if points is None else check_points_folder(points, force=overwrite, output=out)
    ref = None if reference is None else _reference(reference, job)
    _check_memory(job, out, batch_size, video is not None or points is not None, max_memory)
    rec, scale = job.recording, job.scale
    d_min, d_max = job.d_range
    shape = (job.frames, *job.hr_shape)
    preview_t = job.frames // 2
    preview_lr, preview_hr = [], []  # the preview's frames, kept as they stream past (no second pass)
    lr_ahead = collections.deque()  # the video's LR frames, from the model's input until its output comes
    input_label = "input (centre of mass)" if rec.kind == "histograms" else "input"

    def keep_preview(frames):
        for t, f in enumerate(frames):
            depth = f[..., 0] if f.ndim == 3 else f  # a photon model's input: depth in channel 0
            if t == preview_t:
                preview_lr.append(depth)
            if video is not None:
                lr_ahead.append(depth)
            yield f

    stream = job.iter_normalised(batch_size=batch_size, lr_frames=keep_preview(job.lr_frames()))
    if progress:
        stream = tqdm(stream, total=job.frames, unit="frame", desc="upscale")

    with contextlib.ExitStack() as looks:  # the video and point clouds: committed after the output
        film = clouds = None
        if video is not None:
            labels = (input_label, job.label or job.model_name) + (() if ref is None else ("reference",))
            rate = fps if fps is not None else job.fps if job.fps is not None else DEFAULT_FPS
            film = looks.enter_context(DepthVideoWriter(video, job.hr_shape, labels=labels, fps=rate, d_min=d_min,
                                                        d_max=d_max, frames=job.frames, overwrite=overwrite))
        if points is not None:
            clouds = looks.enter_context(PointCloudWriter(points, fov_deg=fov_deg, colour=points_colour,
                                                          d_min=d_min, d_max=d_max, overwrite=overwrite))
        ref_frames = None if ref is None else iter(ref[0])

        def frames(units):
            for t, hr in enumerate(stream):
                if t == preview_t:
                    preview_hr.append(hr)
                if film is not None or clouds is not None:
                    metres = to_units(hr, "m", scale)
                    if film is not None:
                        panels = [to_units(lr_ahead.popleft(), "m", scale), metres]
                        if ref_frames is not None:
                            panels.append(_metres(next(ref_frames), ref[1], scale))
                        film.write(*panels)
                    if clouds is not None:
                        clouds.write(metres)
                yield t, to_units(hr, units, scale)

        def finish():  # inside the output's atomic block: a failed preview or video leaves no output either
            if preview is not None:
                write_comparison(preview, to_units(preview_lr[0], "m", scale), to_units(preview_hr[0], "m", scale),
                                 d_min=d_min, d_max=d_max, labels=(input_label, job.label or job.model_name),
                                 overwrite=overwrite)
            if film is not None:
                film.finish()

        depth, saturated = None, 0
        if out is None:
            depth = np.empty(shape, np.float32)
            for t, f in frames(job.units):
                depth[t] = f
            finish()
        elif out.suffix.lower() == ".npy":  # streamed to disk: memory for a batch, not for the whole result
            with atomic_path(out, overwrite=overwrite) as tmp:
                result = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.float32, shape=shape)
                reserve_space(tmp)  # a full disk: ENOSPC now, not SIGBUS when a page of the map is written
                for t, f in frames(job.units):
                    result[t] = f
                result.flush()
                del result
                finish()
        elif out.suffix.lower() in ARRAY_FORMATS:
            result = np.empty(shape, np.float32)
            for t, f in frames(job.units):
                result[t] = f
            with atomic_path(out, overwrite=overwrite) as tmp:
                write_sequence(tmp, result, overwrite=True, units=job.units, model=job.model_name, input=job.source,
                               scale=_scale(job.model))
                finish()
        else:
            with atomic_folder(out, overwrite=overwrite) as tmp:
                for t, f in frames("m"):
                    write_depth(tmp / f"frame_{t:06d}.{frame_format}", f)
                    if frame_format == "png":
                        saturated += np.count_nonzero(np.isfinite(f) & (f > PNG_MAX_M))
                finish()
    late = (_saturated_note(saturated),) if saturated else ()
    warnings = job.warnings + late
    notes = tuple(f"warning: {w}" for w in job.warnings) + (job.note,) + tuple(f"warning: {w}" for w in late)
    units = "m" if out is not None and out.suffix.lower() not in ARRAY_FORMATS else job.units
    return UpscaleResult(out, depth, job.frames, shape, rec.kind, units, job.model_name, job.gate, scale, preview,
                         warnings, notes, video, points, job.negative_counts, None if units == job.units else job.units,
                         job.ambient_alpha, job.keep_returns)


def _frame_format(frame_format: str | None, out: Path | None, job: UpscaleJob) -> str | None:
    """The frame files' format for a folder OUTPUT (default "exr"); refused for any other output, where it would
    do nothing, and "png" for a range that starts beyond 16-bit PNG's 65.535 m (every pixel would saturate)."""
    folder = out is not None and out.suffix.lower() not in ARRAY_FORMATS
    if frame_format is None:
        return "exr" if folder else None
    if frame_format not in FRAME_FORMATS:
        raise ValueError(f"frame_format (--frame-format) is one of {', '.join(FRAME_FORMATS)}, got {frame_format!r}")
    if not folder:
        raise ValueError(f"frame_format (--frame-format) applies to a folder OUTPUT (one file per frame), not "
                         f"{'an output kept in memory' if out is None else out}")
    if frame_format == "png" and job.d_range[0] >= PNG_MAX_M:
        raise ValueError(f"16-bit PNG frames hold depth up to {PNG_MAX_M} m, and this recording's range starts at "
                         f"{job.d_range[0]:g} m (the gate's start): choose --frame-format exr, pfm or tif")
    return frame_format


def _saturated_note(pixels: int) -> str:
    """The warning on depth beyond 16-bit PNG's range, written as its largest value."""
    return (f"{_plural(pixels, 'pixel')} beyond {PNG_MAX_M} m written as {PNG_MAX_M} m (16-bit PNG's largest "
            "depth); --frame-format exr, pfm or tif store them")


def _network_bytes_per_pixel(model, batch_size: int = 1) -> float:
    """Bytes a model holds per LR pixel of a tile and frame of the batch while it runs (see `NETWORK_BYTES_TR4`):
    a window of features per output frame, or in the sequence form the chunk's batch_size + 2R frames shared by
    its batch_size outputs."""
    cfg = model.config
    try:
        if model.architecture.sequence_form(cfg):
            window = (batch_size + 2 * cfg.input_radius) / batch_size
        else:
            window = model.architecture.frames(cfg)
        blocks = 8 * window * (cfg.base + (cfg.same_blocks + cfg.tr) * cfg.growth)
        return blocks + 4 * (cfg.head + cfg.filter_hidden + cfg.filter_size**2 * cfg.scale**2)
    except AttributeError:  # not the DUF network
        return NETWORK_BYTES_TR4


def upscale_memory(job: UpscaleJob, *, batch_size: int, in_memory: bool, looks: bool = False) -> float:
    """Bytes `write_upscaled` is estimated to need at its peak, from the job's sizes alone (nothing is run):
    `BASE_BYTES`; the input where it is held whole (an .npz's array, time tags' histograms; an .npy is
    memory-mapped); histogram frames on their way to the network (`HISTOGRAM_CHUNK` x `HISTOGRAM_COPIES`); the
    network on one tile (at most `DEFAULT_TILE` LR pixels a side) per frame of the batch; with `ambient_alpha` or
    `keep_returns`, three copies of the `AMBIENT_FRAMES` histogram frames its test holds; the HR frames of two
    batches (the one computed and the one drained; twice over with `keep_returns`: depth and logit) and of a
    frame converted; and the whole result when it is
    held (`in_memory`: an .npz output or none) or drawn (`looks`: the video's panels or a point cloud per
    frame). Measured peaks were 0.6-0.9x of it (frames of 32 x 64 to 2048 x 2048 LR pixels, batches of 1-8)."""
    rec, model = job.recording, job.model
    h, w = (int(v) for v in rec.shape[:2])
    hr = 4.0 * job.hr_shape[0] * job.hr_shape[1]
    need = BASE_BYTES
    if rec.array is not None and not isinstance(rec.array, np.memmap):
        need += rec.array.nbytes
    if rec.kind == "histograms":
        need += HISTOGRAM_COPIES * HISTOGRAM_CHUNK * 4.0 * h * w * int(rec.shape[-1])
    if job._ambient_stream is not None or job._keep_stream is not None:
        # the frames held, their stack and the padded sums of `ambient_only`
        need += 3 * AMBIENT_FRAMES * 4.0 * h * w * int(rec.shape[-1])
    channels = len(getattr(model.config, "inputs", ("depth",)))
    radius = model.architecture.input_radius(model.config)
    tile = min(h, DEFAULT_TILE) * min(w, DEFAULT_TILE)
    need += (batch_size * tile * _network_bytes_per_pixel(model, batch_size)
             + 3 * (batch_size + 2 * radius) * 4.0 * h * w * channels)
    need += (2 * batch_size + 1) * hr * (2 if job._keep_stream is not None else 1)  # raw: depth and logit
    need += (job.frames * hr if in_memory else 0) + (6 * hr if looks else 0)
    return need


def _batch_size(job: UpscaleJob, batch_size: int | None) -> int:
    """Frames per compiled call: `batch_size` (default as `iter_super_resolve`'s) but no more than the
    recording's frames (a larger batch would be padded with copies of the last frame)."""
    if batch_size is not None and int(batch_size) < 1:
        raise ValueError(f"batch_size: expected an integer >= 1, got {batch_size}")
    sequence_form = job.model.architecture.sequence_form(job.model.config)
    size = _default_batch_size(range(job.frames), sequence_form) if batch_size is None else int(batch_size)
    return min(size, job.frames)


def _check_memory(job: UpscaleJob, out, batch_size: int, looks: bool, max_memory) -> None:
    """Refuse a job whose `upscale_memory` exceeds the budget (`jaxsr.checks.require_memory`), naming its sizes and
    what would need less."""
    in_memory = out is None or out.suffix.lower() == ".npz"
    need = upscale_memory(job, batch_size=batch_size, in_memory=in_memory, looks=looks)
    ways = ([f"a smaller --batch-size (now {batch_size})"] if batch_size > 1 else []) + (
        ["an .npy or folder OUTPUT (written frame by frame, not held)"] if in_memory and job.frames > 1 else []) + (
        ["--ambient-alpha off (its test sums 9 frames)"] if job.ambient_alpha is not None else [])
    frame = " x ".join(map(str, job.recording.shape))
    what = (f"upscaling {job.frames} frame{'s' if job.frames > 1 else ''} of {frame} to {job.hr_shape[0]} x "
            f"{job.hr_shape[1]}")
    require_memory(need, what, max_memory, remedy="give " + " or ".join(ways) if ways else "")


def _check_look_options(video, fps, reference, points, points_colour):
    """Options that need another: --fps and --reference need --video; a frame rate > 0; a known colouring."""
    if video is None:
        for name, value in (("--fps", fps), ("--reference", reference)):
            if value is not None:
                raise ValueError(f"{name} applies to --video only")
    if fps is not None and not (np.isfinite(float(fps)) and float(fps) > 0):
        raise ValueError(f"fps (--fps): expected frames per second > 0, got {fps}")
    if points_colour not in ("depth", None):
        raise ValueError(f"points_colour: 'depth' or None, got {points_colour!r}")


def upscale(input, output, *, model="default", kind: str | None = None, bins: int | None = None, bin_width=None,
            gate_start=None, span=None, time_unit=None, variable: str | None = None, drop_outside: bool = False,
            units: str | None = None, frame_format: str | None = None, batch_size: int | None = None,
            min_fps: float | None = None, preview=None, video=None, fps: float | None = None, reference=None,
            points=None, fov_deg: float = DEFAULT_FOV_DEG, points_colour: str | None = "depth",
            overwrite: bool = False, progress: bool = False, clip_negative: bool = False, max_memory=None,
            report: Callable[[str], None] | None = None, precision: str = DEFAULT_PRECISION,
            form: str = DEFAULT_FORM, no_return_logit=None, ambient_alpha=AUTO,
            keep_returns=AUTO) -> UpscaleResult:
    """Super-resolve a recording x4 with a trained model and write it: `jaxsr upscale INPUT OUTPUT` in one call.

    input: a path (.npy / .npz array of depth (T, h, w) or photon counts (T, h, w, bins); a folder or glob
    pattern of EXR, PFM, TIFF or 16-bit PNG depth frames; photon time tags with kind="timetags": a MATLAB v4-v7
    .mat cell array of per-pixel arrival times, or an .npz table 'pixel', 'time', 'shape'), or a `Recording`,
    a NumPy array or `TimeTags` (see `prepare_upscale`). output: .npy / .npz, a folder of frames, or None (the
    result is returned in `UpscaleResult.depth`, (T, H, W) float32). Options, keyword-only, as the command's:

    - model (--model): "default" (the bundled model that fits the input, `DEFAULT_MODELS`: tr4 for depth,
      tr4-ambient for histograms and time tags), "tr0".."tr4" (bundled weights; "paper-tr0".."paper-tr4" always the
      paper's), "auto" (the TR `choose_tr` picks from the motion of the first 64 frames, within min_fps), a
      checkpoint path, or a `Model`; a model reading photons (`ModelConfig.inputs`) needs histograms or time tags.
    - kind (--input): "depth", "histograms" or "timetags" (default: depth or histograms from the data).
    - bins, bin_width, gate_start, span (histograms and time tags): the gate, K bins (default 16) of bin_width
      from gate_start; bin_width and gate_start are metres or strings with a unit ("12.5ns", "2.19m"; a time
      converts as r = c t / 2), default 35 m / 16 from 0 (for time tags: the photons' span); span: metres mapped
      onto the network's [0, 1] (default 35, the models' training range) or "gate" (the gate's length).
    - time_unit (--time-unit, time tags): seconds per time unit, or a string such as "1ps"; variable: the .mat
      cell array to read; drop_outside: ignore photons outside the gate (default: refuse them).
    - clip_negative (--clip-negative, histograms): clip negative counts at 0 (background-subtracted histograms,
      as some published data are) and say how many, in how many pixels (a warning, and
      `UpscaleResult.negative_counts`); default: refuse them, as raw photon counts are never negative.
    - units (--units): "m" (radial metres, inf = no return), "mm", "cm" or "km" (radial distance in those units;
      0 is no return too in mm and cm, as in 16-bit depth images) or "normalised" ([0, 1], 1 = no return) of input
      and output (array outputs in mm, cm or km are float32, inf = no return); default (`guess_units`): normalised
      if the first frame lies in [0, 1], else metres, refused (a ValueError asking for units) for integer arrays
      (millimetres? centimetres?) and for values that could be kilometres; histograms give metres.
    - frame_format (--frame-format): "exr" (default), "pfm", "tif" or "png" for a folder output (always metres),
      refused for any other; 16-bit PNG holds 1 mm .. 65.535 m: a range starting beyond is refused, and deeper
      pixels are written as 65.535 m with a warning that counts them.
    - precision (--precision): how the network's convolutions multiply, "default" (the backend's: float32 on
      CPU), "float32" or "bfloat16" (bfloat16 operands, float32 sums; `jaxsr.config.PRECISIONS`), for the DUF
      network only; default `DEFAULT_PRECISION` (docs/cli.md says when bfloat16 pays).
    - form (--form): the temporal form the DUF network runs in (`jaxsr.inference.video.FORMS`): "auto" (default:
      the bundled windowed depth models of `SEQUENCE_FORM_TRS` in the sequence form on recordings of at least
      `SEQUENCE_FORM_MIN_FRAMES` frames, else the model's own), "model", "window" or "sequence".
    - no_return_logit (--no-return-logit): for a model with a no-return head (tr4-ambient, tr4-photons, ...), the
      logit above which a pixel is output as no return (`jaxsr.nn.with_no_return_logit`; default the model's
      own, 0.0 = p 0.5): higher drops fewer true returns and leaves more of the sky as depth. Refused for a
      model without the head.
    - ambient_alpha (--ambient-alpha, histograms and time tags): also output no return wherever the photons of
      3 x 3 pixels and 9 frames around a pixel pass for ambient light alone at this false-alarm rate
      (`jaxsr.sensor.ambient_only`), with any model: it empties the insides of sky and absorbing regions, and
      drops returns too faint to stand out even summed. "auto" (default): `AUTO_AMBIENT_ALPHA` where the
      recording's frame SNR (`photon_levels`) is at least `AUTO_AMBIENT_MIN_SNR` or its signal photons per pixel
      and frame times that SNR at least `AUTO_AMBIENT_MIN_SIGNAL_SNR` (`auto_ambient_alpha`), else off; off too for
      background-subtracted counts (`clip_negative`), for a model with a no-return head and for recordings of
      fewer than `AUTO_AMBIENT_MIN_FRAMES` frames; the model's name in `notes` says which and why, and
      `UpscaleJob.ambient_alpha` / the summary's "ambient_alpha" the rate. None: off. Depth input: "auto" is off,
      a rate is refused.
    - keep_returns (--keep-returns, histograms and time tags, a model with a no-return head): a false-alarm rate
      such as 0.001; output no return only where the model's head says so AND the pixel's own photons over 9
      frames pass for ambient light alone at it (`jaxsr.inference.overrule_no_return`), elsewhere the network's depth:
      for dark scenes whose dim surfaces a head calls sky. It gives up some sky at the edges of sky regions.
      "auto" (default): `AUTO_KEEP_RETURNS` for a model with a no-return head (the default model of histograms
      and time tags has one), off for a model without, for depth, beside an `ambient_alpha` rate and for
      background-subtracted counts. None: off, the head decides alone. A rate is refused with an `ambient_alpha`
      rate and for a model without a head.
    - batch_size (--batch-size): frames per compiled call (output frames per chunk in the sequence form);
      min_fps (--min-fps, model="auto" only): the slowest acceptable frames/s; preview (--preview): an input |
      output PNG strip of the middle frame; overwrite (--force): replace output, preview and video; progress
      (not --no-progress): show a progress bar.
    - video (--video), fps (--fps), reference (--reference): an .mp4 / .gif of every frame, input | output |
      reference, one colour scale in metres; points (--points), fov_deg (--fov), points_colour: a folder of PLY
      point clouds, one per frame (see `write_upscaled`).
    - max_memory (--max-memory): the memory the command may take, bytes or a size such as "16GB" (default: a
      share of this machine's RAM, `jaxsr.checks.memory_budget`); an .npz input's array, time tags' histograms
      and the work (`upscale_memory`) are estimated before they allocate and refused beyond it.
    - report: called with each line of `notes` as soon as it is known (the warnings, then what is read with which
      model, before the network runs; after the writing, a warning on what it found, such as PNG depth saturated);
      `jaxsr upscale` prints them.

    Everything is checked before the model runs, in order: the output, preview, video and point clouds' paths
    (and that the reference reads), the model, the input and every frame. Returns an `UpscaleResult` (output
    path, frames, shape, units, model, gate, scale, warnings, notes, video, points; `summary()` is the command's
    JSON). Raises FileNotFoundError (missing input, model, reference or output folder), FileExistsError (an
    output, preview or video exists, or the point clouds' folder holds files, without overwrite), IsADirectoryError, NotADirectoryError or
    ValueError (bad options or input), with the messages `jaxsr upscale` prints, TypeError (an input or model of
    another type, None among them), or `jaxsr.io.WriteError` (the disk refused a write: full, over quota, ...);
    nothing is left written then.
    """
    _check_look_options(video, fps, reference, points, points_colour)
    memory_budget(max_memory)  # a bad size is refused before anything is read
    out = None if output is None else check_output(output, force=overwrite)
    if preview is not None:
        check_preview(preview, force=overwrite, output=out)
    if video is not None:
        check_video(video, force=overwrite, output=out)
    if points is not None:
        check_points_folder(points, force=overwrite, output=out)
        PointCloudWriter(points, fov_deg=fov_deg, overwrite=overwrite)  # checks the field of view
    if reference is not None and not isinstance(reference, (np.ndarray, Recording)):
        open_recording(reference, kind="depth")  # exists and reads (its frames are checked against the job's later)
    job = prepare_upscale(input, model=model, kind=kind, bins=bins, bin_width=bin_width, gate_start=gate_start,
                          span=span, time_unit=time_unit, variable=variable, drop_outside=drop_outside,
                          units=units, min_fps=min_fps, clip_negative=clip_negative, max_memory=max_memory,
                          precision=precision, form=form, no_return_logit=no_return_logit,
                          ambient_alpha=ambient_alpha, keep_returns=keep_returns)
    # before the lines below, which say the work starts (write_upscaled checks again, for its own callers)
    _frame_format(frame_format, out, job)
    _check_memory(job, out, _batch_size(job, batch_size), video is not None or points is not None, max_memory)
    early = tuple(f"warning: {w}" for w in job.warnings) + (job.note,)
    for line in early if report is not None else ():
        report(line)
    result = write_upscaled(job, output, frame_format=frame_format, batch_size=batch_size, preview=preview,
                            video=video, fps=fps, reference=reference, points=points, fov_deg=fov_deg,
                            points_colour=points_colour, overwrite=overwrite, progress=progress,
                            max_memory=max_memory)
    for line in result.notes[len(early):] if report is not None else ():  # what the writing found
        report(line)
    return result
