"""Cheap input validation shared by the public functions (shapes always, values only when concrete), and the
memory budget that work growing with the input is checked against before it allocates."""

from __future__ import annotations

import os
import zipfile

import jax
import jax.numpy as jnp
import numpy as np

from .config import Sensor

# How far normalised depth may stray outside [0, 1] by float rounding (a resize, a float16 round trip) and
# still be taken as normalised (and clipped): far less than any depth in metres, which is 0 only at the lens.
NORMALISED_SLACK = 1e-6


def is_concrete(x) -> bool:
    """True when `x` holds values we can inspect now (not a tracer inside jit/vmap/grad)."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x))


def require_array(name, what, x):
    """`x` as a JAX array of real numbers (bool, integer or floating point; traced values too). None, text or
    other objects are a TypeError naming the argument (`what`) and what it should be, not JAX's words on an
    invalid array."""
    if x is None:
        raise TypeError(f"{name}: {what} must be an array of numbers, got None")
    dtype = getattr(x, "dtype", None)
    if dtype is None:  # a list, a number: what NumPy makes of it
        x = np.asarray(x)
        dtype = x.dtype
    if not (jnp.issubdtype(dtype, jnp.bool_) or jnp.issubdtype(dtype, jnp.integer)
            or jnp.issubdtype(dtype, jnp.floating)):
        raise TypeError(f"{name}: {what} must be an array of real numbers, got {type(x).__name__} of dtype {dtype}")
    return jnp.asarray(x)


def require_numbers(name: str, what: str, x) -> np.ndarray:
    """`x` as a NumPy array of integers or floats (what the host functions read: depth, counts). Booleans, text,
    Python objects and complex values are a ValueError naming `what`, as `jaxsr upscale` refuses them, not numbers
    NumPy would make of them; a masked array too, whose mask NumPy would drop."""
    if isinstance(x, np.ma.MaskedArray):
        raise ValueError(f"{name}: {what} is a masked array, whose mask would be dropped; fill the masked values first "
                         "(numpy.ma.filled; NaN is no return in normalised depth)")
    arr = np.asarray(x)
    if arr.dtype.kind not in "iuf":
        raise ValueError(f"{name}: {what} holds {arr.dtype} values; expected real numbers (an integer or floating "
                         "point array)")
    return arr


def require_sensor(name, sensor):
    """Refuse anything but a `Sensor` (None, a dict) with a TypeError, before an attribute error would."""
    if not isinstance(sensor, Sensor):
        raise TypeError(f"{name}: sensor must be a jaxsr.Sensor, got {type(sensor).__name__}")
    return sensor


def require_hr_pair(name, depth, intensity, sensor):
    """Check that depth and intensity are (..., H, W) arrays of the same shape with (H, W) = sensor.hr_shape."""
    require_sensor(name, sensor)
    depth, intensity = require_array(name, "depth", depth), require_array(name, "intensity", intensity)
    hr = tuple(sensor.hr_shape)
    if depth.ndim < 2 or depth.shape[-2:] != hr:
        raise ValueError(
            f"{name}: depth must have shape (..., {hr[0]}, {hr[1]}) (HR rows, cols of the Sensor), got "
            f"{depth.shape}; for another frame size use Sensor(optics=Optics(lr_shape=...)) ({sensor.scale} HR "
            "pixels per SPAD pixel)"
        )
    if intensity.shape != depth.shape:
        raise ValueError(f"{name}: intensity shape {intensity.shape} must equal depth shape {depth.shape}")
    return depth, intensity


def require_bins(name, counts, sensor):
    """Check that a histogram array ends with the sensor's K bins."""
    require_sensor(name, sensor)
    counts = require_array(name, "counts", counts)
    if counts.ndim < 1 or counts.shape[-1] != sensor.bins:
        raise ValueError(f"{name}: counts must have shape (..., {sensor.bins}) (K bins last), got {counts.shape}")
    return counts


def one_positive_number(value, what: str, expected: str) -> float:
    """`value` as a float when it is one finite real number > 0 (a Python or NumPy number, a 0-d or one-element
    array); anything else (several values, 0, a negative, NaN or infinite value, text, None) is a ValueError
    "WHAT: expected EXPECTED, got ..." (the value, or the shape of an array of several)."""
    arr = np.asarray(value)
    if arr.size == 1 and arr.dtype.kind in "iuf" and np.isfinite(arr).all() and arr.item() > 0:
        return float(arr.item())
    got = f"an array of shape {arr.shape}" if arr.size != 1 else repr(arr.item())
    raise ValueError(f"{what}: expected {expected}, got {got}")


def require_normalised_depth(name, frame):
    """Check LR normalised depth on the host and return it as float32 NumPy, ready for the network.

    NaN is "no return" and becomes 1.0 (docs/sensor-model.md; as in `normalise_depth` and `denormalise_depth`); values
    within `NORMALISED_SLACK` of [0, 1] are clipped to it; anything else (depth in metres, negated depth, +-inf)
    raises a ValueError that names the range seen and how to normalise metres.
    """
    frame = np.asarray(frame, np.float32)
    nan = np.isnan(frame)
    if not np.all(nan | ((frame >= -NORMALISED_SLACK) & (frame <= 1 + NORMALISED_SLACK))):
        seen = frame[~nan]
        raise ValueError(
            f"{name} has values in [{seen.min():.4g}, {seen.max():.4g}], outside [0, 1]: expected normalised depth "
            f"(1 or NaN = no return; up to {NORMALISED_SLACK:g} of float rounding is clipped). Depth in metres: "
            "normalise it with jaxsr.normalise_depth, or run `jaxsr upscale --units m`"
        )
    return np.where(nan, np.float32(1.0), np.clip(frame, np.float32(0.0), np.float32(1.0)))


# ---------------------------------------------------------------------------------------------------------
# Memory: work whose memory grows with the input (a frame's size, its bins, the frames held at once) is
# estimated before it allocates, and refused beyond a budget, so that a mistake is one line at once rather than
# the kernel's OOM kill minutes later.

# The default budget: this share of the machine's RAM (the rest for the system and other programs).
MEMORY_SHARE = 0.75
_SIZE_UNITS = {"B": 1, "kB": 1e3, "KB": 1e3, "MB": 1e6, "GB": 1e9, "TB": 1e12,
               "KiB": 2**10, "MiB": 2**20, "GiB": 2**30, "TiB": 2**40}


def parse_memory(text: str) -> int:
    """A size with its unit, such as 16GB, 512MB or 1.5GiB (B, kB, MB, GB, TB; KiB, MiB, GiB, TiB) -> bytes > 0.
    A bare number is refused (bytes? gigabytes?): ValueError."""
    text = str(text).strip()
    for unit in sorted(_SIZE_UNITS, key=len, reverse=True):
        if text.endswith(unit):
            try:
                value = float(text[: -len(unit)]) * _SIZE_UNITS[unit]
            except ValueError:
                break
            if np.isfinite(value) and value >= 1:
                return int(value)
            break
    raise ValueError(f"expected a size > 0 with its unit (B, kB, MB, GB, TB, KiB, MiB, GiB, TiB), such as 16GB, "
                     f"got {text!r}")


def machine_memory() -> int | None:
    """This machine's RAM in bytes (os.sysconf), or None where the system does not say."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # not a POSIX system
        return None


def memory_budget(max_memory=None) -> int | None:
    """The bytes a command may allocate: `max_memory` (bytes, or a string for `parse_memory`), else `MEMORY_SHARE`
    of `machine_memory()`; None (no limit) where neither is known."""
    if max_memory is not None:
        value = parse_memory(max_memory) if isinstance(max_memory, str) else max_memory
        if not (np.isfinite(float(value)) and value >= 1):
            raise ValueError(f"max_memory (--max-memory): expected bytes > 0 or a size such as 16GB, got {value!r}")
        return int(value)
    ram = machine_memory()
    return None if ram is None else int(MEMORY_SHARE * ram)


def format_bytes(n: float, extra_digits: int = 0) -> str:
    """Bytes as people read them: 7.2 GB, 350 MB, 131 kB, 512 B; `extra_digits` more decimals (to tell two sizes
    apart)."""
    for unit, size, digits in (("GB", 1e9, 1), ("MB", 1e6, 0), ("kB", 1e3, 0)):
        if n >= size:
            return f"{n / size:.{digits + extra_digits}f} {unit}"
    return f"{n:.{extra_digits}f} B"


def _two_sizes(need: float, budget: float) -> tuple[str, str]:
    """`format_bytes` of both, with as many more decimals as it takes (up to 6) to write them differently."""
    for extra in range(7):
        texts = format_bytes(need, extra), format_bytes(budget, extra)
        if texts[0] != texts[1]:
            break
    return texts


def require_memory(need: float, what: str, max_memory=None, *, remedy: str = "", at_least: bool = False) -> None:
    """Refuse (ValueError) work estimated to need `need` bytes beyond `memory_budget(max_memory)`: one line with
    what `what` needs ("at least" that, when `need` is a lower bound), the budget, how to override it
    (--max-memory, max_memory=) and `remedy` (e.g. "give fewer --bins")."""
    budget = memory_budget(max_memory)
    if budget is None or need <= budget:
        return
    allowed = ("by --max-memory (max_memory)" if max_memory is not None
               else f"({MEMORY_SHARE:.0%} of this machine's {format_bytes(machine_memory())})")
    need_text, budget_text = _two_sizes(need, budget)
    raise ValueError(f"{what} needs {'at least ' if at_least else ''}about {need_text} of memory, more than the "
                     f"{budget_text} allowed {allowed}; {remedy + ', or ' if remedy else ''}give --max-memory "
                     f"{int(np.ceil(need / 1e9))}GB{' or more' if at_least else ''} (max_memory=) to try anyway")


def npz_array_bytes(path, names) -> int:
    """Bytes the arrays `names` of the .npz file `path` take once read (those it holds), from their .npy headers:
    only each header is decompressed, so a large array can be refused before it is read. Raises ValueError for a
    file that is not an .npz of plain arrays."""
    total = 0
    try:
        with zipfile.ZipFile(path) as archive:
            stored = set(archive.namelist())
            for name in names:
                if f"{name}.npy" not in stored:
                    continue
                with archive.open(f"{name}.npy") as f:
                    version = np.lib.format.read_magic(f)
                    read = {(1, 0): np.lib.format.read_array_header_1_0,
                            (2, 0): np.lib.format.read_array_header_2_0}.get(version)
                    if read is None:  # a header version for structured names: read whole, as np.load does
                        continue
                    shape, _, dtype = read(f)
                total += int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as e:
        raise ValueError(f"cannot read {path}: truncated or not an NPZ file ({e})") from e
    return total
