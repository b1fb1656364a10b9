"""The depth units the super-resolution functions take and give (`units`): "normalised" (the network's own scale,
1.0 = no return; the default, as every jaxsr version before read and wrote it) or "m" (radial metres, inf or NaN
= no return, converted on the sensor's depth scale, `jaxsr.Sensor.depth`).
"""

from __future__ import annotations

import jax.numpy as jnp

from ..config import Sensor
from ..sensor.gates import from_network_depth, to_network_depth

__all__ = ["UNITS", "check_units", "lr_to_network", "network_to_units"]

UNITS = ("normalised", "m")


def check_units(who: str, units, sensor, *, depth_input: bool) -> Sensor:
    """The sensor to convert with (`Sensor()` when None); ValueError for units other than `UNITS`, TypeError for a
    sensor that is no `jaxsr.Sensor`, and ValueError for a sensor given beside normalised depth input (the depth
    scale would do nothing: metres need units="m")."""
    if not isinstance(units, str) or units not in UNITS:
        raise ValueError(f"{who}: units is 'normalised' (the network's scale, 1.0 = no return) or 'm' (radial "
                         f"metres on the sensor's depth scale), got {units!r}")
    if sensor is None:
        return Sensor()
    if not isinstance(sensor, Sensor):
        raise TypeError(f"{who}: sensor is a jaxsr.Sensor, got {type(sensor).__name__}")
    if depth_input and units == "normalised":
        raise ValueError(f"{who}: a sensor converts depth in metres; give units='m' with it (normalised depth is "
                         "on the network's scale already)")
    return sensor


def lr_to_network(lr, units: str, sensor: Sensor, *, channels: bool = False):
    """LR depth in `units` -> the network's normalised depth: (..., h, w), or with `channels` (..., h, w, C)
    whose photon channels are kept and whose depth (channel 0) is converted. jit-compatible; metres:
    `to_network_depth` on `sensor.depth` (NaN, inf and beyond the span: 1.0, no return)."""
    if units == "normalised":
        return lr
    lr = jnp.asarray(lr, jnp.float32)
    if channels:
        return lr.at[..., 0].set(to_network_depth(lr[..., 0], sensor.depth).astype(jnp.float32))
    return to_network_depth(lr, sensor.depth).astype(jnp.float32)


def network_to_units(hr, units: str, sensor: Sensor):
    """The network's output (..., H, W), normalised and unclipped -> `units`: itself, or radial metres
    (`from_network_depth` on `sensor.depth`, inf for no return). jit-compatible."""
    if units == "normalised":
        return hr
    return from_network_depth(hr, sensor.depth).astype(jnp.float32)
