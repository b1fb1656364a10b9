"""Photon time tags: per-pixel lists of arrival times, read from files and histogrammed in JAX over a gate.

Supported inputs (anything else is refused with a message that says so):
- MATLAB v4-v7 .mat files (scipy.io) holding a cell array of shape (h, w) or (T, h, w) whose cells are numeric
  vectors of arrival times (empty = no photon);
- a flat NumPy table, .npz with `pixel` (N,) integer row-major indices into `shape` (h, w), `time` (N,) and
  optionally `frame` (N,) frame indices and `time_unit_s` (seconds per time unit);
- the same cells as a nested Python list or an object array (`time_tags_from_cells`).
MATLAB v7.3 files are HDF5 and are refused: re-save them with save(FILE, VAR, '-v7').

Times are in the recording's own unit (ps in most lidar files, or the system's bins); `time_unit_s` says how
many seconds one unit is, which puts them on a `jaxsr.Gate` in metres (r = c t / 2).
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.util
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ..checks import format_bytes, npz_array_bytes, one_positive_number, require_memory
from ..config import METRES_PER_SECOND, Gate
from .quantities import TIME_UNITS

__all__ = ["TimeTags", "time_tags_from_cells", "read_time_tags", "histogram_photons", "histogram_time_tags",
           "gate_of_tags", "time_tag_warnings", "TIME_TAG_FORMATS"]

TIME_TAG_FORMATS = (".mat", ".npz")
_TABLE_ARRAYS = ("pixel", "time", "shape", "frame", "time_unit_s")  # what a table's reader reads, nothing else
# `histogram_photons` indexes the counts with int32: the histograms of one call hold fewer than this many.
MAX_HISTOGRAM_COUNTS = 2**31 - 1
MAX_BINS = 2**22  # bins whose centres float32 holds exactly (k + 0.5), so JAX's floor finds NumPy's bin


@dataclasses.dataclass(frozen=True)
class TimeTags:
    """Photon arrival times of a recording (host NumPy arrays): `pixel` (N,) int64 row-major pixel indices into
    `shape` (h, w), `frame` (N,) int64 frame indices in [0, frames), `time` (N,) float64 arrival times in the
    recording's unit, `time_unit_s` (seconds per unit; None when the file does not say) and `source`."""

    pixel: np.ndarray
    frame: np.ndarray
    time: np.ndarray
    shape: tuple[int, int]
    frames: int
    time_unit_s: float | None = None
    source: str = "time tags"

    @property
    def photons_per_pixel(self) -> float:
        """Mean photons per pixel and frame."""
        return self.time.size / (self.frames * self.shape[0] * self.shape[1])


def _cell_times(cell, where: str, source: str) -> np.ndarray:
    """One cell's arrival times as a float64 vector (empty for no photon); refuses anything but real numbers."""
    arr = np.asarray(cell)
    if arr.dtype == object or arr.dtype.kind not in "iuf":
        raise ValueError(f"{source}: cell {where} holds {arr.dtype} values; expected a vector of arrival times "
                         "(real numbers) or an empty cell")
    if arr.size and arr.size != max(arr.shape):
        raise ValueError(f"{source}: cell {where} is a {arr.shape} matrix; expected a vector of arrival times")
    times = arr.astype(np.float64).ravel()
    if not np.all(np.isfinite(times)):
        raise ValueError(f"{source}: cell {where} holds non-finite arrival times")
    return times


def time_tags_from_cells(cells, *, time_unit_s: float | None = None, source: str = "cells") -> TimeTags:
    """Time tags from per-pixel lists of arrival times.

    cells: an (h, w) or (T, h, w) object array (a MATLAB cell array as scipy.io reads it) or nested lists of the
    same rectangular shape, each entry a vector of arrival times (empty: no photon in that pixel, a no-return
    pixel after histogramming). Returns `TimeTags`. Raises ValueError for ragged nesting, a cell that is not a
    numeric vector, or non-finite times."""
    if not isinstance(cells, np.ndarray) or cells.dtype != object:
        grid = np.empty(_nested_shape(cells, source), dtype=object)
        for index in np.ndindex(grid.shape):
            item = cells
            for i in index:
                item = item[i]
            grid[index] = item
        cells = grid
    if cells.ndim == 2:
        cells = cells[None]
    if cells.ndim != 3 or min(cells.shape) < 1:
        raise ValueError(f"{source}: expected cells of shape (h, w) or (T, h, w), got {cells.shape}")
    frames, h, w = cells.shape
    times, pixel, frame = [], [], []
    for (t, y, x), cell in np.ndenumerate(cells):
        c = _cell_times(cell, f"({y}, {x})" + (f" of frame {t}" if frames > 1 else ""), source)
        times.append(c)
        pixel.append(np.full(c.size, y * w + x, np.int64))
        frame.append(np.full(c.size, t, np.int64))
    return TimeTags(np.concatenate(pixel), np.concatenate(frame), np.concatenate(times), (h, w), frames,
                    time_unit_s, source)


def _nested_shape(cells, source) -> tuple[int, ...]:
    """The rectangular (rows, cols) or (T, rows, cols) shape of nested lists of time vectors; ValueError if ragged."""
    if not isinstance(cells, (list, tuple)) or not cells:
        raise ValueError(f"{source}: expected per-pixel lists of arrival times, (h, w) or (T, h, w) nested lists")
    depth = 3 if isinstance(cells[0], (list, tuple)) and cells[0] and isinstance(cells[0][0], (list, tuple)) \
        and cells[0][0] and isinstance(cells[0][0][0], (list, tuple, np.ndarray)) else 2

    def lengths(item, level):
        if level == depth:
            return
        if not isinstance(item, (list, tuple)):
            raise ValueError(f"{source}: ragged cells: expected {depth} levels of lists")
        yield level, len(item)
        for sub in item:
            yield from lengths(sub, level + 1)

    shape = [None] * depth
    for level, n in lengths(cells, 0):
        if shape[level] is None:
            shape[level] = n
        elif shape[level] != n:
            raise ValueError(f"{source}: ragged cells: rows of {shape[level]} and {n} entries at level {level}; "
                             "expected every row to have the same number of pixels")
    return tuple(shape)


def _read_mat(path: Path, variable: str | None) -> tuple[np.ndarray, str]:
    import scipy.io

    try:
        major, _ = scipy.io.matlab.matfile_version(str(path))
    except Exception as e:  # scipy raises several kinds for a file that is not a MAT-file
        raise ValueError(f"{path}: not a MATLAB .mat file ({e})") from None
    if major == 2:
        why = "h5py is not installed" if importlib.util.find_spec("h5py") is None else "not supported yet"
        raise ValueError(f"{path}: a MATLAB v7.3 (HDF5) file, which jaxsr does not read ({why}); re-save it in "
                         "MATLAB with save(FILE, VAR, '-v7')")
    try:
        contents = scipy.io.loadmat(str(path), squeeze_me=False)
    except Exception as e:
        raise ValueError(f"{path}: cannot read this .mat file ({e})") from None
    cells = {k: v for k, v in contents.items() if not k.startswith("__") and isinstance(v, np.ndarray)
             and v.dtype == object and v.ndim in (2, 3)}
    if variable is not None:
        if variable not in cells:
            raise ValueError(f"{path}: no cell array named {variable!r}; cell arrays here: {sorted(cells) or 'none'}")
        return cells[variable], variable
    if len(cells) != 1:
        found = sorted(k for k in contents if not k.startswith("__"))
        raise ValueError(f"{path}: expected one cell array of per-pixel arrival times, found "
                         f"{sorted(cells) or 'none'} among {found}" + ("; name one (--variable)" if cells else ""))
    (name, value), = cells.items()
    return value, name


def _read_table(path: Path, time_unit_s: float | None, max_memory) -> TimeTags:
    """A time-tag table (.npz), reading only its arrays `_TABLE_ARRAYS` (each decompressed whole; their sizes
    checked against the memory budget first). The file's `time_unit_s` is checked unless `time_unit_s` is given."""
    # read as stored, then int64 / float64 copies of pixel, frame and time
    require_memory(3 * npz_array_bytes(path, _TABLE_ARRAYS), f"{path}: the time-tag table", max_memory)
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in _TABLE_ARRAYS if k in z.files}
            found = z.files
    except (ValueError, OSError) as e:
        raise ValueError(f"{path}: cannot read this .npz file ({e})") from None
    missing = {"pixel", "time", "shape"} - set(arrays)
    if missing:
        raise ValueError(f"{path}: a time-tag table needs arrays 'pixel', 'time' and 'shape'; missing "
                         f"{sorted(missing)} (found {sorted(found)})")
    pixel, time, shape = arrays["pixel"], arrays["time"], arrays["shape"]
    frame = arrays.get("frame", np.zeros(pixel.shape, np.int64))
    if shape.shape != (2,) or shape.dtype.kind not in "iu" or shape.min() < 1:
        raise ValueError(f"{path}: 'shape' must be two integers (h, w) >= 1, got {shape!r}")
    if pixel.ndim != 1 or time.shape != pixel.shape or frame.shape != pixel.shape:
        raise ValueError(f"{path}: 'pixel', 'time' (and 'frame') must be vectors of one length, got "
                         f"{pixel.shape}, {time.shape}, {frame.shape}")
    if pixel.dtype.kind not in "iu" or frame.dtype.kind not in "iu" or time.dtype.kind not in "iuf":
        raise ValueError(f"{path}: 'pixel' and 'frame' must be integers and 'time' real numbers")
    h, w = (int(v) for v in shape)
    if pixel.size and (pixel.min() < 0 or pixel.max() >= h * w or frame.min() < 0):
        raise ValueError(f"{path}: pixel indices must lie in [0, {h * w}) (row-major in {h} x {w}) and frames >= 0")
    if not np.all(np.isfinite(time)):
        raise ValueError(f"{path}: 'time' holds non-finite arrival times")
    if time_unit_s is None:
        time_unit_s = _time_unit(arrays.get("time_unit_s"), f"{path}: 'time_unit_s'")
    return TimeTags(pixel.astype(np.int64), frame.astype(np.int64), time.astype(np.float64), (h, w),
                    int(frame.max()) + 1 if frame.size else 1, time_unit_s, str(path))


def read_time_tags(path, *, variable: str | None = None, time_unit_s: float | None = None,
                   max_memory=None) -> TimeTags:
    """Read photon time tags from a .mat cell array or an .npz table of pixels and times (module docstring).

    variable: the .mat cell array to read (default: the only one). time_unit_s: seconds per time unit (overrides
    a table's `time_unit_s`): one number > 0. max_memory: the memory budget a table's arrays are checked against
    before they are read (bytes or a size such as "16GB"; default `jaxsr.checks.memory_budget`). Returns
    `TimeTags`. Raises FileNotFoundError for a missing file and ValueError for another format, MATLAB v7.3, no or
    several cell arrays, malformed contents or a time unit that is not one number > 0 (the message says which)."""
    time_unit_s = _time_unit(time_unit_s, "time_unit_s")
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    suffix = path.suffix.lower()
    if suffix == ".mat":
        cells, name = _read_mat(path, variable)
        tags = time_tags_from_cells(cells, source=f"{path}:{name}")
    elif suffix == ".npz":
        tags = _read_table(path, time_unit_s, max_memory)
    else:
        raise ValueError(f"{path}: time tags are read from a MATLAB .mat cell array (v4-v7) or an .npz table "
                         f"('pixel', 'time', 'shape'), not {suffix or 'a file without a suffix'}")
    if time_unit_s is not None:
        tags = dataclasses.replace(tags, time_unit_s=time_unit_s)
    return tags


@functools.partial(jax.jit, static_argnames=("cells", "bins"))
def histogram_photons(cell, delay, *, cells: int, bins: int):
    """Histogram photons into `cells` histograms of `bins` bins (pure JAX, jit-compiled).

    Args:
      cell: (N,) int histogram index of each photon (frame * pixels + pixel), in [0, cells).
      delay: (N,) float arrival time after the gate start, in bins; photon n falls into bin floor(delay[n]), and
        photons outside [0, bins) are not counted.
    Returns:
      (cells, bins) float32 photon counts.
    """
    k = jnp.floor(delay)
    inside = (k >= 0) & (k < bins)
    index = jnp.where(inside, cell * bins + k.astype(jnp.int32), 0)
    counts = jnp.zeros(cells * bins, jnp.float32).at[index].add(inside.astype(jnp.float32))
    return counts.reshape(cells, bins)


def _time_unit(value, where: str) -> float | None:
    """Seconds per time unit: None stays None; else one finite number > 0 (a 0-d or one-element array too).
    A vector, a negative or NaN value or text (such as '1ps' stored in a file) is a ValueError naming `where`."""
    if value is None:
        return None
    return one_positive_number(value, where, "one number of seconds per time unit, > 0 (such as 1e-12 for "
                               "picoseconds; --time-unit 1ps on the command line)")


def _unit_s(tags: TimeTags) -> float:
    if tags.time_unit_s is None:
        raise ValueError(f"{tags.source}: the time unit of the tags is unknown; give it (time_unit_s, --time-unit "
                         "such as 1ps); if nobody knows it, any nominal unit gives the same normalised depth "
                         "with the default span, fitted to the returns, or --span gate")
    return _time_unit(tags.time_unit_s, f"{tags.source}: time_unit_s")


# The widest gate `gate_of_tags` makes, metres of range (6.7 ms): photons spread further are stray tags or a wrong
# time unit, and a gate over them holds nothing float32 depth can mean
MAX_AUTO_GATE_M = 1e6


def gate_of_tags(tags: TimeTags, *, bins: int = 16) -> Gate:
    """The gate that just covers the photons seen: `bins` bins from the first to the last arrival time, widened
    by a millionth of that span (half before the first photon, but never before time 0, the laser pulse; half
    after the last) so that both fall inside whatever the rounding of the conversion to metres and back. Returns
    a Gate in metres (its start >= 0, as --gate-start must be); raises ValueError when there are no photons, all
    arrive at one time, or some at a negative time (before the laser pulse: a gate in negative metres would give
    negative depth)."""
    if tags.time.size == 0:
        raise ValueError(f"{tags.source}: holds no photons (no time tag in any pixel); expected a recording's "
                         "photon arrival times")
    if tags.time.max() <= tags.time.min():
        raise ValueError(f"{tags.source}: {tags.time.size} photons at one arrival time; give the gate "
                         "(--gate-start, --bin-width)")
    negative = int(np.count_nonzero(tags.time < 0))
    if negative:
        raise ValueError(f"{tags.source}: {negative} of {tags.time.size} photons arrive at negative times (from "
                         f"{tags.time.min():.6g}, in the tags' unit); expected times >= 0 from the laser pulse: check "
                         "the recording's time origin, or give the gate (--gate-start, --bin-width) and drop the "
                         "photons outside it (--drop-outside)")
    metres = METRES_PER_SECOND * _unit_s(tags)
    t0, t1 = float(tags.time.min()), float(tags.time.max())
    if not (t1 - t0) * metres <= MAX_AUTO_GATE_M:  # a stray time tag, or the wrong unit: no lidar's gate
        late = int(np.count_nonzero(tags.time > t0 + MAX_AUTO_GATE_M / metres))
        raise ValueError(f"{tags.source}: the photons span {(t1 - t0) * metres:.3g} m of range (times {t0:.6g} to "
                         f"{t1:.6g} in the tags' unit), beyond the {MAX_AUTO_GATE_M:g} m a gate may cover; {late} of "
                         f"{tags.time.size} photons lie beyond that after the first: give the gate (--gate-start, "
                         "--bin-width) and drop the photons outside it (--drop-outside), or check --time-unit")
    pad = 0.5e-6 * (t1 - t0)
    start = max(t0 - pad, 0.0)  # a photon at time 0 starts the gate at 0 m, not a hair before
    return Gate(bins, (t1 + pad - start) / bins * metres, start * metres)


def _bin_positions(tags: TimeTags, gate: Gate, unit_s: float) -> np.ndarray:
    """Each photon's position in `gate` in bins (float64: bin k is [k, k + 1)), its time read in `unit_s`
    seconds per unit. Subtracting in float64 keeps the precision of microseconds counted in picoseconds."""
    per_unit = METRES_PER_SECOND * unit_s  # metres of range per time unit
    return (tags.time - float(gate.start) / per_unit) / (float(gate.bin_width) / per_unit)


def _unit_name(seconds: float) -> str:
    """A duration as --time-unit takes it: 1ns, 8ps."""
    for name, size in sorted(TIME_UNITS.items(), key=lambda item: -item[1]):
        if seconds >= size * (1 - 1e-9):
            return f"{seconds / size:.6g}{name}"
    return f"{seconds:.6g}s"


def _spread(position: np.ndarray, bins: int) -> tuple[float, float]:
    """(share of the photons inside the gate, share of the gate the middle 98% of those inside span)."""
    inside = position[(position >= 0) & (position < bins)]
    if position.size == 0 or inside.size == 0:
        return 0.0, 0.0
    lo, hi = np.percentile(inside, [1, 99])
    return inside.size / position.size, float(hi - lo) / bins


def _likely_unit(tags: TimeTags, gate: Gate) -> str:
    """' (with --time-unit X, N% of them would ...)' when another power of 1000 of the tags' unit would put most
    photons inside `gate` and spread them over it: the usual mistake (ns for ps); else ''."""
    unit = _unit_s(tags)
    best = None
    for factor in (1e-6, 1e-3, 1e3, 1e6):
        share, spread = _spread(_bin_positions(tags, gate, unit * factor), gate.bins)
        if share >= 0.5 and spread >= 0.05 and (best is None or share > best[1]):
            best = (unit * factor, share, spread)
    if best is None:
        return ""
    return (f"; is the time unit right? with --time-unit {_unit_name(best[0])} (not {_unit_name(unit)}) "
            f"{best[1]:.0%} of them would fall inside, over {best[2]:.0%} of the gate")


def time_tag_warnings(tags: TimeTags, gate: Gate, *, outside: str = "error") -> list[str]:
    """Sentences on how the photons of `tags` fall in `gate`, for people: how many `outside="drop"` drops, and a
    likely wrong time unit (almost every photon outside the gate, or all inside 1% of it; with the power of
    1000 of the unit that would fit, when one does). An empty list when nothing is odd."""
    position = _bin_positions(tags, gate, _unit_s(tags))
    out = []
    n_out = int(np.count_nonzero((position < 0) | (position >= gate.bins)))
    if n_out and outside == "drop":
        out.append(f"{tags.source}: {n_out} of {position.size} photons outside the gate dropped (--drop-outside)")
    share, spread = _spread(position, gate.bins)
    if position.size and (share < 0.1 or spread < 0.01):
        where = (f"{1 - share:.0%} of the photons fall outside the gate" if share < 0.1
                 else f"the photons fall inside {spread:.2%} of the gate")
        out.append(f"{tags.source}: {where}{_likely_unit(tags, gate) or '; check the time unit and the gate'}")
    return out


def histogram_time_tags(tags: TimeTags, gate: Gate, *, outside: str = "error", max_memory=None) -> np.ndarray:
    """Photon counts of time tags over `gate`: (T, h, w, K) float32 NumPy, K = gate.bins, histogrammed in JAX
    (`histogram_photons`).

    Each time t (in the tags' unit) is placed in bin floor((t - t_start) / t_width), with the gate's start and
    bin width converted to that unit (r = c t / 2); the bin is found in float64, so times of microseconds in
    picoseconds keep their precision and a photon on the gate's edge falls where NumPy says. A pixel with no
    photon in the gate is an empty histogram (no return after the centre of mass). outside: "error" (default)
    refuses photons outside the gate with their count and time range (and the likely time unit when the tags'
    is off by a power of 1000); "drop" ignores them (`time_tag_warnings` counts them). max_memory: the budget
    the histograms' memory is checked against before they are made (bytes or "16GB"; default
    `jaxsr.checks.memory_budget`). Raises ValueError for those photons, for an unknown time unit, for a gate
    that catches no photon, and for histograms beyond the memory budget or `MAX_HISTOGRAM_COUNTS`."""
    if outside not in ("error", "drop"):
        raise ValueError(f"histogram_time_tags: outside must be 'error' or 'drop', got {outside!r}")
    h, w = tags.shape
    cells = tags.frames * h * w
    what = (f"{tags.source}: histogramming {tags.frames} frame{'s' if tags.frames > 1 else ''}" + (
        f" (frame indices up to {tags.frames - 1})" if tags.frames > 1 else "") + f" of {h} x {w} pixels x "
        f"{gate.bins} bins")
    # the counts twice (zeros and the scatter's result) and per photon its time, bin and cell, in NumPy and JAX
    require_memory(2 * 4 * cells * gate.bins + 40 * tags.time.size, what, max_memory,
                   remedy="give fewer --bins, or check the frame indices")
    if cells * gate.bins > MAX_HISTOGRAM_COUNTS or gate.bins > MAX_BINS:
        raise ValueError(f"{what} makes {cells * gate.bins:,} counts ({format_bytes(4 * cells * gate.bins)}), more "
                         f"than the {MAX_HISTOGRAM_COUNTS:,} (and {MAX_BINS:,} bins) one histogramming can index; "
                         "give fewer --bins, or "
                         "check the frame indices")
    position = _bin_positions(tags, gate, _unit_s(tags))
    inside = (position >= 0) & (position < gate.bins)
    n_out = int(position.size - inside.sum())
    if n_out and outside == "error":
        per_unit = METRES_PER_SECOND * _unit_s(tags)
        lo, hi = gate.start / per_unit, gate.end / per_unit
        raise ValueError(f"{tags.source}: {n_out} of {position.size} photons arrive outside the gate [{lo:.6g}, "
                         f"{hi:.6g}) (times seen {tags.time.min():.6g} .. {tags.time.max():.6g}, in the tags' unit); "
                         "widen the gate or drop them (outside='drop', --drop-outside)" + _likely_unit(tags, gate))
    if position.size and not inside.any():
        raise ValueError(f"{tags.source}: no photon arrives inside the gate" + _likely_unit(tags, gate))
    cell = tags.frame * (h * w) + tags.pixel
    # the bin's centre, exact in float32 (bins < 2^23), so that JAX's float32 floor finds the bin chosen above
    centre = np.where(inside, np.floor(position) + 0.5, -1.0).astype(np.float32)
    counts = histogram_photons(jnp.asarray(cell, jnp.int32), jnp.asarray(centre), cells=cells, bins=gate.bins)
    return np.asarray(counts).reshape(tags.frames, h, w, gate.bins)
