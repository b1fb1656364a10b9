"""Recordings to super-resolve, as `jaxsr upscale` reads and writes them: open depth or histogram recordings in
any supported layout, stream their frames as LR normalised depth, and bring network output back to the
recording's units.

A recording is an .npy array, an .npz from `jaxsr.io.formats.write_sequence` / `write_histograms`, or a folder or glob
pattern of depth frames (EXR, PFM, TIFF, 16-bit PNG). Frames stream one by one where the format allows (image
frames, or an .npy read through a memory map), so a long recording needs memory for a batch, not for the whole
sequence. Units (`DEPTH_UNITS`): "m" (radial metres, inf = no return), "mm", "cm" or "km" (radial distance in
those units; for "mm" and "cm" 0 is no return too, as in 16-bit depth images) or "normalised" ([0, 1], 1 = no
return); NaN is no return in each. `guess_units` guesses only "m" or "normalised", and refuses to guess for integer
arrays (millimetres? centimetres?) and for values that could be kilometres.
"""

from __future__ import annotations

import glob
from pathlib import Path

import numpy as np

from ..io import formats as io
from ..checks import NORMALISED_SLACK, npz_array_bytes, require_memory, require_normalised_depth
from ..config import MIN_LR_SIDE, TRAINED_RANGE_M, DepthScale, Gate, Sensor
from ..sensor.effects import clip_negative_counts
from ..sensor.gates import from_network_depth, gate_to_network
from ..sensor.forward import normalise_depth
from ..sensor.quantities import RANGE_UNITS
from ..sensor.timetags import histogram_time_tags

__all__ = ["ARRAY_FORMATS", "DEPTH_UNITS", "FRAME_FORMATS", "METRES_PER_UNIT", "Recording", "check_frames",
           "clipped_recording", "gate_frames", "guess_units", "normalised_frames", "open_recording",
           "time_tag_recording", "to_metres", "to_units"]

FRAME_FORMATS = (".exr", ".pfm", ".tif", ".tiff", ".png")
ARRAY_FORMATS = (".npy", ".npz")
# Units of depth frames (--units): radial distance in metres, millimetres, centimetres or kilometres, or normalised
# [0, 1] (the network's). METRES_PER_UNIT converts the distances.
METRES_PER_UNIT = {unit: RANGE_UNITS[unit] for unit in ("m", "mm", "cm", "km")}  # the CLI's range units
DEPTH_UNITS = ("m", "normalised", "mm", "cm", "km")
# Units whose 0 is no return (the convention of integer depth images: 16-bit PNG, depth cameras).
_ZERO_IS_NO_RETURN = ("mm", "cm")
# `guess_units` does not guess "normalised" for a first frame whose largest value is below this: in kilometres a
# scene within 100 m, normalised a scene within 3.5 m without one no-return pixel (1.0), which the bundled models
# (trained on streets up to 35 m) never saw.
KM_OR_NORMALISED = 0.1
# `guess_units` does not guess metres for a first frame whose median positive depth is beyond this: millimetres or
# centimetres stored as floats (9000.0 for 9 m), not a scene kilometres away from a sensor trained on 35 m.
MM_OR_METRES = 1000.0


# ---------------------------------------------------------------------------------------------------------
# Input


class Recording:
    """A recording opened for reading: `kind` ("depth" or "histograms"), `frames` (the number of frames),
    `shape` (of one frame), `__iter__` over frames (NumPy, as stored), `array` (the whole (T, ...) array,
    memory-mapped for .npy, when the recording is one; None for image frames) and `fps` (frames per second where
    the file says, as an .npz's metadata from `jaxsr simulate` does; else None)."""

    def __init__(self, kind, frames, shape, reader, source, array=None, fps=None):
        self.kind, self.frames, self.shape, self._reader, self.source = kind, frames, shape, reader, source
        self.array = array
        self.fps = fps

    def __iter__(self):
        return self._reader()

    def head(self, n):
        """The first n frames as one array."""
        out = []
        for f in self:
            out.append(np.asarray(f))
            if len(out) == n:
                break
        return np.stack(out)


def _frame_files(spec: str) -> list[Path]:
    p = Path(spec)
    if p.is_file():
        if p.suffix.lower() not in FRAME_FORMATS:
            raise ValueError(f"{spec}: not a recording; expected an .npy / .npz array, or depth frames "
                             f"({', '.join(FRAME_FORMATS)}): one, a folder or a quoted pattern")
        return [p]
    if p.is_dir():
        files = sorted(f for f in p.iterdir() if f.suffix.lower() in FRAME_FORMATS)
        if not files:
            raise ValueError(f"{spec}: no depth frames ({', '.join(FRAME_FORMATS)}) in this folder")
        return files
    if any(c in spec for c in "*?["):
        files = sorted(Path(f) for f in glob.glob(spec))
        if not files:
            raise FileNotFoundError(f"{spec}: the pattern matches no file")
        bad = [f.name for f in files if f.suffix.lower() not in FRAME_FORMATS]
        if bad:
            raise ValueError(f"{spec}: matches files that are not depth frames ({', '.join(FRAME_FORMATS)}): "
                             f"{bad[:3]}")
        return files
    raise FileNotFoundError(f"no such file or folder: {spec}")


def _kind_of(ndim, requested, source):
    kind = requested or {3: "depth", 4: "histograms"}.get(ndim)
    want = {"depth": 3, "histograms": 4}
    if kind is None or ndim != want[kind]:
        raise ValueError(f"{source}: expected depth (T, h, w) or histograms (T, h, w, bins), got {ndim} "
                         f"dimensions" + (f" for --kind {requested}" if requested else ""))
    return kind


def open_recording(spec, *, kind: str | None = None, max_memory=None) -> Recording:
    """Open INPUT: an .npy array (memory-mapped), an .npz from `write_sequence` (depth) or `write_histograms`
    (counts; only that array is read, whole, once its size passes `jaxsr.checks.require_memory` with
    `max_memory`), or a folder or glob pattern of EXR / PFM / TIFF / 16-bit PNG depth frames (sorted by name).
    kind: "depth", "histograms" or None (from the data: 4 dimensions or a `counts` array = histograms)."""
    spec = str(spec)
    p = Path(spec)
    suffix = p.suffix.lower()
    if suffix in ARRAY_FORMATS and not any(c in spec for c in "*?["):
        if not p.is_file():
            raise FileNotFoundError(f"no such file: {spec}")
        if suffix == ".npy":
            arr = io.load_npy(p, mmap_mode="r")
        else:
            arr, fps = _npz_recording(p, kind, max_memory)
        if arr.dtype.kind not in "iuf":
            raise ValueError(f"{spec}: holds {arr.dtype} values; expected real numbers (an integer or floating "
                             "point array)")
        if arr.ndim == 2 and kind != "histograms":  # one frame
            arr = arr[None]
        k = _kind_of(arr.ndim, kind, spec)
        if arr.shape[0] < 1:
            raise ValueError(f"{spec}: the recording has no frames")
        return Recording(k, arr.shape[0], arr.shape[1:], lambda: iter(arr), spec, array=arr,
                         fps=None if suffix == ".npy" else fps)
    if suffix in ARRAY_FORMATS:
        raise ValueError(f"{spec}: patterns select image frames ({', '.join(FRAME_FORMATS)}), not {suffix} arrays")
    if kind == "histograms":
        raise ValueError(f"{spec}: histograms are read from .npy or .npz arrays, not from image frames")
    files = _frame_files(spec)
    first = io.read_depth(files[0])

    def frames():
        for f in files:
            d = io.read_depth(f)
            if d.shape != first.shape:
                raise ValueError(f"{f}: frame of shape {d.shape}, expected {first.shape} like {files[0].name}")
            yield d

    return Recording("depth", len(files), first.shape, frames, spec)


def _npz_recording(path: Path, kind: str | None, max_memory) -> tuple[np.ndarray, float | None]:
    """(the recording's array of an .npz, its frame rate or None): 'counts' (unless `kind` is "depth") or
    'depth', decompressed alone once its size passes the memory budget; the file's other arrays (an .npz of
    `jaxsr simulate` holds the HR ground truth beside the counts) are never read."""
    unreadable = f"cannot read {path}: truncated or not an NPZ file"
    try:
        z = np.load(path, allow_pickle=False)
    except MemoryError:  # the machine's fault, not the file's
        raise
    except Exception as e:  # zipfile.BadZipFile, EOFError, ValueError on truncated files
        raise ValueError(f"{unreadable} ({e})") from e
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise ValueError(f"{unreadable} (it holds one .npy array: name it .npy)")
    with z:
        name = "counts" if "counts" in z.files and kind != "depth" else "depth"
        if name not in z.files:
            raise ValueError(f"{path}: expected an array 'depth' or 'counts', found {sorted(z.files)}")
        require_memory(npz_array_bytes(path, [name]), f"{path}: its array '{name}'", max_memory)
        try:
            return z[name], _stored_fps(z)
        except MemoryError:  # no room for an array within the budget: the machine's fault, not the file's
            raise
        except Exception as e:  # a damaged array: zipfile.BadZipFile, zlib.error, EOFError, ValueError
            raise ValueError(f"{unreadable} ({e})") from e


def _stored_fps(arrays) -> float | None:
    """The frame rate an .npz's JSON metadata gives (`fps`), or None when it gives none (or no usable one: metadata
    that is no JSON object, or too large or deeply nested to read)."""
    try:
        fps = float(io._json_metadata(io.read_entry(arrays, "metadata", "metadata"), "metadata").get("fps"))
    except (KeyError, TypeError, ValueError, AttributeError):  # a header that lies too (`read_entry`)
        return None
    return fps if np.isfinite(fps) and fps > 0 else None


# `check_frames` reads an array in blocks of at most this many bytes (as float64): 256 frames of the sensor's
# histograms, one of a large frame.
CHECK_BLOCK_BYTES = 64 * 2**20


def _chunks(recording: Recording):
    """(first frame index, (n, ...) float64 block) over the recording: blocks of an array (at most
    `CHECK_BLOCK_BYTES`, at least a frame), else single frames. float64 holds every stored value (float16/32/64,
    integers) without overflow."""
    if recording.array is not None:
        size = max(1, CHECK_BLOCK_BYTES // (8 * int(np.prod(recording.shape))))
        for t in range(0, recording.frames, size):
            yield t, np.asarray(recording.array[t : t + size], np.float64)
    else:
        for t, f in enumerate(recording):
            yield t, np.asarray(f, np.float64)[None]


def check_frames(recording: Recording, units: str, gate: Gate = Gate(), *,
                 clip_negative: bool = False) -> tuple[int, int]:
    """Check every frame before any work, so that a bad recording is refused before compute and before any
    output is written (one pass over the input: a memory-mapped array in blocks, image frames one by one).

    Frames of any size h x w with h, w >= MIN_LR_SIDE run (the bundled models were trained on 32 x 64 frames
    of a 30 deg field of view: README "Frame size"); histograms must have `gate.bins` bins (--bins). Depth: NaN
    and inf are no return; for `units` "normalised" the other values lie within [0, 1] (up to
    NORMALISED_SLACK, as `super_resolve` checks). Histograms: finite counts, >= 0 unless `clip_negative`
    (background-subtracted histograms, whose negative counts `clipped_recording` clips at 0). Raises ValueError
    naming the recording, the frame and what was expected.

    Returns (negative counts, pixels holding one): what `clip_negative` lets through ((0, 0) for depth)."""
    src = recording.source
    frame = tuple(recording.shape[:2])
    if recording.kind == "histograms" and recording.shape[-1] != gate.bins:
        raise ValueError(f"{src}: histogram frames of shape {tuple(recording.shape)} ({recording.shape[-1]} bins); "
                         f"expected {gate.bins} bins (give the sensor's with --bins, --bin-width and --gate-start)")
    if len(frame) != 2 or min(frame) < MIN_LR_SIDE:
        raise ValueError(f"{src}: frames of {' x '.join(map(str, frame))} pixels; expected LR frames of at least "
                         f"{MIN_LR_SIDE} x {MIN_LR_SIDE} pixels (T, h, w)")
    counts = pixels = 0
    for t, block in _chunks(recording):
        if recording.kind == "histograms":
            n, p = _negative_counts(src, t, block, clip_negative)
            counts, pixels = counts + n, pixels + p
            continue
        if units != "normalised":
            continue  # metres: any value is meaningful (NaN, inf, negative and beyond d_max: no return)
        bad = ~np.isnan(block) & ((block < -NORMALISED_SLACK) | (block > 1 + NORMALISED_SLACK))
        if np.any(bad):
            raise ValueError(f"{src}: frame {_first_frame(t, bad)} holds values outside [0, 1]; for depth in "
                             "metres pass --units m")
    return counts, pixels


def _first_frame(t: int, bad: np.ndarray) -> int:
    """The first frame of a block (frames t, t + 1, ...) where `bad` holds anywhere."""
    return t + int(np.argmax(bad.reshape(len(bad), -1).any(axis=1)))


def _negative_counts(src, t: int, block: np.ndarray, clip_negative: bool) -> tuple[int, int]:
    """(negative counts, pixels holding one) of a block of histogram frames from frame t. Refuses non-finite
    counts and counts beyond float32 always, negative ones unless `clip_negative` (the message says it exists:
    raw photon counts are never negative, background-subtracted ones are)."""
    bad = ~(np.isfinite(block) & (block <= np.finfo(np.float32).max))
    if np.any(bad):
        raise ValueError(f"{src}: frame {_first_frame(t, bad)} holds non-finite or huge (beyond float32) photon "
                         "counts; expected finite counts >= 0")
    negative = block < 0
    if np.any(negative) and not clip_negative:
        raise ValueError(f"{src}: frame {_first_frame(t, negative)} holds negative photon counts; expected counts "
                         ">= 0 (for background-subtracted histograms pass --clip-negative, clip_negative=True, to "
                         "clip them at 0)")
    return int(negative.sum()), int(negative.any(axis=-1).sum())


def clipped_recording(recording: Recording) -> Recording:
    """A histogram recording with its negative counts clipped at 0 (`jaxsr.sensor.clip_negative_counts`), frame
    by frame as it streams: background-subtracted histograms made fit for the centre of mass, which refuses
    negative counts. Frames (h, w, K) float32; NaN stays NaN (and is refused downstream)."""
    sensor = Sensor(gate=Gate.spanning(TRAINED_RANGE_M, int(recording.shape[-1])))

    def frames():
        for f in recording:
            yield np.asarray(clip_negative_counts(np.asarray(f, np.float32), sensor)[0])

    return Recording("histograms", recording.frames, recording.shape, frames, recording.source, fps=recording.fps)


def gate_frames(com_frames, gate: Gate, scale: DepthScale):
    """Centre-of-mass frames normalised to the gate (tau / K, 1.0 = no return, as `iter_centre_of_mass` gives
    them for K = gate.bins) -> the network's normalised depth under `scale` (`jaxsr.sensor.gates.gate_to_network`,
    as `jaxsr.nn.network_inputs` reads a `Sensor(gate=gate, depth=scale)`). Yields (h, w) float32 frames; (h, w, C)
    frames of `iter_network_inputs` for the gate's own scale keep their photon channels, the depth in channel 0
    converted."""
    sensor = Sensor(gate=gate, depth=scale)
    for f in com_frames:
        depth = f[..., 0] if f.ndim == 3 else f
        network = np.asarray(gate_to_network(np.asarray(depth, np.float32), sensor), np.float32)
        yield np.concatenate([network[..., None], f[..., 1:]], axis=-1) if f.ndim == 3 else network


def time_tag_recording(tags, gate: Gate, *, outside: str = "error", max_memory=None) -> Recording:
    """A recording of photon counts histogrammed from `jaxsr.sensor.timetags.TimeTags` over `gate`
    (`histogram_time_tags`, its memory checked against `max_memory` first): kind "histograms", frames (h, w,
    gate.bins)."""
    counts = histogram_time_tags(tags, gate, outside=outside, max_memory=max_memory)
    return Recording("histograms", counts.shape[0], counts.shape[1:], lambda: iter(counts), tags.source, array=counts)


def to_metres(frame, units: str) -> np.ndarray:
    """A depth frame in `units` ("m", "mm", "cm" or "km", `METRES_PER_UNIT`) -> float32 radial metres; 0 is no
    return (inf) in "mm" and "cm", as in 16-bit depth images. NaN and the rest as they are."""
    with np.errstate(over="ignore"):  # distances beyond float32 are no return (inf), as they should be
        f = np.asarray(frame, np.float32)
    if units == "m":
        return f
    metres = (f * np.float32(METRES_PER_UNIT[units])).astype(np.float32)
    return np.where(f == 0, np.float32(np.inf), metres) if units in _ZERO_IS_NO_RETURN else metres


def normalised_frames(recording: Recording, units: str, sensor: Sensor):
    """Depth frames of a recording as LR normalised depth: metres (or mm, cm, km: `to_metres`) -> `normalise_depth`
    (NaN, inf, negative and beyond d_max: no return, 1.0); normalised -> checked as `super_resolve` checks it (NaN
    -> 1.0, values outside [0, 1] by more than float rounding refused with a message that suggests --units m)."""
    for t, f in enumerate(recording):
        if units in METRES_PER_UNIT:
            yield np.asarray(normalise_depth(to_metres(f, units), sensor))
        else:
            yield require_normalised_depth(f"{recording.source}: frame {t}", np.asarray(f, np.float32))


def guess_units(recording: Recording, *, ask: str = "pass --units (units=): m, mm, cm, km or normalised") -> str:
    """The units of a depth recording, from its first frame: "normalised" when its values other than NaN (no return
    in either unit) are finite and within [0, 1] up to float rounding (no lidar scene lies within a metre), else
    "m". Refuses to guess (ValueError: what is ambiguous, then `ask`) where that would silently read other units:
    integer frames (millimetres, as 16-bit depth images store them, or centimetres; image frames are read as
    metres already), floats of a median beyond `MM_OR_METRES` (millimetres or centimetres), and values within
    [0, 1] that could be kilometres (with inf for no return, which normalised depth never holds; or all below
    `KM_OR_NORMALISED`)."""
    head = np.asarray(recording.head(1)[0])
    src = recording.source
    if head.dtype.kind in "iu":
        raise ValueError(f"{src}: depth as integers ({head.dtype}) could be millimetres (as 16-bit depth images store "
                         f"it), centimetres or metres; {ask}")
    with np.errstate(over="ignore"):  # values beyond float32 become inf: not normalised depth
        f = np.asarray(head, np.float32)
    f = f[~np.isnan(f)]
    finite = f[np.isfinite(f)]
    if head.size and not f.size:  # no evidence either way: metres read as normalised would come out as 1.0
        raise ValueError(f"{src}: the first frame is NaN (no return) in every pixel, which says nothing of its "
                         f"units; {ask}")
    if finite.size and finite.size == f.size and np.all(finite < 0):  # negative is no return: every pixel would be
        raise ValueError(f"{src}: the first frame's depth is negative in every pixel (negative is no return; depth "
                         f"along a camera's -z axis? negate it); {ask}")
    if not np.all(np.isfinite(f) & (f >= -NORMALISED_SLACK) & (f <= 1 + NORMALISED_SLACK)):
        if finite.size and np.all(np.isposinf(f) | ((f >= -NORMALISED_SLACK) & (f <= 1 + NORMALISED_SLACK))):
            raise ValueError(f"{src}: depth within [0, 1] with inf for no return could be kilometres (or metres of "
                             f"a scene within 1 m); {ask}")
        positive = finite[finite > 0]
        if positive.size and np.median(positive) > MM_OR_METRES:
            raise ValueError(f"{src}: depth of a median {np.median(positive):.4g} could be millimetres or "
                             f"centimetres stored as floats (in metres, a scene {np.median(positive) / 1000:.3g} km "
                             f"away); {ask}")
        return "m"
    if finite.size and finite.max() < KM_OR_NORMALISED:
        raise ValueError(f"{src}: depth all below {KM_OR_NORMALISED:g} could be kilometres (a scene within "
                         f"{KM_OR_NORMALISED * 1000:g} m) or normalised depth (a scene within "
                         f"{KM_OR_NORMALISED * TRAINED_RANGE_M:g} m without one no-return pixel at 1.0); {ask}")
    return "normalised"


def to_units(hr, units: str, scale: DepthScale = DepthScale()):
    """Network output (H, W), normalised and unclipped -> the recording's units: "normalised" (clipped to
    [0, 1]) or "m" (radial metres offset + n * span, inf for no return: `jaxsr.sensor.gates.from_network_depth`; with
    the default scale `jaxsr.sensor.forward.denormalise_depth`), or those metres in "mm", "cm" or "km" (float32, inf
    for no return). Returns (H, W)."""
    if units == "normalised":
        return np.clip(hr, 0.0, 1.0)
    metres = np.asarray(from_network_depth(hr, scale), np.float32)
    return metres if units == "m" else (metres / np.float32(METRES_PER_UNIT[units])).astype(np.float32)
