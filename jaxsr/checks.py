"""Cheap input validation shared by the public functions (shapes always, values only when concrete)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .config import SensorConfig

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


def require_sensor(name, sensor):
    """Refuse anything but a `SensorConfig` (None, a dict) with a TypeError, before an attribute error would."""
    if not isinstance(sensor, SensorConfig):
        raise TypeError(f"{name}: sensor must be a jaxsr.SensorConfig, got {type(sensor).__name__}")
    return sensor


def require_hr_pair(name, depth, intensity, sensor):
    """Check that depth and intensity are (..., H, W) arrays of the same shape with (H, W) = sensor.hr_shape."""
    require_sensor(name, sensor)
    depth, intensity = require_array(name, "depth", depth), require_array(name, "intensity", intensity)
    hr = tuple(sensor.hr_shape)
    if depth.ndim < 2 or depth.shape[-2:] != hr:
        raise ValueError(
            f"{name}: depth must have shape (..., {hr[0]}, {hr[1]}) (HR rows, cols of the SensorConfig), got "
            f"{depth.shape}; for another frame size use SensorConfig(hr_shape=...) divisible by scale {sensor.scale}"
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
