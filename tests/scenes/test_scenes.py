"""Procedural scenes and the ray caster: closed-form geometry, physical motion, determinism, variety, windows.

One jitted renderer (8 frames) is shared by the tests to keep compilation to a few seconds."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr import scenes
from jaxsr.config import Sensor
from jaxsr.scenes import Boxes, Cylinders, Ellipsoids, Motion, test_sets, tile_overflow
from jaxsr.sensor.forward import planar_to_radial

SENSOR = Sensor()
H, W = SENSOR.hr_shape
F = float(SENSOR.focal_px)
T = 8
CAM_H = 1.7

_render = test_sets._render_jit  # one compiled renderer shared with test_sequence (same shapes, same cache)


def frames(scene, fps=100.0, t0=0.0, **kw):
    return _render(scene, t0 + jnp.arange(T, dtype=jnp.float32) / fps, **kw)


def static_motion(n, velocity=(0.0, 0.0, 0.0)):
    v = jnp.broadcast_to(jnp.asarray(velocity, jnp.float32), (n, 3))
    return Motion(v, jnp.broadcast_to(jnp.array([1.0, 0.0, 0.0]), (n, 3)), jnp.full((n,), jnp.inf), jnp.zeros((n, 3)))


def box(centre, half, height, *, velocity=(0.0, 0.0, 0.0), reflectivity=0.5):
    return Boxes(jnp.array([centre], jnp.float32), jnp.array([half], jnp.float32), jnp.array([height], jnp.float32),
                 jnp.zeros(1), jnp.array([reflectivity]), jnp.array([[1.0, 1.0, 0.0, 0.0]]), jnp.ones(1, bool),
                 static_motion(1, velocity))


def ellipsoid(centre, radii):
    return Ellipsoids(jnp.array([centre], jnp.float32), jnp.array([radii], jnp.float32), jnp.zeros(1),
                      jnp.array([0.5]), jnp.array([[1.0, 1.0, 0.0, 0.0]]), jnp.ones(1, bool), static_motion(1))


def cylinder(pivot, length, radius, *, lean=0.0):
    return Cylinders(jnp.array([pivot], jnp.float32), jnp.array([length], jnp.float32),
                     jnp.array([[radius, radius]], jnp.float32), jnp.zeros(1), jnp.array([lean], jnp.float32),
                     jnp.zeros((1, 3)), jnp.array([0.5]), jnp.array([[1.0, 1.0, 0.0, 0.0]]), jnp.ones(1, bool),
                     static_motion(1))


def unit_rays():
    """Unit ray directions (H, W, 3) of the HR pixel centres, camera frame (x right, y up, z forward), float64."""
    x = (np.arange(W) + 0.5 - W / 2) / F
    y = -(np.arange(H) + 0.5 - H / 2) / F
    d = np.stack(np.broadcast_arrays(x[None, :], y[:, None], np.ones((H, W))), -1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


# ---------------------------------------------------------------------------------------------------------
# Geometry against closed forms


def test_ground_plane_and_sky_closed_form():
    depth, intensity = frames(scenes.empty_scene(camera_height=CAM_H, sky=0.9))
    d = unit_rays()
    below = d[..., 1] < 0
    expected = np.where(below, CAM_H / np.where(below, -d[..., 1], 1.0), np.inf)
    np.testing.assert_allclose(np.asarray(depth[0])[below], expected[below], rtol=2e-5)
    assert np.all(np.isinf(np.asarray(depth[0])[~below])), "sky must have no return"
    assert float(intensity[0][~below].min()) > 0.7, "sky must be bright"
    assert float(jnp.min(intensity)) >= 0 and float(jnp.max(intensity)) <= 1


def test_fronto_parallel_plane_is_planar_to_radial():
    z0 = 20.0
    scene = scenes.place(scenes.empty_scene(camera_height=CAM_H), box((0.0, 0.0, z0 + 0.5), (50.0, 0.5), 40.0))
    depth, _ = frames(scene)
    expected = np.asarray(planar_to_radial(jnp.full((H, W), z0), SENSOR))
    d = unit_rays()
    wall = (d[..., 1] >= 0) | (CAM_H / np.maximum(-d[..., 1], 1e-9) > expected)  # the ground is not in front
    assert wall.mean() > 0.7
    np.testing.assert_allclose(np.asarray(depth[0])[wall], expected[wall], rtol=1e-5)


def test_sphere_closed_form():
    c = np.array([1.0, 0.3, 12.0])  # camera frame (y relative to the camera)
    r = 2.0
    scene = scenes.place(scenes.empty_scene(camera_height=CAM_H),
                         ellipsoid((c[0], c[1] + CAM_H, c[2]), (r, r, r)))
    depth = np.asarray(frames(scene)[0][0])
    d = unit_rays()
    b = d @ c
    disc = b ** 2 - (c @ c - r ** 2)
    hit = disc > 1e-3  # away from the grazing silhouette
    expected = b - np.sqrt(np.where(hit, disc, 0.0))
    np.testing.assert_allclose(depth[hit], expected[hit], rtol=3e-5)  # float32 quadratic
    ground = CAM_H / np.maximum(-d[..., 1], 1e-9)
    miss = (disc < -1e-3) & (d[..., 1] >= 0)
    assert np.all(np.isinf(depth[miss]))
    assert np.all(depth[(disc < -1e-3) & (d[..., 1] < 0)] == pytest.approx(ground[(disc < -1e-3) & (d[..., 1] < 0)],
                                                                         rel=1e-4))


def test_vertical_cylinder_closed_form():
    cx, cz, rad, top = -0.8, 9.0, 0.6, 3.0
    scene = scenes.place(scenes.empty_scene(camera_height=CAM_H), cylinder((cx, top, cz), top, rad))
    depth = np.asarray(frames(scene)[0][0])
    d = unit_rays()
    h = np.linalg.norm(d[..., [0, 2]], axis=-1)  # horizontal part of the unit ray
    b = (d[..., 0] * cx + d[..., 2] * cz)
    disc = b ** 2 - h ** 2 * (cx ** 2 + cz ** 2 - rad ** 2)
    t = (b - np.sqrt(np.maximum(disc, 0))) / h ** 2
    y = CAM_H + t * d[..., 1]
    hit = (disc > 1e-3) & (y > 0.05) & (y < top - 0.05)
    np.testing.assert_allclose(depth[hit], t[hit], rtol=1e-5)


def test_leaning_cylinder_matches_brute_force_march():
    """A cylinder leaning by 0.4 rad, checked against marching along rays with an inside test (independent)."""
    pivot, length, rad, lean = np.array([0.5, 2.6, 8.0]), 2.0, 0.25, 0.4
    scene = scenes.place(scenes.empty_scene(camera_height=CAM_H), cylinder(tuple(pivot), length, rad, lean=lean))
    depth = np.asarray(frames(scene)[0][0])
    d = unit_rays()
    p0 = pivot - np.array([0.0, CAM_H, 0.0])
    rows, cols = np.nonzero(np.isfinite(depth) & (depth < 20))
    rng = np.random.default_rng(0)
    pick = rng.choice(len(rows), 40, replace=False)
    ts = np.linspace(5.0, 11.0, 30001)
    for i in pick:
        ray = d[rows[i], cols[i]]
        pts = ts[:, None] * ray[None, :] - p0
        # Horizontal caps: the solid is the oblique slab of heights [top - L cos a, top] of the infinite cylinder.
        height = pts[:, 1]
        inside_oblique = _inside_oblique(pts, lean, rad) & (height <= 0) & (height >= -length * math.cos(lean))
        first = ts[np.argmax(inside_oblique)] if inside_oblique.any() else np.inf
        ground = CAM_H / -ray[1] if ray[1] < 0 else np.inf
        assert depth[rows[i], cols[i]] == pytest.approx(min(first, ground), abs=2e-3)


def _inside_oblique(pts, lean, rad):
    """Inside the renderer's oblique cylinder: the horizontal slice at height y (relative to the pivot) is an
    ellipse centred at -y tan(a) along X, semi-axes rad / cos(a) along X and rad along Z."""
    cx = -pts[:, 1] * math.tan(lean)
    return ((pts[:, 0] - cx) * math.cos(lean) / rad) ** 2 + (pts[:, 2] / rad) ** 2 <= 1.0


@pytest.mark.slow
def test_tiled_culling_matches_full_casting():
    scene, fps = scenes.test_scene("scene1_street")
    a, ia = frames(scene, fps)
    b, ib = frames(scene, fps, tiles=None)
    both = np.isfinite(np.asarray(a)) & np.isfinite(np.asarray(b))
    assert np.array_equal(np.isfinite(np.asarray(a)), np.isfinite(np.asarray(b)))
    differ = np.abs(np.where(both, np.asarray(a) - np.asarray(b), 0.0)) > 1e-3
    assert differ.mean() < 1e-3  # only float32 ties at silhouettes
    assert all(v <= 0 for v in tile_overflow(scene, 0.0).values())


# ---------------------------------------------------------------------------------------------------------
# Motion in physical units


def test_paper_half_pixel_check():
    """35 m, 50 km/h, 100 FPS -> about 0.5 LR pixels per frame, from the closed form, from `mean_lr_shift`, and
    from the rendered edge of a moving wall."""
    v, z, fps = 50.0 / 3.6, 35.0, 100.0
    closed = v / (fps * z) * F / SENSOR.scale
    assert closed == pytest.approx(0.474, abs=0.001)
    scene = scenes.place(scenes.empty_scene(camera_height=CAM_H),
                         box((-20.0, 0.0, z), (20.0, 0.01), 10.0, velocity=(v, 0.0, 0.0)))
    assert float(scenes.mean_lr_shift(scene, fps)) == pytest.approx(closed, rel=1e-3)
    depth, _ = frames(scene, fps)
    row = np.asarray(depth[:, H // 2, :])
    # The wall's right edge (its left edge stays out of view): the count of wall pixels in the row.
    edge = (row < 40).sum(axis=1).astype(float)
    assert np.all(row[:, 0] < 40)
    slope = np.polyfit(np.arange(T), edge, 1)[0] / SENSOR.scale
    assert slope == pytest.approx(closed, abs=0.03)


def test_walkers_100fps_shift_matches_paper():
    scene, fps = scenes.test_scene("walkers_100fps")
    assert fps == 100.0
    closed = 4.3 / 3.6 / (fps * 9.0) * F / SENSOR.scale
    assert closed == pytest.approx(0.16, abs=0.005)  # the paper's 0.16
    assert float(scenes.mean_lr_shift(scene, fps)) == pytest.approx(closed, rel=0.3)


def test_shift_scales_inversely_with_frame_rate():
    scene, _ = scenes.test_scene("scene2_road")
    s25, s100 = float(scenes.mean_lr_shift(scene, 25.0)), float(scenes.mean_lr_shift(scene, 100.0))
    assert s25 > 0 and s25 == pytest.approx(4 * s100, rel=1e-5)


@pytest.mark.slow
def test_training_clips_span_the_paper_shift_range():
    keys = jax.random.split(jax.random.key(0), 32)

    def shift(k):
        scene, fps, t = scenes.training_scene(k)
        return scenes.in_view_lr_shift(scene, fps, t=t), fps

    shifts, fps = (np.asarray(a) for a in jax.jit(jax.vmap(shift))(keys))
    inside = (fps > 1.0) & (fps < 2000.0)  # where the fps clip did not bind
    assert np.all(shifts[inside] > 0.2 * 0.999) and np.all(shifts[inside] < 5.0 * 1.001)
    assert np.all(shifts > 0)
    assert shifts.min() < 0.6 and shifts.max() > 2.0
    assert inside.mean() > 0.8


@pytest.mark.slow
def test_training_clip_jit_vmap():
    keys = jax.random.split(jax.random.key(2), 2)
    depth, intensity, info = jax.jit(jax.vmap(lambda k: scenes.training_clip(k, 2, return_info=True)))(keys)
    assert depth.shape == (2, 2, H, W) and intensity.shape == (2, 2, H, W)
    assert np.all(np.asarray(info["fps"]) >= 1.0)


# ---------------------------------------------------------------------------------------------------------
# API, determinism, variety


_sample_batch = jax.jit(jax.vmap(lambda k: scenes.sample_scene(k)))


@pytest.fixture(scope="module")
def random_batch():
    return _sample_batch(jax.random.split(jax.random.key(5), 12))


def test_sample_scene_vmaps_and_is_deterministic(random_batch):
    batch = random_batch
    assert batch.boxes.centre.shape == (12, scenes.N_BOXES, 3)
    assert batch.cylinders.pivot.shape == (12, scenes.N_CYLINDERS, 3)
    again = _sample_batch(jax.random.split(jax.random.key(5), 12))
    for a, b in zip(jax.tree.leaves(batch), jax.tree.leaves(again)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # Different keys give different layouts.
    assert not np.allclose(np.asarray(batch.boxes.centre[0]), np.asarray(batch.boxes.centre[1]))


def test_scenes_deterministic_per_key_and_moving():
    def render_key(seed):
        return frames(scenes.sample_scene(jax.random.key(seed), kind="street", camera="moving"), 30.0)

    d1, i1 = render_key(3)
    d2, i2 = render_key(3)
    np.testing.assert_array_equal(np.asarray(d1), np.asarray(d2))
    np.testing.assert_array_equal(np.asarray(i1), np.asarray(i2))
    d3, _ = render_key(4)
    assert not np.array_equal(np.asarray(d1), np.asarray(d3))
    assert d1.shape == (T, H, W) and d1.dtype == jnp.float32
    assert np.mean(np.asarray(d1[0]) != np.asarray(d1[-1])) > 1e-3, "a moving camera moves the image"


@pytest.mark.slow
def test_sequence_equals_scene_rendering():
    d, i = scenes.sequence(jax.random.key(3), T, 30.0, kind="street", camera="moving")
    scene = scenes.sample_scene(jax.random.key(3), kind="street", camera="moving")
    d2, i2 = frames(scene, 30.0)
    a, b = np.asarray(d), np.asarray(d2)
    assert np.array_equal(np.isfinite(a), np.isfinite(b))
    close = np.isclose(a, b, rtol=1e-5) | ~np.isfinite(a)
    assert close.mean() > 0.9999  # the same up to float32 rounding (different XLA fusion) at a few silhouettes
    assert d.shape == (T, H, W)


def test_variety_of_random_scenes(random_batch):
    batch = random_batch
    counts = np.asarray(batch.boxes.active.sum(1) * 100 + batch.cylinders.active.sum(1))
    assert len(set(counts.tolist())) >= 6, "scenes differ in content"
    shifts = np.asarray(jax.vmap(lambda s: scenes.mean_lr_shift(s, 30.0))(batch))
    assert shifts.std() > 0.1, "scenes differ in motion"
    moving = np.asarray(jnp.abs(batch.camera.velocity[:, 0]) > 0)
    assert moving.any() and not moving.all(), "static and moving cameras both occur"
    spreads = []
    for j in range(4):
        d, _ = _render(jax.tree.map(lambda x: x[j], batch), jnp.zeros(T))
        r = np.asarray(d[0])
        spreads.append(np.std(np.clip(r[np.isfinite(r)], 0, 35)))
    assert max(spreads) - min(spreads) > 0.5, "scenes differ in depth spread"


def test_each_kind_renders_plausibly():
    for kind in scenes.KINDS:
        scene = scenes.sample_scene(jax.random.key(7), kind=kind)
        depth, intensity = frames(scene, 30.0)
        d = np.asarray(depth)
        finite = d[np.isfinite(d)]
        assert finite.size > 0.5 * d.size, kind
        assert finite.min() > 0.05 and np.median(finite) < 60, kind
        i = np.asarray(intensity)
        assert 0 <= i.min() and i.max() <= 1 and i.std() > 0.03, kind
        # Intensity is not a copy of depth.
        assert abs(np.corrcoef(np.clip(d[0], 0, 35).ravel(), i[0].ravel())[0, 1]) < 0.9, kind


def test_unknown_kind_and_options_raise():
    with pytest.raises(ValueError, match="unknown scene kind"):
        scenes.sample_scene(jax.random.key(0), kind="forest")
    with pytest.raises(ValueError, match="camera"):
        scenes.sample_scene(jax.random.key(0), kind="street", camera="flying")
    with pytest.raises(ValueError, match="named kind"):
        scenes.sample_scene(jax.random.key(0), n_people=(1, 2))


@pytest.mark.slow
def test_test_sequences_are_fixed_and_labelled():
    seqs = scenes.test_sequences(n_frames=T, names=["scene1_street", "scene3_courtyard"])
    assert seqs["scene1_street"].snr == 1.3 and seqs["scene3_courtyard"].snr == 3.0
    assert seqs["scene1_street"].depth.shape == (T, H, W)
    again = scenes.test_sequence("scene1_street", n_frames=T)
    np.testing.assert_array_equal(seqs["scene1_street"].depth, again.depth)
    assert set(scenes.TEST_SEQUENCES) >= {"scene1_street", "scene2_road", "scene3_courtyard", "walkers_100fps"}
    assert {v[3] for k, v in scenes.TEST_SEQUENCES.items() if k.startswith("scene")} == {1.3, 3.0}
    with pytest.raises(ValueError, match="unknown test sequence"):
        scenes.test_sequence("scene9")


# ---------------------------------------------------------------------------------------------------------
# Temporal windows and frame-rate changes


@pytest.mark.parametrize("jit", [False, True])
def test_windows_edge_replication(jit):
    seq = jnp.arange(5.0)[:, None, None] * jnp.ones((5, 2, 3))
    fn = jax.jit(scenes.windows, static_argnums=1) if jit else scenes.windows
    w = fn(seq, 2)
    assert w.shape == (5, 5, 2, 3)
    expected = np.clip(np.arange(5)[:, None] + np.arange(-2, 3)[None, :], 0, 4)
    np.testing.assert_array_equal(np.asarray(w[:, :, 0, 0]), expected)
    np.testing.assert_array_equal(np.asarray(scenes.windows(seq, 0))[:, 0], np.asarray(seq))
    with pytest.raises(ValueError):
        scenes.windows(seq, -1)


def test_change_frame_rate():
    seq = np.arange(100)
    np.testing.assert_array_equal(scenes.change_frame_rate(seq, 100, 25), np.arange(0, 100, 4))
    assert len(scenes.change_frame_rate(seq, 100, 100)) == 100
    with pytest.raises(ValueError, match="integer"):
        scenes.change_frame_rate(seq, 100, 30)
