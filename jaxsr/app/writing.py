"""The second half of `jaxsr upscale`: run a prepared job (`jaxsr.app.prepare_upscale`) and write its result
atomically, with what `Writing` asks for beside it (a preview, a video, point clouds), frame by frame
(`write_upscaled`); `UpscaleResult` says what was done.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
from pathlib import Path
from typing import Callable

import numpy as np
from tqdm.auto import tqdm

from ..config import DepthScale, Gate
from ..io.files import atomic_folder, atomic_path, reserve_space
from ..io.formats import PNG_MAX_M, write_depth, write_sequence
from ..io.pointcloud import PointCloudWriter
from ..io.previews import write_comparison
from ..io.video import DEFAULT_FPS, DepthVideoWriter
from .job import UpscaleJob, array_recording
from .memory import batch_size_of, check_memory
from .outputs import Outputs, check_outputs
from .recordings import Recording, guess_units, open_recording, to_units
from .specs import FRAME_FORMATS, Writing, check_fps

__all__ = ["UpscaleResult", "write_upscaled"]


@dataclasses.dataclass(frozen=True)
class UpscaleResult:
    """What `upscale` / `write_upscaled` did. output: the file or folder written (None when kept in memory);
    depth: the (T, H, W) float32 result in `units` when no output was written, else None; frames: T; shape:
    (T, H, W); kind: "depth" or "histograms"; units: of the output's values (an array's: the input's units; a
    folder of frames: always "m"); model: the model's name (a bundled name or the path given, which --model takes
    back); model_description: how it was chosen and set, as people read it; gate, scale: the histogram gate and depth
    scale (gate None for depth); preview: the PNG written, or None; warnings: sentences on what the models never
    saw and on what the writing found; notes: every line `jaxsr upscale` prints to stderr (warnings as "warning:
    ...", then what was read with which model, then warnings on what the writing found); video: the side-by-side
    video written, or None; points: the folder of PLY point clouds, or None; negative_counts: with
    `clip_negative`, (negative counts clipped at 0, pixels holding one), else None; input_units: the input's
    units (`UpscaleJob.units`), where they differ from `units`; ambient_alpha: the ambient-only test's
    false-alarm rate (`UpscaleJob.ambient_alpha`, None: no test); keep_returns: `upscale`'s keep_returns rate
    (`UpscaleJob.keep_returns`; in the summary only when set); confidence, depth_std: for photon histograms and
    time tags kept in memory (output None), the (T, H, W) float32 probability that each pixel holds a return, in
    [0, 1], and its depth's standard deviation in metres (NaN where no return is output), else None
    (`jaxsr.inference.confidence`; an .npz output holds them as arrays "confidence" and "depth_std", an .npy
    output has them beside it as OUT.confidence.npy and OUT.depth_std.npy); confidence_files: those side files."""

    output: Path | None
    depth: np.ndarray | None
    frames: int
    shape: tuple[int, int, int]
    kind: str
    units: str
    model: str
    model_description: str
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
    confidence: np.ndarray | None = None
    depth_std: np.ndarray | None = None
    confidence_files: tuple[Path, ...] = ()

    def summary(self) -> dict:
        """The JSON summary `jaxsr upscale` prints: frames, output, shape, units (of the output; input_units too
        where the input's differ), model and model_description, for histograms the gate, the depth scale (metres) and the ambient-only
        test's rate (null: none) and `keep_returns`' where set, the preview, the video and the point clouds' file or
        folder where written, and with --clip-negative the negative counts clipped and the pixels holding them."""
        out = {"frames": self.frames, "output": None if self.output is None else str(self.output),
               "shape": list(self.shape), "units": self.units, "model": self.model,
               "model_description": self.model_description}
        if self.input_units is not None:
            out["input_units"] = self.input_units
        if self.preview is not None:
            out["preview"] = str(self.preview)
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
        if self.confidence_files:
            out["confidence_files"] = [str(p) for p in self.confidence_files]
        return out


def _reference(reference, job: UpscaleJob):
    """The reference (ground truth) for the video, opened and checked against the job: (recording, units).
    A path (as INPUT's depth formats), a `Recording` or a NumPy array (T, H, W) of HR depth in metres or
    normalised on the job's scale; T frames of the output's (H, W)."""
    if isinstance(reference, Recording):
        rec = reference
    elif isinstance(reference, np.ndarray):
        rec = array_recording(reference, "depth")
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


def write_upscaled(job: UpscaleJob, output, write: Writing = Writing(), *, batch_size: int | None = None,
                   progress: bool = False, max_memory=None,
                   report: Callable[[str], None] | None = None) -> UpscaleResult:
    """Run a prepared job (`prepare_upscale`) and write its result, as `jaxsr upscale` does.

    output: an .npy file (written through a memory map), an .npz (`jaxsr.io.write_sequence`, with units, model,
    input and scale as metadata), a folder (one `Writing.frame_format` file per frame, frame_000000.exr ...,
    always metres; missing parent folders are created), None (the (T, H, W) result is returned in
    `UpscaleResult.depth`), or `Outputs` already checked with `write` (`check_outputs`). write: what is written
    beside it (`Writing`: preview, video and reference, point clouds, overwrite). Everything is written atomically
    (a folder into a hidden `.NAME.WRITER-PID.XXXXXXXX.partial` sibling, renamed when complete); an interrupted or
    failed run leaves nothing. Previews, videos and point clouds show the sensor's true range in metres
    (`UpscaleJob.d_range`: the gate's start included). batch_size: frames per compiled call (default: see
    `jaxsr.inference.iter_super_resolve`; at most the recording's frames). progress: a tqdm progress bar.
    max_memory: the memory the work may take, bytes or a size such as "16GB" (default
    `jaxsr.checks.memory_budget`); `jaxsr.app.upscale_memory` estimates it before any work, and a job beyond it
    is refused (ValueError: the estimate and what would need less). report: called with each line of
    `UpscaleResult.notes` as soon as it is known (the warnings and what is read with which model before the
    network runs; what the writing found after).

    Returns an `UpscaleResult`. Raises FileExistsError, IsADirectoryError, NotADirectoryError, FileNotFoundError,
    `jaxsr.io.NotWritableError` or ValueError for an output, preview, video, reference or point clouds' file or
    folder that cannot be written or read, or a symbolic link among them (checked before any work).
    """
    if isinstance(output, Outputs) and write != Writing() and write != output.writing:
        raise ValueError("write_upscaled: give what is written either in the checked Outputs or as write, not both "
                         "(Outputs already holds its Writing)")
    outputs = output if isinstance(output, Outputs) else check_outputs(output, write, input=job.input_path)
    write, out = outputs.writing, outputs.output
    batch_size = batch_size_of(job, batch_size)
    frame_format = _frame_format(write.frame_format, outputs, job)
    ref = None if write.reference is None else _reference(write.reference, job)
    if outputs.video is not None and write.fps is None and job.fps is not None:  # the file's own rate, before work
        check_fps(job.fps, f"{job.source}: its frame rate (give --fps)")
    check_memory(job, batch_size=batch_size, in_memory=outputs.in_memory, looks=write.looks, max_memory=max_memory)
    early = tuple(f"warning: {w}" for w in job.warnings) + (job.note,)
    for line in early if report is not None else ():
        report(line)
    sides = _side_files(outputs, job)
    saturated, depth, extra = _write(job, outputs, frame_format, ref, batch_size, progress, sides)
    late = (_saturated_note(saturated),) if saturated else ()
    for line in late if report is not None else ():
        report(f"warning: {line}")
    units = "m" if outputs.folder else job.units
    return UpscaleResult(out, depth, job.frames, (job.frames, *job.hr_shape), job.recording.kind, units,
                         job.model_id, job.model_name, job.gate, job.scale, outputs.preview, job.warnings + late,
                         early + tuple(f"warning: {w}" for w in late), outputs.video, outputs.points,
                         job.negative_counts, None if units == job.units else job.units, job.ambient_alpha,
                         job.keep_returns, *(extra if out is None else (None, None)), tuple(sides.values()))


def side_file(output: Path, name: str) -> Path:
    """The file beside an .npy OUTPUT that holds its `name` array ("confidence", "depth_std"): OUT.name.npy."""
    return output.with_name(f"{output.stem}.{name}.npy")


def _side_files(outputs: Outputs, job: UpscaleJob) -> dict:
    """{name: path} of the confidence's side files of an .npy output of photons (none for other outputs), each
    refused before any work where it exists and --force is not given, or is a link."""
    out = outputs.output
    if out is None or outputs.folder or out.suffix.lower() != ".npy" or not job.has_confidence:
        return {}
    sides = {name: side_file(out, name) for name in ("confidence", "depth_std")}
    for path in sides.values():
        if path.is_symlink():
            raise ValueError(f"{path}: a symbolic link; the confidence is written beside {out.name} as a file of "
                             "its own (remove the link)")
        if path.exists() and not outputs.writing.overwrite:
            raise FileExistsError(f"{path} exists (the confidence of {out.name} is written there); --force "
                                  "replaces it")
    return sides


def _write(job: UpscaleJob, outputs: Outputs, frame_format, ref, batch_size: int, progress: bool, sides: dict):
    """Stream the job through the network into the output and the pictures: (PNG pixels saturated, the result
    (T, H, W) when kept in memory, else None, (confidence, depth_std) (T, H, W) where the job has them and they
    are kept in memory or in an .npz, else (None, None)). `sides`: the .npy output's side files (`_side_files`)."""
    write, out, scale = outputs.writing, outputs.output, job.scale
    d_min, d_max = _colour_range(job, write) if write.preview or write.video else job.d_range
    cmap = write.cmap
    shape = (job.frames, *job.hr_shape)
    preview_t = job.frames // 2
    preview_lr, preview_hr = [], []  # the preview's frames, kept as they stream past (no second pass)
    lr_ahead = collections.deque()  # the video's LR frames, from the model's input until its output comes
    input_label = "input (centre of mass)" if job.recording.kind == "histograms" else "input"
    label = job.label or job.model_name

    def keep_preview(frames):
        for t, f in enumerate(frames):
            depth = f[..., 0] if f.ndim == 3 else f  # a photon model's input: depth in channel 0
            if t == preview_t:
                preview_lr.append(depth)
            if outputs.video is not None:
                lr_ahead.append(depth)
            yield f

    stream = job.iter_outputs(batch_size=batch_size, lr_frames=keep_preview(job.lr_frames()))
    folder = outputs.folder
    extra = (np.empty(shape, np.float32), np.empty(shape, np.float32)) if job.has_confidence and not folder and (
        out is None or out.suffix.lower() == ".npz") else None
    if progress:
        stream = tqdm(stream, total=job.frames, unit="frame", desc="upscale")

    with contextlib.ExitStack() as looks:  # the video and point clouds: committed after the output
        film = clouds = None
        if outputs.video is not None:
            labels = (input_label, label) + (() if ref is None else ("reference",))
            rate = write.fps if write.fps is not None else job.fps if job.fps is not None else DEFAULT_FPS
            film = looks.enter_context(DepthVideoWriter(outputs.video, job.hr_shape, labels=labels, fps=rate,
                                                        d_min=d_min, d_max=d_max, frames=job.frames, cmap=cmap,
                                                        overwrite=write.overwrite))
        if outputs.points is not None:
            # a cloud's geometry keeps every return: its colours span the given scale or the sensor's whole range
            c_min = job.d_range[0] if write.vmin is None else write.vmin
            c_max = job.d_range[1] if write.vmax is None else write.vmax
            clouds = looks.enter_context(PointCloudWriter(
                outputs.points, intrinsics=write.points_camera(job.hr_shape, job.scale_factor),
                depth_kind=write.points_depth or "radial", axes=write.points_axes or "opencv",
                colour=write.points_colour, d_min=c_min, d_max=c_max, cmap=cmap, overwrite=write.overwrite))
        ref_frames = None if ref is None else iter(ref[0])

        def frames(units, side_maps=None):
            for t, (hr, conf, std) in enumerate(stream):
                if extra is not None:
                    extra[0][t], extra[1][t] = conf, std
                if side_maps is not None:
                    side_maps[0][t], side_maps[1][t] = conf, std
                _require_depth_output(hr, t, job.label or job.model_name)
                if t == preview_t:
                    preview_hr.append(hr)
                if film is not None or clouds is not None:
                    metres = to_units(hr, "m", scale)
                    if film is not None:
                        panels = [to_units(lr_ahead.popleft(), "m", scale), metres]
                        if ref_frames is not None:
                            panels.append(_metres(next(ref_frames), ref[1], scale))
                        film.write(*(_on_scale(p, d_min, d_max) for p in panels))
                    if clouds is not None:
                        clouds.write(metres)
                yield t, to_units(hr, units, scale)

        def finish():  # inside the output's atomic block: a failed preview or video leaves no output either
            if outputs.preview is not None:
                write_comparison(outputs.preview, _on_scale(to_units(preview_lr[0], "m", scale), d_min, d_max),
                                 _on_scale(to_units(preview_hr[0], "m", scale), d_min, d_max), d_min=d_min,
                                 d_max=d_max, cmap=cmap, labels=(input_label, label), overwrite=write.overwrite)
            if film is not None:
                film.finish()

        depth, saturated = None, 0
        if out is None:
            depth = np.empty(shape, np.float32)
            for t, f in frames(job.units):
                depth[t] = f
            finish()
        elif out.suffix.lower() == ".npy":  # streamed to disk: memory for a batch, not for the whole result
            with contextlib.ExitStack() as files:
                tmp = files.enter_context(atomic_path(out, overwrite=write.overwrite))
                side_tmps = [files.enter_context(atomic_path(p, overwrite=write.overwrite)) for p in sides.values()]
                result = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.float32, shape=shape)
                maps = [np.lib.format.open_memmap(p, mode="w+", dtype=np.float32, shape=shape) for p in side_tmps]
                for path in (tmp, *side_tmps):
                    reserve_space(path)  # a full disk: ENOSPC now, not SIGBUS when a page of the map is written
                for t, f in frames(job.units, maps or None):
                    result[t] = f
                for m in (result, *maps):
                    m.flush()
                del result, maps
                finish()
        elif not outputs.folder:  # .npz
            result = np.empty(shape, np.float32)
            for t, f in frames(job.units):
                result[t] = f
            arrays = {} if extra is None else {"confidence": extra[0], "depth_std": extra[1]}
            with atomic_path(out, overwrite=write.overwrite) as tmp:
                write_sequence(tmp, result, overwrite=True, arrays=arrays, units=job.units, model=job.model_name,
                               input=job.source, scale=job.scale_factor)
                finish()
        else:
            # --force: the folder holds this run's frames only (an earlier run's, of any format, are removed)
            with atomic_folder(out, overwrite=write.overwrite,
                               replaces=tuple(f"frame_*.{f}" for f in FRAME_FORMATS)) as tmp:
                for t, f in frames("m"):
                    write_depth(tmp / f"frame_{t:06d}.{frame_format}", f)
                    if frame_format == "png":
                        saturated += np.count_nonzero(np.isfinite(f) & (f > PNG_MAX_M))
                finish()
    return saturated, depth, (None, None) if extra is None else extra


# Normalised network output further than one whole span outside [0, 1] (the gate) is no depth of any scene (the
# bundled TR0, TR4 and TR0-ambient stay within [-0.41, 1.33] on noise, checkerboards, flicker and all-sky frames):
# a frame that holds it in most of its pixels comes from weights or a config that compute nothing, and would be
# written as no return and 0 m without a word.
OUTPUT_SPANS_BEYOND = 1.0


def _require_depth_output(hr, t: int, name: str) -> None:
    """Raise ValueError where the network's output frame `hr` (normalised, unclipped) is not depth: NaN or inf in
    any pixel, or more than `OUTPUT_SPANS_BEYOND` spans outside [0, 1] in most of them; never written as no return."""
    finite = np.isfinite(hr)
    if not finite.all():
        what = "NaN" if np.isnan(hr).any() else "inf"
        raise ValueError(f"model {name}: its output holds {what} in frame {t} ({1 - finite.mean():.0%} of the pixels) "
                         "from finite input: it computes nothing usable (check its config and weights, jaxsr info); "
                         "nothing written")
    far = np.mean((hr < -OUTPUT_SPANS_BEYOND) | (hr > 1 + OUTPUT_SPANS_BEYOND))
    if far > 0.5:
        raise ValueError(f"model {name}: its output in frame {t} lies more than a whole depth span outside the gate in "
                         f"{far:.0%} of the pixels (normalised {float(hr.min()):.3g} to {float(hr.max()):.3g}): it "
                         "computes nothing usable (check its config and weights, jaxsr info); nothing written")


def _colour_range(job: UpscaleJob, write: Writing) -> tuple[float, float]:
    """The pictures' colour scale in metres: --vmin / --vmax where given, the recording's depth range elsewhere."""
    lo, hi = job.depth_range() if write.vmin is None or write.vmax is None else (write.vmin, write.vmax)
    lo = lo if write.vmin is None else write.vmin
    hi = hi if write.vmax is None else write.vmax
    if not lo < hi:
        raise ValueError(f"the colour scale from {lo:g} to {hi:g} m is empty: give --vmin below --vmax")
    return float(lo), float(hi)


def _on_scale(metres, d_min: float, d_max: float) -> np.ndarray:
    """Depth in metres with its returns clipped to the colour scale (a return beyond d_max is drawn at its end, not
    as no return); no return (inf, NaN) stays."""
    metres = np.asarray(metres, np.float32)
    return np.where(np.isfinite(metres), np.clip(metres, d_min, d_max), metres)


def _frame_format(frame_format: str | None, outputs: Outputs, job: UpscaleJob) -> str | None:
    """The frame files' format for a folder OUTPUT (default "exr"; `check_outputs` refused one for any other
    output), and "png" refused for a range that starts beyond 16-bit PNG's 65.535 m (every pixel would saturate)."""
    if not outputs.folder:
        return None
    if frame_format == "png" and job.d_range[0] >= PNG_MAX_M:
        raise ValueError(f"16-bit PNG frames hold depth up to {PNG_MAX_M} m, and this recording's range starts at "
                         f"{job.d_range[0]:g} m (the gate's start): choose --frame-format exr, pfm or tif")
    return "exr" if frame_format is None else frame_format


def _saturated_note(pixels: int) -> str:
    """The warning on depth beyond 16-bit PNG's range, written as its largest value."""
    return (f"{pixels} pixel{'' if pixels == 1 else 's'} beyond {PNG_MAX_M} m written as {PNG_MAX_M} m (16-bit "
            "PNG's largest depth); --frame-format exr, pfm or tif store them")
