"""The pinhole camera of a depth frame: intrinsics (fx, fy, cx, cy) in pixels, and the back-projection of depth to
3-D points as a pure function of arrays (`jax.jit`, `jax.vmap` and `jax.grad` go through it).

Pixel conventions are OpenCV's and Open3D's (`cv2.calibrateCamera`'s K, `open3d.camera.PinholeCameraIntrinsic`):
the pixel in row v, column u has its centre at image coordinates (u, v); (cx, cy) is the principal point in those
coordinates, so a centred camera of a W x H frame has cx = (W - 1) / 2, cy = (H - 1) / 2. The ray through a pixel
is D = ((u - cx) / fx, (v - cy) / fy, 1) in the OpenCV camera frame. The sensor model's camera
(`Sensor.fov_deg` across the width, square pixels, rays through col + 0.5, row + 0.5 about the frame's
centre, `jaxsr.sensor.forward.pixel_rays`) is `Intrinsics.from_fov(hr_shape, fov_deg)`.

Depth is "radial" (the range r along the ray: what a time-of-flight sensor measures and what jaxsr's depth is; the
point is r D / |D|) or "planar" (the z of a z-buffer, as AirSim's DepthPlanar or a depth camera's image; the
point is z D).

Axes of the points, both right-handed, metres:
- "opencv": x right, y down, z forward (OpenCV, Open3D's `PointCloud.create_from_depth_image`, COLMAP);
- "opengl": x right, y up, z backward, the camera looking along -z (OpenGL, Blender's and three.js's cameras;
  Open3D's examples turn an "opencv" cloud into this with diag(1, -1, -1) so that its viewer shows it upright).
"""

from __future__ import annotations

import math
import numbers
from typing import NamedTuple

import jax.numpy as jnp

__all__ = ["AXES", "DEPTH_KINDS", "Intrinsics", "as_intrinsics", "back_project"]

AXES = ("opencv", "opengl")
DEPTH_KINDS = ("radial", "planar")


class Intrinsics(NamedTuple):
    """A pinhole camera's intrinsics in pixels (OpenCV's K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]): focal lengths
    fx, fy and principal point cx, cy, pixel centres at integer coordinates (see the module). A pytree: its four
    numbers may be traced (vmap over a focal length, grad with respect to it)."""

    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def of_optics(cls, optics, *, hr: bool = True) -> "Intrinsics":
        """The pinhole of a `jaxsr.Optics`' HR frame (or, hr=False, its SPAD frame), in OpenCV's terms, as point
        clouds take it. Needs a concrete fov_deg."""
        return cls.from_fov(optics.hr_shape if hr else optics.lr_shape, float(optics.fov_deg))

    @classmethod
    def from_fov(cls, shape, fov_deg) -> "Intrinsics":
        """The centred camera of an (H, W) frame whose fields of view span its width and height: fov_deg a
        horizontal angle in degrees (square pixels, fy = fx) or (horizontal, vertical). Returns `Intrinsics`
        with fx = (W / 2) / tan(fov_x / 2), fy = (H / 2) / tan(fov_y / 2), cx = (W - 1) / 2, cy = (H - 1) / 2."""
        h, w = (int(n) for n in shape)
        pair = fov_deg if isinstance(fov_deg, (tuple, list)) else (fov_deg,)
        if len(pair) not in (1, 2) or not all(_real(a) and 0 < a < 180 for a in pair):
            raise ValueError(f"fov_deg: expected a horizontal field of view in (0, 180) degrees, or (horizontal, "
                             f"vertical), got {fov_deg!r}")
        fx = (w / 2) / math.tan(math.radians(float(pair[0])) / 2)
        fy = fx if len(pair) == 1 else (h / 2) / math.tan(math.radians(float(pair[1])) / 2)
        return cls(fx, fy, (w - 1) / 2, (h - 1) / 2)

    def scaled(self, scale) -> "Intrinsics":
        """The same camera on a frame `scale` times finer (LR intrinsics -> HR, scale 4): the focal lengths scale,
        and the principal point keeps its place on the sensor: an LR pixel u covers HR pixels s u .. s u + s - 1,
        whose middle is s (u + 0.5) - 0.5. Returns `Intrinsics`."""
        s = float(scale)
        return Intrinsics(self.fx * s, self.fy * s, s * (self.cx + 0.5) - 0.5, s * (self.cy + 0.5) - 0.5)


def _real(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(float(value))


def as_intrinsics(value, what: str = "intrinsics") -> Intrinsics:
    """Check four numbers fx, fy, cx, cy (a sequence or `Intrinsics`) on the host: finite, focal lengths > 0.
    Returns `Intrinsics` of Python floats; raises ValueError naming `what`."""
    try:
        numbers_ = tuple(value)
    except TypeError:
        numbers_ = ()
    if len(numbers_) != 4 or not all(_real(v) for v in numbers_):
        raise ValueError(f"{what}: expected four finite numbers fx, fy, cx, cy in pixels, got {value!r}")
    fx, fy, cx, cy = (float(v) for v in numbers_)
    if not (fx > 0 and fy > 0):
        raise ValueError(f"{what}: the focal lengths fx, fy must be > 0 pixels, got fx={fx:g}, fy={fy:g}")
    return Intrinsics(fx, fy, cx, cy)


def back_project(depth, intrinsics, *, depth_kind: str = "radial", axes: str = "opencv"):
    """The 3-D point of every pixel of depth frames: (..., H, W) depth in metres -> (..., H, W, 3) x, y, z in
    metres. Returns NaN points where there is no return (inf, NaN or negative depth).

    intrinsics: `Intrinsics` (or four numbers fx, fy, cx, cy) of the frame's pixels, possibly traced;
    depth_kind: "radial" (range along the ray) or "planar" (z); axes: "opencv" or "opengl" (see the module).
    Pure: jit, vmap and grad go through it (no-return pixels give zero gradients, not NaN).
    """
    if depth_kind not in DEPTH_KINDS:
        raise ValueError(f"depth_kind: expected one of {', '.join(DEPTH_KINDS)}, got {depth_kind!r}")
    if axes not in AXES:
        raise ValueError(f"axes: expected one of {', '.join(AXES)}, got {axes!r}")
    depth = jnp.asarray(depth)
    if depth.ndim < 2:
        raise ValueError(f"back_project: expected depth (..., H, W), got {depth.shape}")
    dtype = jnp.promote_types(depth.dtype, jnp.float32)
    depth = depth.astype(dtype)
    fx, fy, cx, cy = (jnp.asarray(v, dtype) for v in intrinsics)
    h, w = depth.shape[-2:]
    x = (jnp.arange(w, dtype=dtype) - cx) / fx
    y = (jnp.arange(h, dtype=dtype) - cy) / fy
    rays = jnp.stack(jnp.broadcast_arrays(x[None, :], y[:, None], jnp.ones((h, w), dtype)), axis=-1)  # (H, W, 3)
    valid = jnp.isfinite(depth) & (depth >= 0)
    along = jnp.where(valid, depth, 0)  # 0, not inf, where there is no return: finite gradients
    if depth_kind == "radial":
        along = along / jnp.sqrt(jnp.sum(rays * rays, axis=-1))
    points = along[..., None] * rays
    if axes == "opengl":
        points = points * jnp.asarray([1, -1, -1], dtype)
    return jnp.where(valid[..., None], points, jnp.nan)
