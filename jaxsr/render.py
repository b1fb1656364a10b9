"""Analytic ray casting of procedural scenes to radial depth and intensity (the "our AirSim" renderer).

Coordinates (metres, right-handed with Y up):

- world: X to the right of the camera's initial view, Y up (the ground is the plane Y = 0), Z forward
  (the camera's initial viewing direction);
- camera: at height `camera.height`, looking horizontally (no pitch, no roll: the image's vertical axis is
  the world's vertical), yaw `psi` about Y (positive turns the view towards +X). Camera-frame coordinates are
  x right, y up (height relative to the camera), z forward (planar depth);
- pixels: HR pixel (row, col) has centre (col + 0.5, row + 0.5); its ray direction in the camera frame is
  D = ((col + 0.5 - W/2) / f, -(row + 0.5 - H/2) / f - tilt, 1) with f = `sensor.focal_px`, so the ray
  parameter along D is the planar depth z, and the radial depth is r = z |D|; with tilt = 0 this is the relation
  of `jaxsr.sensor.planar_to_radial`. A camera 1.7 m up looking level sees the ground only beyond 13 m (the
  vertical field of view is 15.25 deg), so scenes use a small tilt (a lens shift, not a rotation, so that the
  image's vertical stays the world's vertical and the ray casting stays separable).

A `Scene` is a pytree of fixed-size arrays (a fixed number of primitives per type, each with an `active`
mask), so scenes sampled under `jax.vmap` share one shape and `render(scene, t)` is pure and jittable.
Primitive types, chosen so that most of the work factorises into per-row and per-column terms:

- `Boxes`: boxes with vertical sides and a yaw (buildings, walls, fences, car bodies, benches, tables);
- `Cylinders`: solid cylinders with horizontal caps whose axis may lean and swing about a pivot at the top
  (limbs with a gait, torsos, poles, tree trunks);
- `Ellipsoids`: ellipsoids with a vertical axis and a yaw (heads, tree crowns, wheels, bushes, spheres).

Every primitive moves with a constant velocity (m/s) and wraps around along a `wrap_axis` when it is more than
`wrap_half` metres from the camera along that axis, so traffic keeps coming in long sequences. Intensity is
reflectivity x procedural texture x a Lambertian-like shading term, in [0, 1]; the sky has no return
(depth = inf) and is bright.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .config import SensorConfig

__all__ = [
    "Boxes",
    "Camera",
    "Cylinders",
    "Ellipsoids",
    "Ground",
    "Scene",
    "pixel_rays",
    "render",
    "render_sequence",
    "tile_overflow",
]

# Texture parameters per primitive: (period_s [m], period_h [m], amplitude, phase [rad]).
TEX_PARAMS = 4


class Camera(NamedTuple):
    """Camera pose and motion. position (3,) m at t = 0 (Y is the height above the ground), velocity (3,) m/s,
    yaw (rad, positive towards +X), yaw_rate (rad/s), and tilt: a downward view emulated by a vertical lens shift
    (the ray of a pixel has dy reduced by `tilt`, so the horizon sits tilt * focal_px pixels above the centre;
    verticals stay vertical). tilt = 0 is the centred pinhole of PHYSICS.md."""

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
    camera: Camera
    ground: Ground
    boxes: Boxes
    cylinders: Cylinders
    ellipsoids: Ellipsoids


def pixel_rays(sensor: SensorConfig = SensorConfig()):
    """Ray directions of the HR pixel centres in the camera frame, scaled so that their z component is 1.

    Returns (dx (W,), dy (H,), norm (H, W)): D = (dx[col], dy[row], 1) and norm = |D|, so a planar depth z is
    the radial depth z * norm.
    """
    h, w = sensor.hr_shape
    f = sensor.focal_px
    dx = (jnp.arange(w, dtype=jnp.float32) + 0.5 - w / 2) / f
    dy = -(jnp.arange(h, dtype=jnp.float32) + 0.5 - h / 2) / f
    norm = jnp.sqrt(1.0 + dx[None, :] ** 2 + dy[:, None] ** 2)
    return dx, dy, norm


# ---------------------------------------------------------------------------------------------------------
# Motion and camera transforms (per primitive: cheap)


def _camera_at(camera: Camera, t):
    return camera.position + camera.velocity * t, camera.yaw + camera.yaw_rate * t


def _moved(points, motion: Motion, cam_pos, t):
    """Positions (N, 3) at time t of points that move with `motion`, wrapped about the camera position."""
    anchor = motion.anchor + motion.velocity * t
    along = jnp.sum((anchor - cam_pos) * motion.wrap_axis, axis=-1)
    period = 2.0 * motion.wrap_half
    wrapped = jnp.where(jnp.isfinite(period), jnp.mod(along + motion.wrap_half, period) - motion.wrap_half, along)
    shift = motion.velocity * t + (wrapped - along)[:, None] * motion.wrap_axis
    return points + shift


def _to_camera(points, cam_pos, psi):
    """World points (N, 3) -> camera frame (x right, y up relative to the camera, z forward)."""
    d = points - cam_pos
    c, s = jnp.cos(psi), jnp.sin(psi)
    return jnp.stack([c * d[:, 0] - s * d[:, 2], d[:, 1], s * d[:, 0] + c * d[:, 2]], axis=-1)


# ---------------------------------------------------------------------------------------------------------
# Posing: every primitive in the camera frame at one time, as a flat parameter vector per primitive, plus its
# camera-frame axis-aligned bounding box (for screen-space culling) and a row of the shading table.

_NEAR = 0.05  # m: near clipping plane
_INF = jnp.inf
_BOX, _CYL, _ELL = 0, 1, 2


class _Group(NamedTuple):
    params: jax.Array  # (P, K) intersection parameters
    active: jax.Array  # (P,) bool
    aabb: jax.Array  # (P, 6): x0, x1, y0, y1, z0, z1 in the camera frame
    shading: jax.Array  # (P, 15) rows of the shading table


def _shading_rows(kind, origin, c, s, a1, a2, a3, tan_a, reflectivity, texture):
    n = origin.shape[0]
    cols = [jnp.full((n,), kind, jnp.float32), origin[:, 0], origin[:, 1], origin[:, 2], c, s, a1, a2, a3, tan_a,
            reflectivity]
    return jnp.concatenate([jnp.stack(cols, axis=-1), texture], axis=-1)


def _pose_boxes(b: Boxes, cam_pos, psi, t):
    centre = _to_camera(_moved(b.centre, b.motion, cam_pos, t), cam_pos, psi)
    yaw = b.yaw + psi
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    h1, h2 = b.half[:, 0], b.half[:, 1]
    y0, y1 = centre[:, 1], centre[:, 1] + b.height
    params = jnp.stack([centre[:, 0], centre[:, 2], c, s, h1, h2, y0, y1], axis=-1)
    ex = jnp.abs(c) * h1 + jnp.abs(s) * h2
    ez = jnp.abs(s) * h1 + jnp.abs(c) * h2
    aabb = jnp.stack([centre[:, 0] - ex, centre[:, 0] + ex, y0, y1, centre[:, 2] - ez, centre[:, 2] + ez], -1)
    shading = _shading_rows(_BOX, centre, c, s, h1, jnp.zeros_like(h1), h2, jnp.zeros_like(h1), b.reflectivity,
                            b.texture)
    return _Group(params, b.active, aabb, shading)


def _pose_cylinders(cy: Cylinders, cam_pos, psi, t):
    pivot = _to_camera(_moved(cy.pivot, cy.motion, cam_pos, t), cam_pos, psi)
    yaw = cy.yaw + psi
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    angle = cy.lean + cy.swing[:, 0] * jnp.sin(2.0 * jnp.pi * cy.swing[:, 1] * t + cy.swing[:, 2])
    cos_a, tan_a = jnp.cos(angle), jnp.tan(angle)
    # A leaning cylinder of radius r has an elliptic horizontal cross-section, r / cos(a) along the lean.
    ra, rb = cy.radius[:, 0] / cos_a, cy.radius[:, 1]
    ex, ez = tan_a * c, tan_a * s
    # Axis centre at camera-frame height y: q - y (ex, ez), q the axis centre at the camera's height.
    qx = pivot[:, 0] + pivot[:, 1] * ex
    qz = pivot[:, 2] + pivot[:, 1] * ez
    y1 = pivot[:, 1]
    y0 = y1 - cy.length * cos_a
    params = jnp.stack([qx, qz, c, s, 1.0 / ra, 1.0 / rb, ex, ez, y0, y1], axis=-1)
    rx = jnp.abs(c) * ra + jnp.abs(s) * rb
    rz = jnp.abs(s) * ra + jnp.abs(c) * rb
    xa, xb = qx - y1 * ex, qx - y0 * ex  # axis x at the top and bottom
    za, zb = qz - y1 * ez, qz - y0 * ez
    aabb = jnp.stack([jnp.minimum(xa, xb) - rx, jnp.maximum(xa, xb) + rx, y0, y1,
                      jnp.minimum(za, zb) - rz, jnp.maximum(za, zb) + rz], -1)
    shading = _shading_rows(_CYL, pivot, c, s, ra, jnp.ones_like(ra), rb, tan_a, cy.reflectivity, cy.texture)
    return _Group(params, cy.active, aabb, shading)


def _pose_ellipsoids(e: Ellipsoids, cam_pos, psi, t):
    centre = _to_camera(_moved(e.centre, e.motion, cam_pos, t), cam_pos, psi)
    yaw = e.yaw + psi
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    r1, r2, r3 = e.radii[:, 0], e.radii[:, 1], e.radii[:, 2]
    params = jnp.stack([centre[:, 0], centre[:, 1], centre[:, 2], c, s, 1.0 / r1, 1.0 / r2, 1.0 / r3], axis=-1)
    ex = jnp.sqrt((c * r1) ** 2 + (s * r3) ** 2)
    ez = jnp.sqrt((s * r1) ** 2 + (c * r3) ** 2)
    aabb = jnp.stack([centre[:, 0] - ex, centre[:, 0] + ex, centre[:, 1] - r2, centre[:, 1] + r2,
                      centre[:, 2] - ez, centre[:, 2] + ez], -1)
    shading = _shading_rows(_ELL, centre, c, s, r1, r2, r3, jnp.zeros_like(r1), e.reflectivity, e.texture)
    return _Group(params, e.active, aabb, shading)


# ---------------------------------------------------------------------------------------------------------
# Intersections. The work factorises into per-column terms (P, n, W), per-row terms (P, n, H) and per-primitive
# constants, computed once for all primitives; per pixel only a few operations remain (`_pixel_*`), which
# return the planar depth (H, W) of one primitive, inf where missed.


def _terms_box(params, dx, dy):
    cx, cz, c, s, h1, h2, y0, y1 = (params[:, i, None] for i in range(8))
    lo, hi = -_INF, _INF
    for ax, az, h in ((c, s, h1), (-s, c, h2)):
        d = ax * dx + az  # ray slope along the box axis, per column
        d = jnp.where(jnp.abs(d) < 1e-9, 1e-9, d)
        o = -(ax * cx + az * cz)
        t1, t2 = (-h - o) / d, (h - o) / d
        lo = jnp.maximum(lo, jnp.minimum(t1, t2))
        hi = jnp.minimum(hi, jnp.maximum(t1, t2))
    ya, yb = y0 / dy, y1 / dy  # dy is never 0 at pixel centres
    col = jnp.stack([lo, hi], 1)
    row = jnp.stack([jnp.minimum(ya, yb), jnp.maximum(ya, yb)], 1)
    return col, row, jnp.zeros((params.shape[0], 1))


def _pixel_box(col, row, const):
    t = jnp.maximum(col[0][None, :], row[0][:, None])
    ok = (t <= jnp.minimum(col[1][None, :], row[1][:, None])) & (t > _NEAR)
    return jnp.where(ok, t, _INF)


def _terms_cylinder(params, dx, dy):
    qx, qz, c, s, ira, irb, ex, ez, y0, y1 = (params[:, i, None] for i in range(10))
    col = jnp.stack([(c * dx + s) * ira, (-s * dx + c) * irb], 1)
    ya, yb = y0 / dy, y1 / dy
    row = jnp.stack([(c * ex + s * ez) * ira * dy, (-s * ex + c * ez) * irb * dy,
                     jnp.minimum(ya, yb), jnp.maximum(ya, yb)], 1)
    q1, q2 = (c * qx + s * qz) * ira, (-s * qx + c * qz) * irb
    return col, row, jnp.concatenate([q1, q2, q1 * q1 + q2 * q2 - 1.0], 1)


def _pixel_cylinder(col, row, const):
    q1, q2, cc = const[0], const[1], const[2]
    g1 = col[0][None, :] + row[0][:, None]
    g2 = col[1][None, :] + row[1][:, None]
    a = g1 * g1 + g2 * g2
    b = g1 * q1 + g2 * q2
    disc = b * b - a * cc
    root = b + jnp.sqrt(jnp.maximum(disc, 0.0))
    near = cc / jnp.maximum(root, 1e-30)  # the smaller root, written to avoid cancellation
    t = jnp.maximum(near, row[2][:, None])
    ok = (disc > 0) & (t * a <= root) & (t <= row[3][:, None]) & (t > _NEAR)  # t * a <= root: t <= far root
    return jnp.where(ok, t, _INF)


def _terms_ellipsoid(params, dx, dy):
    cx, cy, cz, c, s, i1, i2, i3 = (params[:, i, None] for i in range(8))
    col1, col3 = (c * dx + s) * i1, (-s * dx + c) * i3
    row2 = dy * i2
    q1, q2, q3 = (c * cx + s * cz) * i1, cy * i2, (-s * cx + c * cz) * i3
    col = jnp.stack([col1 * col1 + col3 * col3, col1 * q1 + col3 * q3], 1)
    row = jnp.stack([row2 * row2, row2 * q2], 1)
    return col, row, q1 * q1 + q2 * q2 + q3 * q3 - 1.0


def _pixel_ellipsoid(col, row, const):
    a = col[0][None, :] + row[0][:, None]
    b = col[1][None, :] + row[1][:, None]
    cc = const[0]
    disc = b * b - a * cc
    near = cc / jnp.maximum(b + jnp.sqrt(jnp.maximum(disc, 0.0)), 1e-30)
    ok = (disc > 0) & (near > _NEAR) & (b > 0)
    return jnp.where(ok, near, _INF)


_TERMS = {_BOX: _terms_box, _CYL: _terms_cylinder, _ELL: _terms_ellipsoid}
_PIXEL = {_BOX: _pixel_box, _CYL: _pixel_cylinder, _ELL: _pixel_ellipsoid}


# ---------------------------------------------------------------------------------------------------------
# Casting a group: nearest hit over its primitives, either over the whole frame or, with screen-space culling,
# per tile over the `k_max` nearest primitives whose projected bounding box touches the tile.


def _project_bounds(aabb, sensor, tilt):
    """Conservative pixel bounds (P, 4): col_min, col_max, row_min, row_max (continuous pixel coordinates)."""
    h, w = sensor.hr_shape
    f = sensor.focal_px
    z0 = jnp.maximum(aabb[:, 4], _NEAR)
    z1 = jnp.maximum(aabb[:, 5], _NEAR)
    xs = jnp.stack([aabb[:, 0] / z0, aabb[:, 0] / z1, aabb[:, 1] / z0, aabb[:, 1] / z1], -1)
    ys = jnp.stack([aabb[:, 2] / z0, aabb[:, 2] / z1, aabb[:, 3] / z0, aabb[:, 3] / z1], -1)
    visible = aabb[:, 5] > _NEAR
    col0, col1 = f * xs.min(-1) + w / 2, f * xs.max(-1) + w / 2
    row0, row1 = -f * (ys.max(-1) + tilt) + h / 2, -f * (ys.min(-1) + tilt) + h / 2
    return jnp.stack([col0, col1, row0, row1], -1), visible


def _tile_touches(group: _Group, sensor, tiles, tilt):
    """(tiles, P) bool: which active primitives' projected bounding boxes touch each tile (row-major tiles)."""
    h, w = sensor.hr_shape
    n_r, n_c = tiles
    th, tw = h // n_r, w // n_c
    bounds, visible = _project_bounds(group.aabb, sensor, tilt)
    r0 = jnp.repeat(jnp.arange(n_r) * th, n_c)[:, None]
    c0 = jnp.tile(jnp.arange(n_c) * tw, n_r)[:, None]
    return (
        (bounds[None, :, 1] >= c0 - 1) & (bounds[None, :, 0] <= c0 + tw + 1)
        & (bounds[None, :, 3] >= r0 - 1) & (bounds[None, :, 2] <= r0 + th + 1)
        & (visible & group.active)[None, :]
    )


def _running_min(carry, t, idx):
    t_min, i_min = carry
    closer = t < t_min
    return jnp.where(closer, t, t_min), jnp.where(closer, idx, i_min)


def _cast_full(kind, group: _Group, dx, dy):
    col, row, const = jax.lax.optimization_barrier(_TERMS[kind](group.params, dx, dy))
    pixel = _PIXEL[kind]

    def body(carry, xs):  # a scan keeps each step one fused, vectorised loop over the pixels
        c, r, k, active, idx = xs
        return _running_min(carry, jnp.where(active, pixel(c, r, k), _INF), idx), None

    shape = (dy.shape[0], dx.shape[0])
    init = (jnp.full(shape, _INF), jnp.zeros(shape, jnp.int32))
    n = group.params.shape[0]
    (t_min, i_min), _ = jax.lax.scan(body, init, (col, row, const, group.active, jnp.arange(n)))
    return t_min, i_min


def _cast_tiled(kind, group: _Group, dx, dy, sensor, tiles, k_max, tilt):
    h, w = sensor.hr_shape
    n_r, n_c = tiles
    th, tw = h // n_r, w // n_c
    n_t = n_r * n_c
    col, row, const = jax.lax.optimization_barrier(_TERMS[kind](group.params, dx, dy))
    key = jnp.where(_tile_touches(group, sensor, tiles, tilt), group.aabb[None, :, 4], _INF)
    neg, order = jax.lax.top_k(-key, k_max)  # (tiles, k_max), nearest first
    valid = jnp.isfinite(neg)
    tile_c = jnp.tile(jnp.arange(n_c), n_r)
    tile_r = jnp.repeat(jnp.arange(n_r), n_c)
    # Per tile and slot, the primitive's column terms over the tile's columns and row terms over its rows.
    col_t = col.reshape(col.shape[:2] + (n_c, tw))[order, :, tile_c[:, None]]  # (tiles, k, n, tw)
    row_t = row.reshape(row.shape[:2] + (n_r, th))[order, :, tile_r[:, None]]
    const_t = const[order]
    pixel = jax.vmap(_PIXEL[kind])

    def body(carry, xs):
        c, r, k, ok, idx = xs
        return _running_min(carry, jnp.where(ok[:, None, None], pixel(c, r, k), _INF), idx[:, None, None]), None

    init = (jnp.full((n_t, th, tw), _INF), jnp.zeros((n_t, th, tw), jnp.int32))
    slot_first = lambda a: jnp.moveaxis(a, 1, 0)
    (t_min, i_min), _ = jax.lax.scan(
        body, init, (slot_first(col_t), slot_first(row_t), slot_first(const_t), slot_first(valid), slot_first(order))
    )
    untile = lambda a: a.reshape(n_r, n_c, th, tw).transpose(0, 2, 1, 3).reshape(h, w)
    return untile(t_min), untile(i_min)


def tile_overflow(scene: Scene, t, *, sensor: SensorConfig = SensorConfig(), tiles=None, k_max=None):
    """Diagnostic: for each primitive type, the largest number of primitives touching one tile minus its
    `k_max` (> 0 means the tiled renderer dropped the farthest ones somewhere). Returns a dict of ints.

    Args: scene (Scene), t (s). Returns a dict with one int per primitive type (shape-free).
    """
    tiles = DEFAULT_TILES if tiles is None else tiles
    k_max = DEFAULT_K_MAX if k_max is None else k_max
    groups, _, _ = _pose_all(scene, jnp.asarray(t, jnp.float32))
    out = {}
    for name, group, k in zip(("boxes", "cylinders", "ellipsoids"), groups, k_max):
        touches = _tile_touches(group, sensor, tiles, scene.camera.tilt)
        out[name] = int(touches.sum(-1).max()) - min(k, group.params.shape[0])
    return out


# ---------------------------------------------------------------------------------------------------------
# Texture and shading (triangle waves: sin/cos cost 20x more than arithmetic on CPU)


def _wave(x):
    """Triangle wave with period 1, +1 at integers, -1 at half-integers (a cheap cos(2 pi x))."""
    return 4.0 * jnp.abs(x - jnp.floor(x) - 0.5) - 1.0


def _texture(s, h, tex):
    """Procedural texture in [0, 1] at surface coordinates s (along the surface) and h (height), both m.

    tex (..., 4): (period_s, period_h, amplitude, phase). A soft grid of rectangles (windows, bricks, slats,
    paving) scaled by `amplitude` (negative: lighter rectangles), times a fine grain.
    """
    ps, ph, amp, phase = tex[..., 0], tex[..., 1], tex[..., 2], tex[..., 3]
    soft = lambda w: jnp.clip((w - 0.1) * 2.5 + 0.5, 0.0, 1.0)
    grid = soft(_wave(s / ps + phase)) * soft(_wave(h / ph + 0.5 * phase))
    grain = _wave(2.3 * s + 1.1 * h + phase) * _wave(0.7 * s - 1.9 * h + 2.0 * phase)
    return jnp.clip((1.0 - amp * grid) * (0.9 + 0.1 * grain), 0.0, 1.0)


def _shade(cos_incidence):
    """Shading factor from the cosine between the ray and the surface normal: ambient plus Lambertian."""
    return 0.45 + 0.55 * jnp.clip(cos_incidence, 0.0, 1.0)


def _object_intensity(row, px, py, pz, dx, dy, norm):
    """Intensity of object hits from the gathered shading-table rows (H, W, 15) and hit points (H, W)."""
    kind, ox, oy, oz, c, s, a1, a2, a3, tan_a, refl = (row[..., i] for i in range(11))
    tex = row[..., 11:15]
    lx, ly, lz = px - ox, py - oy, pz - oz
    l1, l2 = c * lx + s * lz, -s * lx + c * lz
    # Local normal (along e1, up, e2) for each primitive type.
    box_side1 = jnp.abs(l1) * a3 > jnp.abs(l2) * a1
    box_top = (jnp.abs(l1) < 0.999 * a1) & (jnp.abs(l2) < 0.999 * a3)
    n1 = jnp.where(kind == _BOX, jnp.where(box_side1, jnp.sign(l1), 0.0), (l1 + ly * tan_a) / (a1 * a1))
    ny = jnp.where(kind == _ELL, ly / (a2 * a2), 0.0)
    n3 = jnp.where(kind == _BOX, jnp.where(box_side1, 0.0, jnp.sign(l2)), l2 / (a3 * a3))
    ny = jnp.where((kind == _BOX) & box_top, 1.0, ny)
    n1 = jnp.where((kind == _BOX) & box_top, 0.0, n1)
    n3 = jnp.where((kind == _BOX) & box_top, 0.0, n3)
    nx, nz = c * n1 - s * n3, s * n1 + c * n3
    n_len = jnp.sqrt(nx * nx + ny * ny + nz * nz) + 1e-9
    cos_inc = jnp.abs(nx * dx[None, :] + ny * dy[:, None] + nz) / (n_len * norm)
    return refl * _texture(l1 + l2, ly, tex) * _shade(cos_inc)


# ---------------------------------------------------------------------------------------------------------
# Rendering

# Screen-space culling: tiles (rows, cols) of the HR frame and, per primitive type (boxes, cylinders,
# ellipsoids), how many of the nearest primitives touching a tile are intersected there. None = no culling.
# Measured on 120 random scene-times: at most 7 boxes, 6 cylinders, 2 ellipsoids touch one 32x8 tile.
DEFAULT_TILES = (4, 32)
DEFAULT_K_MAX = (8, 10, 6)


def _pose_all(scene: Scene, t):
    cam_pos, psi = _camera_at(scene.camera, t)
    groups = (
        _pose_boxes(scene.boxes, cam_pos, psi, t),
        _pose_cylinders(scene.cylinders, cam_pos, psi, t),
        _pose_ellipsoids(scene.ellipsoids, cam_pos, psi, t),
    )
    return groups, cam_pos, psi


def render(scene: Scene, t, *, sensor: SensorConfig = SensorConfig(), tiles=DEFAULT_TILES, k_max=DEFAULT_K_MAX):
    """Render one HR frame of `scene` at time `t` (s).

    Returns (depth, intensity), each (H, W) = sensor.hr_shape, float32: radial depth in metres (inf where the
    ray hits nothing: sky) and intensity in [0, 1]. Pure and jittable; vmap over t or over scenes.

    `tiles` (rows, cols) and `k_max` (boxes, cylinders, ellipsoids) set the screen-space culling: in each tile
    only the k_max nearest primitives of a type whose projected bounding box touches the tile are intersected
    (exact unless more touch one tile; see `tile_overflow`). `tiles=None` intersects every primitive with every
    pixel (the reference, slower).
    """
    h, w = sensor.hr_shape
    dx, dy, _ = pixel_rays(sensor)
    dy = dy - scene.camera.tilt
    norm = jnp.sqrt(1.0 + dx[None, :] ** 2 + dy[:, None] ** 2)
    groups, cam_pos, psi = _pose_all(scene, jnp.asarray(t, jnp.float32))
    # Materialise the per-primitive parameters: otherwise XLA recomputes their sin/cos in every pixel.
    groups = jax.lax.optimization_barrier(groups)
    g = scene.ground

    hits = []
    offset = 0
    for kind, group, k in zip((_BOX, _CYL, _ELL), groups, k_max if k_max is not None else (None,) * 3):
        n = group.params.shape[0]
        if tiles is None or k is None or k >= n or h % tiles[0] or w % tiles[1]:
            t_min, i_min = _cast_full(kind, group, dx, dy)
        else:
            t_min, i_min = _cast_tiled(kind, group, dx, dy, sensor, tiles, k, scene.camera.tilt)
        # Materialise: otherwise XLA fuses (recomputes) the whole cast into each consumer.
        hits.append(jax.lax.optimization_barrier((t_min, i_min + offset)))
        offset += n
    cam_h = scene.camera.position[1]
    t_gnd = jnp.where(dy < 0, -cam_h / jnp.where(dy < 0, dy, -1.0), _INF)[:, None] * jnp.ones((1, w))

    z, index = hits[0]
    for t_min, i_min in hits[1:]:
        closer = t_min < z
        z = jnp.where(closer, t_min, z)
        index = jnp.where(closer, i_min, index)
    on_ground = t_gnd < z
    z = jnp.minimum(z, t_gnd)
    hit = jnp.isfinite(z)

    zs = jnp.where(hit, z, 0.0)
    px, py = zs * dx[None, :], zs * dy[:, None]
    table = jnp.concatenate([grp.shading for grp in groups], axis=0)
    obj_int = _object_intensity(table[index], px, py, zs, dx, dy, norm)

    # Ground: texture in world coordinates so that it stays put when the camera moves; a dashed lane line.
    cpsi, spsi = jnp.cos(psi), jnp.sin(psi)
    wx = cam_pos[0] + cpsi * px + spsi * zs
    wz = cam_pos[2] - spsi * px + cpsi * zs
    lane = (jnp.abs(wz - g.lane_z) < 0.12) & (_wave(wx / 6.0) > 0.0)
    gnd_int = g.reflectivity * _texture(wx, wz, g.texture)
    gnd_int = jnp.where(lane, 0.85, gnd_int) * _shade(jnp.abs(dy)[:, None] / norm * 6.0)

    sky = g.sky * (0.85 + 0.15 * jnp.clip(dy[:, None] * 6.0, 0.0, 1.0)) * jnp.ones((1, w))
    intensity = jnp.where(hit, jnp.where(on_ground, gnd_int, obj_int), sky)
    depth = jnp.where(hit, z * norm, jnp.inf)
    return depth.astype(jnp.float32), jnp.clip(intensity, 0.0, 1.0).astype(jnp.float32)


def render_sequence(scene: Scene, times, *, sensor: SensorConfig = SensorConfig(), tiles=DEFAULT_TILES,
                    k_max=DEFAULT_K_MAX):
    """Render `scene` at each time of `times` (T,) s: (depth, intensity), each (T, H, W).

    Args: scene (Scene), times (T,) seconds.
    Returns (depth, intensity), each of shape (T, H, W) float32.
    """
    times = jnp.asarray(times, jnp.float32)
    return jax.vmap(lambda t: render(scene, t, sensor=sensor, tiles=tiles, k_max=k_max))(times)
