"""The pinhole camera (`jaxsr.sensor.camera`): a hand-computed point on each axes convention and depth kind, the
sensor model's rays as fields of view, fields of view that span the frame's edges, LR intrinsics scaled to HR
onto the same rays, and a back-projection that jits, vmaps and differentiates."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr.config import Optics, Sensor
from jaxsr.sensor import Intrinsics, as_intrinsics, back_project, pixel_rays

project = jax.jit(back_project, static_argnames=("depth_kind", "axes"))  # one compile a call's shapes, not an op's

# a 4 x 6 frame whose pixel (row 0, col 3) looks along D = ((3 - 1) / 2, (0 - 2) / 4, 1) = (1, -0.5, 1), |D| = 1.5
CAMERA = Intrinsics(fx=2.0, fy=4.0, cx=1.0, cy=2.0)


@pytest.mark.parametrize("depth_kind,axes,value,point", [
    ("radial", "opencv", 3.0, (2.0, -1.0, 2.0)),  # 3 D / 1.5: x right, y down (above the centre: y < 0), z forward
    ("radial", "opengl", 3.0, (2.0, 1.0, -2.0)),  # y up, the camera looking along -z
    ("planar", "opencv", 2.0, (2.0, -1.0, 2.0)),  # z D
    ("planar", "opengl", 2.0, (2.0, 1.0, -2.0)),
])
def test_a_hand_computed_point(depth_kind, axes, value, point):
    depth = np.full((4, 6), 5.0, np.float32)
    depth[0, 3] = value
    p = np.asarray(project(depth, CAMERA, depth_kind=depth_kind, axes=axes))
    assert p.shape == (4, 6, 3)
    np.testing.assert_allclose(p[0, 3], point, rtol=1e-6)
    # the principal point's pixel (row 2, col 1) looks straight ahead
    np.testing.assert_allclose(p[2, 1], (0.0, 0.0, 5.0 if axes == "opencv" else -5.0), atol=1e-6)


def test_no_return_gives_nan_points_and_zero_gradients():
    depth = np.full((4, 6), 2.0, np.float32)
    depth[0, 0], depth[1, 1], depth[2, 2] = np.inf, np.nan, -1.0
    p = np.asarray(project(depth, CAMERA))
    bad = np.zeros((4, 6), bool)
    bad[0, 0] = bad[1, 1] = bad[2, 2] = True
    assert np.isnan(p[bad]).all() and np.isfinite(p[~bad]).all()

    def total(d, fx):
        pts = back_project(d, CAMERA._replace(fx=fx))
        return jnp.nansum(pts)

    g_depth, g_fx = jax.jit(jax.grad(total, argnums=(0, 1)))(jnp.asarray(depth), 2.0)
    assert np.all(np.asarray(g_depth)[bad] == 0) and np.isfinite(np.asarray(g_depth)).all()
    assert np.isfinite(float(g_fx))


def test_the_sensor_models_camera_is_its_field_of_view():
    assert Intrinsics.from_fov(Sensor().hr_shape, Sensor().fov_deg).fx == pytest.approx(
        float(Sensor().focal_px), rel=1e-6)
    sensor = Sensor(optics=Optics.of_hr((16, 24), 1, fov_deg=50.0))
    cam = Intrinsics.from_fov(sensor.hr_shape, sensor.fov_deg)
    h, w = sensor.hr_shape
    assert (cam.cx, cam.cy) == ((w - 1) / 2, (h - 1) / 2) and cam.fx == cam.fy
    assert cam.fx == pytest.approx(float(sensor.focal_px), rel=1e-6)
    dx, dy, norm = (np.asarray(a, np.float64) for a in jax.jit(pixel_rays)(sensor))
    p = np.asarray(project(np.ones(sensor.hr_shape, np.float32), cam), np.float64)
    # the same rays: x / z = dx, y / z = -dy (pixel_rays' y points up, OpenCV's down), unit range
    np.testing.assert_allclose(p[..., 0] / p[..., 2], np.broadcast_to(dx, (h, w)), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(p[..., 1] / p[..., 2], -np.broadcast_to(dy[:, None], (h, w)), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(p[..., 2], 1 / norm, rtol=1e-6)


@pytest.mark.parametrize("fov", [(60.0, 20.0), (90.0, 120.0), 45.0])
def test_fields_of_view_span_the_frames_edges(fov):
    h, w = 12, 20
    cam = Intrinsics.from_fov((h, w), fov)
    fov_x, fov_y = (fov, None) if np.isscalar(fov) else fov
    # the outer edges of the edge pixels, half a pixel beyond their centres
    angle = lambda lo, hi, c, f: math.degrees(math.atan((hi - c) / f) - math.atan((lo - c) / f))  # noqa: E731
    assert angle(-0.5, w - 0.5, cam.cx, cam.fx) == pytest.approx(fov_x, rel=1e-9)
    if fov_y is None:
        assert cam.fy == cam.fx  # square pixels
    else:
        assert angle(-0.5, h - 0.5, cam.cy, cam.fy) == pytest.approx(fov_y, rel=1e-9)


@pytest.mark.parametrize("scale", [2, 4])
def test_lr_intrinsics_scale_onto_the_same_rays(scale):
    """An LR pixel's ray, through its centre, is the ray through the middle of the s x s HR pixels it covers."""
    lr = Intrinsics(fx=31.0, fy=29.0, cx=7.3, cy=3.9)  # an off-centre calibration of an 8 x 16 sensor
    hr = lr.scaled(scale)
    rows, cols = np.meshgrid(np.arange(8), np.arange(16), indexing="ij")
    lr_rays = np.stack([(cols - lr.cx) / lr.fx, (rows - lr.cy) / lr.fy], -1)
    middle = lambda i: scale * i + (scale - 1) / 2  # noqa: E731  the mean of the HR pixels s i .. s i + s - 1
    hr_rays = np.stack([(middle(cols) - hr.cx) / hr.fx, (middle(rows) - hr.cy) / hr.fy], -1)
    np.testing.assert_allclose(hr_rays, lr_rays, rtol=1e-12, atol=1e-12)
    # the sensor model's centred camera stays centred: LR fields of view give the HR ones
    assert Intrinsics.from_fov((8, 16), (30.0, 16.0)).scaled(scale) == pytest.approx(
        Intrinsics.from_fov((8 * scale, 16 * scale), (30.0, 16.0)), rel=1e-12)


def test_jit_and_vmap_give_the_same_points():
    depth = np.random.default_rng(0).uniform(1, 9, (3, 4, 6)).astype(np.float32)
    eager = np.asarray(back_project(depth, CAMERA, axes="opengl"))
    np.testing.assert_allclose(np.asarray(project(depth, CAMERA, axes="opengl")), eager, rtol=1e-6)
    focal = jnp.asarray([1.0, 2.0, 3.0])
    mapped = jax.jit(jax.vmap(lambda f: back_project(depth[0], CAMERA._replace(fx=f, fy=f))))(focal)
    for i, f in enumerate([1.0, 2.0, 3.0]):
        np.testing.assert_allclose(mapped[i], project(depth[0], CAMERA._replace(fx=f, fy=f)), rtol=1e-6)
    # radial depth: z = r / |D|, so dz/dr = 1 / |D| (|D| = 1.5 at row 0, col 3)
    dz = jax.jit(jax.grad(lambda d: back_project(d, CAMERA)[0, 3, 2]))(jnp.asarray(depth[0]))
    assert float(dz[0, 3]) == pytest.approx(1 / 1.5, rel=1e-6) and float(jnp.abs(dz).sum()) == pytest.approx(1 / 1.5)


@pytest.mark.parametrize("value,message", [
    ((0.0, 2.0, 1.0, 1.0), "must be > 0"),
    ((2.0, -2.0, 1.0, 1.0), "must be > 0"),
    ((2.0, 2.0, 1.0), "four finite numbers"),
    ((2.0, 2.0, float("nan"), 1.0), "four finite numbers"),
    ("2,2,1,1", "four finite numbers"),
])
def test_bad_intrinsics_are_refused(value, message):
    with pytest.raises(ValueError, match=message):
        as_intrinsics(value)


def test_bad_conventions_and_fields_of_view_are_refused():
    with pytest.raises(ValueError, match="depth_kind: expected one of radial, planar"):
        back_project(np.ones((4, 6)), CAMERA, depth_kind="z")
    with pytest.raises(ValueError, match="axes: expected one of opencv, opengl"):
        back_project(np.ones((4, 6)), CAMERA, axes="blender")
    with pytest.raises(ValueError, match=r"expected depth \(\.\.\., H, W\)"):
        back_project(np.ones(6), CAMERA)
    for fov in (0.0, 180.0, (30.0, 200.0), (30.0, 20.0, 10.0)):
        with pytest.raises(ValueError, match="field of view"):
            Intrinsics.from_fov((4, 6), fov)
