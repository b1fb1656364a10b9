"""Cheap input validation shared by the public functions (shapes always, values only when concrete)."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def is_concrete(x) -> bool:
    """True when `x` holds values we can inspect now (not a tracer inside jit/vmap/grad)."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x))


def require_hr_pair(name, depth, intensity, sensor):
    """Check that depth and intensity are (..., H, W) arrays of the same shape with (H, W) = sensor.hr_shape."""
    depth, intensity = jnp.asarray(depth), jnp.asarray(intensity)
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
    counts = jnp.asarray(counts)
    if counts.ndim < 1 or counts.shape[-1] != sensor.bins:
        raise ValueError(f"{name}: counts must have shape (..., {sensor.bins}) (K bins last), got {counts.shape}")
    return counts
