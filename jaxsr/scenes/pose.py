"""Posing: every primitive of a scene in the camera frame at one time.

Each primitive becomes a flat vector of intersection parameters, a camera-frame axis-aligned bounding box (for
screen-space culling and motion statistics) and a row of the shading table. Motion wraps about the camera
(`Motion`), the camera translates and pans (`Camera`). Per primitive, so cheap next to the ray casting.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..config import Sensor
from .primitives import Boxes, Camera, Cylinders, Ellipsoids, Motion, Scene

__all__ = ["BOX", "CYL", "ELL", "NEAR", "Group", "pose_all", "project_bounds"]

NEAR = 0.05  # m: near clipping plane
BOX, CYL, ELL = 0, 1, 2  # primitive type codes, the first column of the shading table


class Group(NamedTuple):
    """One primitive type posed at one time."""

    params: jax.Array  # (P, K) intersection parameters
    active: jax.Array  # (P,) bool
    aabb: jax.Array  # (P, 6): x0, x1, y0, y1, z0, z1 in the camera frame
    shading: jax.Array  # (P, 15) rows of the shading table


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
    shading = _shading_rows(BOX, centre, c, s, h1, jnp.zeros_like(h1), h2, jnp.zeros_like(h1), b.reflectivity,
                            b.texture)
    return Group(params, b.active, aabb, shading)


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
    shading = _shading_rows(CYL, pivot, c, s, ra, jnp.ones_like(ra), rb, tan_a, cy.reflectivity, cy.texture)
    return Group(params, cy.active, aabb, shading)


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
    shading = _shading_rows(ELL, centre, c, s, r1, r2, r3, jnp.zeros_like(r1), e.reflectivity, e.texture)
    return Group(params, e.active, aabb, shading)



def project_bounds(aabb, sensor: Sensor, tilt):
    """Conservative pixel bounds (P, 4): col_min, col_max, row_min, row_max (continuous pixel coordinates)."""
    h, w = sensor.hr_shape
    f = sensor.focal_px
    z0 = jnp.maximum(aabb[:, 4], NEAR)
    z1 = jnp.maximum(aabb[:, 5], NEAR)
    xs = jnp.stack([aabb[:, 0] / z0, aabb[:, 0] / z1, aabb[:, 1] / z0, aabb[:, 1] / z1], -1)
    ys = jnp.stack([aabb[:, 2] / z0, aabb[:, 2] / z1, aabb[:, 3] / z0, aabb[:, 3] / z1], -1)
    visible = aabb[:, 5] > NEAR
    col0, col1 = f * xs.min(-1) + w / 2, f * xs.max(-1) + w / 2
    row0, row1 = -f * (ys.max(-1) + tilt) + h / 2, -f * (ys.min(-1) + tilt) + h / 2
    return jnp.stack([col0, col1, row0, row1], -1), visible



def pose_all(scene: Scene, t):
    """Every primitive group of `scene` posed at time `t` (s): ((boxes, cylinders, ellipsoids) as `Group`s,
    camera position (3,), camera yaw)."""
    cam_pos, psi = _camera_at(scene.camera, t)
    groups = (
        _pose_boxes(scene.boxes, cam_pos, psi, t),
        _pose_cylinders(scene.cylinders, cam_pos, psi, t),
        _pose_ellipsoids(scene.ellipsoids, cam_pos, psi, t),
    )
    return groups, cam_pos, psi
