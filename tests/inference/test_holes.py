"""`fill_holes`: a black region that returns enclose takes the depth of the surfaces around it (`black_holes` says
which are black)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr import DepthScale
from jaxsr.inference import HOLE_FILL_ITERATIONS, fill_holes, filled_where_holes
from jaxsr.sensor import black_holes

SCALE = DepthScale(0.0, 35.0)


def _plane(h=12, w=16, r=4, offset=0.0, span=35.0):
    """HR normalised depth of a tilted plane: inverse metres affine in the image (a pinhole's view of a plane)."""
    y, x = np.mgrid[0:h * r, 0:w * r].astype(np.float64)
    metres = 1.0 / (0.2 + 0.004 * x + 0.002 * y)  # 1.7-5 m
    return ((metres - offset) / span).astype(np.float32)


def test_a_hole_in_a_plane_is_filled_with_the_plane():
    truth = _plane()
    holes = np.zeros((12, 16), bool)
    holes[3:7, 4:9] = True  # 20 LR pixels: 16 x 20 HR pixels of hole
    holes[9, 13] = True  # a lone one
    guessed = np.where(np.repeat(np.repeat(holes, 4, 0), 4, 1), np.float32(0.9), truth)  # the network's guess
    got = np.asarray(fill_holes(guessed, holes, SCALE))
    np.testing.assert_allclose(got, truth, rtol=0, atol=2e-5)  # 0.7 mm in 35 m


def test_the_gate_start_is_kept_out_of_the_inverse():
    """The network's 0 may lie at 0 m (a gate from 0) or far from it: the plane is filled in metres either way."""
    truth = _plane(offset=1.0, span=10.0)
    holes = np.zeros((12, 16), bool)
    holes[4:8, 6:10] = True
    guessed = np.where(np.repeat(np.repeat(holes, 4, 0), 4, 1), np.float32(0.0), truth)
    got = np.asarray(fill_holes(guessed, holes, DepthScale(1.0, 10.0)))
    np.testing.assert_allclose(got, truth, rtol=0, atol=2e-5)
    wrong = np.asarray(fill_holes(guessed, holes, SCALE))  # read as metres from 0 over 35 m: not the plane
    assert np.abs(wrong - truth).max() > 5e-4  # 25 times the tolerance above


def test_only_the_holes_change_and_frames_without_one_stay_exactly():
    rng = np.random.default_rng(0)
    hr = rng.uniform(0.05, 1.0, (3, 16, 20)).astype(np.float32)
    holes = np.zeros((3, 4, 5), bool)
    holes[1, 1:3, 1:3] = True
    got = np.asarray(fill_holes(hr, holes, SCALE))
    outside = ~np.repeat(np.repeat(holes, 4, 1), 4, 2)
    np.testing.assert_array_equal(got[outside], hr[outside])
    assert not np.array_equal(got[1], hr[1])
    np.testing.assert_array_equal(filled_where_holes(hr[0], holes[0], SCALE), hr[0])
    np.testing.assert_array_equal(filled_where_holes(hr[1], holes[1], SCALE), got[1])


def test_a_hole_lies_within_the_depths_around_it_and_no_further_than_no_return():
    """The harmonic fill's maximum principle: between the nearest and farthest surface around the hole; a hole
    beside no return (1.0) is filled no further."""
    rng = np.random.default_rng(1)
    hr = rng.uniform(0.1, 0.6, (24, 24)).astype(np.float32)
    hr[:, 12:] = 1.0  # no return on the right half
    holes = np.zeros((6, 6), bool)
    holes[2:4, 2:4] = True
    holes[2:4, 5] = True  # at the frame's edge, beside no return
    got = np.asarray(fill_holes(hr, holes, SCALE))
    inside = np.repeat(np.repeat(holes, 4, 0), 4, 1)
    assert got[inside].min() >= 0.1 - 1e-6 and got[inside].max() <= 1.0
    np.testing.assert_allclose(got[:, 20:][inside[:, 20:]], 1.0, atol=1e-5)


@pytest.mark.parametrize("edge", [0.0, -0.5, 1e4])
def test_depths_at_zero_behind_the_gate_start_and_far_beyond_stay_finite(edge):
    hr = np.full((16, 16), np.float32(edge))
    hr[::3] = 0.5
    holes = np.zeros((4, 4), bool)
    holes[1:3, 1:3] = True
    got = np.asarray(fill_holes(hr, holes, SCALE))
    assert np.all(np.isfinite(got)) and got[4:12, 4:12].max() <= 1.0
    grad = jax.grad(lambda d: jnp.sum(fill_holes(d, holes, SCALE)))(jnp.asarray(hr))
    assert np.all(np.isfinite(np.asarray(grad)))


@pytest.mark.slow  # compiles the fill and its gradient: 5-15 s on 2 cores
def test_a_frame_that_is_all_hole_is_left_as_it_is():
    hr = np.linspace(0.1, 0.9, 64, dtype=np.float32).reshape(8, 8)
    np.testing.assert_array_equal(np.asarray(fill_holes(hr, np.ones((2, 2), bool), SCALE)), hr)
    grad = jax.grad(lambda d: jnp.sum(fill_holes(d, jnp.ones((2, 2), bool), SCALE)))(jnp.asarray(hr))
    np.testing.assert_array_equal(np.asarray(grad), 1.0)


@pytest.mark.slow  # compiles the fill and its gradient: 5-15 s on 2 cores
def test_jit_vmap_and_gradient():
    truth = jnp.asarray(np.stack([_plane(4, 6), _plane(4, 6) * 0.5]))
    holes = jnp.zeros((2, 4, 6), bool).at[:, 1:3, 2:4].set(True)
    eager = fill_holes(truth, holes, SCALE)
    jitted = jax.jit(fill_holes, static_argnames=("scale", "iterations"))(truth, holes, SCALE)
    np.testing.assert_allclose(np.asarray(jitted), np.asarray(eager), rtol=0, atol=1e-6)
    mapped = jax.vmap(lambda d, f: fill_holes(d, f, SCALE))(truth, holes)
    np.testing.assert_allclose(np.asarray(mapped), np.asarray(eager), rtol=0, atol=1e-6)
    grad = np.asarray(jax.grad(lambda d: jnp.sum(fill_holes(d, holes, SCALE)))(truth))
    inside = np.repeat(np.repeat(np.asarray(holes), 4, 1), 4, 2)
    assert np.all(np.isfinite(grad)) and np.all(grad[inside] == 0.0)  # a hole's own guess counts for nothing
    assert grad[~inside].sum() > grad[~inside].size  # the surfaces around carry the holes' depth
    assert HOLE_FILL_ITERATIONS >= 2 * 4 * 8  # enough steps for the widest hole: 8 LR pixels of 4


@pytest.mark.parametrize("hr_shape, holes_shape, match", [
    ((16, 20), (4, 4), "integer scale"),
    ((16, 20), (3, 4, 5), "leading shape"),
    ((2, 16, 20), (3, 4, 5), "leading shape"),
    ((16,), (4,), "leading shape"),
])
def test_shapes_that_do_not_match_are_refused(hr_shape, holes_shape, match):
    with pytest.raises(ValueError, match=match):
        fill_holes(np.zeros(hr_shape, np.float32), np.zeros(holes_shape, bool), SCALE)


def test_a_scale_that_is_not_a_depth_scale_is_refused():
    with pytest.raises(TypeError, match="DepthScale"):
        fill_holes(np.zeros((8, 8), np.float32), np.zeros((2, 2), bool), (0.0, 35.0))


def _lit_surface_with_patch(patch_ambient: float, ambient: float = 2.0, seed: int = 0):
    """One 9-frame window summed: 12 x 12 LR pixels of a surface returning 6 photons a frame at bin 7 with
    `ambient` photons a frame over the gate, and a 3 x 2 patch that returns none and gets `patch_ambient`."""
    rng = np.random.default_rng(seed)
    rates = np.full((12, 12, 16), ambient / 16)
    rates[..., 7] += 6.0
    rates[4:7, 5:7] = patch_ambient / 16
    holes = np.zeros((12, 12), bool)
    holes[4:7, 5:7] = True
    return rng.poisson(9 * rates).astype(np.float32), holes


@pytest.mark.parametrize("patch_ambient, black", [(0.0, True), (0.3, True), (2.0, False), (2.6, False)])
def test_a_hole_is_black_where_its_photons_fall_short_of_the_ambient_light_around_it(patch_ambient, black):
    """A black screen reflects neither the laser nor the ambient light; a far or dim surface reflects the ambient
    light as its neighbours do, and only that one is not the surface around it continued."""
    summed, holes = _lit_surface_with_patch(patch_ambient)
    got = np.asarray(black_holes(summed, holes))
    assert not got[~holes].any()
    assert got[holes].all() if black else not got[holes].any()


def test_without_ambient_light_around_nothing_is_black():
    summed, holes = _lit_surface_with_patch(0.0, ambient=0.0)
    assert not np.asarray(black_holes(summed, holes)).any()


def test_black_holes_jit_frames_and_refusals():
    a, holes = _lit_surface_with_patch(0.0)
    b, _ = _lit_surface_with_patch(2.0, seed=1)
    summed, both = np.stack([a, b]), np.stack([holes, holes])
    got = np.asarray(jax.jit(black_holes)(summed, both))
    np.testing.assert_array_equal(got, np.stack([holes, np.zeros_like(holes)]))
    with pytest.raises(ValueError, match="alpha"):
        black_holes(a, holes, alpha=0.0)
    with pytest.raises(ValueError, match=r"\(\.\.\., h, w, 16\)"):
        black_holes(a[..., :8], holes)
    with pytest.raises(ValueError, match=r"\(\.\.\., h, w, 16\)"):
        black_holes(a, holes[:6])


def test_one_pixel_around_a_hole_at_or_behind_the_gate_start_pulls_only_its_side_of_the_fill():
    """The network's output is unclipped: a pixel around the hole at -0.01 (behind the gate's start) counts as the
    nearest distance the fill takes (0.35 m), not as an infinite inverse depth; in inverse depth a near pixel weighs
    more, so the hole's side beside it comes nearer, the far side stays with the surface."""
    hr = np.full((16, 16), np.float32(0.3))
    holes = np.zeros((4, 4), bool)
    holes[1:3, 1:3] = True
    hr[3, 6] = -0.01  # on the hole's edge
    got = np.asarray(fill_holes(hr, holes, SCALE))[4:12, 4:12]
    assert got.min() > 0.01 and got.max() <= 0.3 + 1e-6 and got[-2:].min() > 0.2
