"""The scene description: a camera, the ground and fixed-size groups of primitives, all pytrees of arrays.

Coordinates (metres, right-handed with Y up):

- world: X to the right of the camera's initial view, Y up (the ground is the plane Y = 0), Z forward
  (the camera's initial viewing direction);
- camera: at height `camera.height`, looking horizontally (no pitch, no roll: the image's vertical axis is
  the world's vertical), yaw `psi` about Y (positive turns the view towards +X). Camera-frame coordinates are
  x right, y up (height relative to the camera), z forward (planar depth);
- pixels: HR pixel (row, col) has centre (col + 0.5, row + 0.5); its ray direction in the camera frame is
  D = ((col + 0.5 - W/2) / f, -(row + 0.5 - H/2) / f - tilt, 1) with f = `sensor.focal_px`
  (`jaxsr.sensor.forward.pixel_rays`), so the ray parameter along D is the planar depth z, and the radial depth
  is r = z |D|; with tilt = 0 this is the relation of `jaxsr.sensor.forward.planar_to_radial`. A camera 1.7 m up
  looking level sees the ground only beyond 13 m (the vertical field of view is 15.25 deg), so scenes use a small
  tilt (a lens shift, not a rotation, so that the image's vertical stays the world's vertical and the ray casting
  stays separable).

A `Scene` holds a fixed number of primitives per type, each with an `active` mask, so scenes sampled under
`jax.vmap` share one shape and rendering is pure and jittable. Primitive types, chosen so that most of the
ray casting factorises into per-row and per-column terms:

- `Boxes`: boxes with vertical sides and a yaw (buildings, walls, fences, car bodies, benches, tables);
- `Cylinders`: solid cylinders with horizontal caps whose axis may lean and swing about a pivot at the top
  (limbs with a gait, torsos, poles, tree trunks);
- `Ellipsoids`: ellipsoids with a vertical axis and a yaw (heads, tree crowns, wheels, bushes, spheres).

Every primitive moves with a constant velocity (m/s) and wraps around along a `wrap_axis` when it is more than
`wrap_half` metres from the camera along that axis, so traffic keeps coming in long sequences.
"""

from __future__ import annotations

from typing import NamedTuple

import jax

__all__ = ["TEX_PARAMS", "Boxes", "Camera", "Cylinders", "Ellipsoids", "Ground", "Motion", "Scene"]

# Texture parameters per primitive: (period_s [m], period_h [m], amplitude, phase [rad]).
TEX_PARAMS = 4


class Camera(NamedTuple):
    """Camera pose and motion. position (3,) m at t = 0 (Y is the height above the ground), velocity (3,) m/s,
    yaw (rad, positive towards +X), yaw_rate (rad/s), and tilt: a downward view emulated by a vertical lens shift
    (the ray of a pixel has dy reduced by `tilt`, so the horizon sits tilt * focal_px pixels above the centre;
    verticals stay vertical). tilt = 0 is the centred pinhole of docs/sensor-model.md."""

    position: jax.Array
    velocity: jax.Array
    yaw: jax.Array
    yaw_rate: jax.Array
    tilt: jax.Array = 0.0


class Motion(NamedTuple):
    """Linear motion with wrap-around, per primitive: velocity (N, 3) m/s, wrap_axis (N, 3) unit vector,
    wrap_half (N,) m (position along the axis relative to the camera is wrapped into [-wrap_half, wrap_half)),
    anchor (N, 3) m: the point that wraps (the object's reference), so all parts of an object wrap together."""

    velocity: jax.Array
    wrap_axis: jax.Array
    wrap_half: jax.Array
    anchor: jax.Array


class Boxes(NamedTuple):
    """Boxes with vertical sides. centre (N, 3): footprint centre X, bottom height Y, Z; half (N, 2): half
    extents along the box's own axes e1 = (cos yaw, sin yaw) and e2 = (-sin yaw, cos yaw) in (X, Z);
    height (N,); yaw (N,); reflectivity (N,); texture (N, 4); active (N,) bool."""

    centre: jax.Array
    half: jax.Array
    height: jax.Array
    yaw: jax.Array
    reflectivity: jax.Array
    texture: jax.Array
    active: jax.Array
    motion: Motion


class Cylinders(NamedTuple):
    """Solid cylinders hanging from a pivot: pivot (N, 3) (the top centre), length (N,) along the axis,
    radius (N, 2) of the cross-section along e1 and e2 (yaw as for boxes), yaw (N,), lean (N,) rad (static
    tilt of the axis in the e1-vertical plane: positive puts the lower end forward, along +e1), swing (N, 3):
    (amplitude rad, frequency Hz, phase rad) of a pendulum gait added to the lean; reflectivity, texture,
    active, motion as for boxes."""

    pivot: jax.Array
    length: jax.Array
    radius: jax.Array
    yaw: jax.Array
    lean: jax.Array
    swing: jax.Array
    reflectivity: jax.Array
    texture: jax.Array
    active: jax.Array
    motion: Motion


class Ellipsoids(NamedTuple):
    """Ellipsoids: centre (N, 3), radii (N, 3) along (e1, up, e2), yaw (N,); the rest as for boxes."""

    centre: jax.Array
    radii: jax.Array
    yaw: jax.Array
    reflectivity: jax.Array
    texture: jax.Array
    active: jax.Array
    motion: Motion


class Ground(NamedTuple):
    """The ground plane Y = 0: reflectivity, texture (4,) (period_s along X, period_h along Z, amplitude,
    phase), a lane marking parallel to X at Z = lane_z (set beyond range to hide it), sky brightness in [0, 1]."""

    reflectivity: jax.Array
    texture: jax.Array
    lane_z: jax.Array
    sky: jax.Array


class Scene(NamedTuple):
    """A whole scene: camera, ground and the three primitive groups (inactive slots fill each group)."""

    camera: Camera
    ground: Ground
    boxes: Boxes
    cylinders: Cylinders
    ellipsoids: Ellipsoids
