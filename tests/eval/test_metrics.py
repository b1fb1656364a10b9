"""Metrics against scikit-image and closed forms (docs/sensor-model.md, section 5)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

import jaxsr


def pair(seed, shape=(2, 3, 40, 56)):
    rng = np.random.default_rng(seed)
    gt = rng.uniform(0, 1, shape)
    pred = np.clip(gt + rng.normal(0, 0.1, shape), 0, 1)
    return pred, gt


@pytest.mark.parametrize("jit", [False, True])
def test_ssim_matches_scikit_image(jit):
    pred, gt = pair(0)
    f = jax.jit(jaxsr.ssim) if jit else jaxsr.ssim
    with jax.enable_x64(True):
        got = np.asarray(f(pred, gt))
    want = np.array(
        [
            [
                structural_similarity(
                    gt[i, j], pred[i, j], gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1
                )
                for j in range(3)
            ]
            for i in range(2)
        ]
    )
    assert got.shape == (2, 3)
    np.testing.assert_allclose(got, want, atol=1e-6)
    # float32 stays close too
    np.testing.assert_allclose(np.asarray(jaxsr.ssim(pred.astype(np.float32), gt.astype(np.float32))), want, atol=2e-4)


def test_psnr_matches_scikit_image_and_clips_prediction():
    pred, gt = pair(1)
    got = np.asarray(jaxsr.psnr(pred, gt))
    want = np.array([[peak_signal_noise_ratio(gt[i, j], pred[i, j], data_range=1) for j in range(3)] for i in range(2)])
    np.testing.assert_allclose(got, want, rtol=1e-5)
    gt0 = np.zeros((8, 8))
    assert float(jaxsr.psnr(np.full((8, 8), 2.0), gt0)) == pytest.approx(0.0, abs=1e-5)  # clipped to 1
    assert float(jaxsr.psnr(np.full((8, 8), 0.1), gt0)) == pytest.approx(20.0, rel=1e-5)
    assert float(jaxsr.psnr(gt0, gt0)) == pytest.approx(120.0)  # capped, finite


def test_ssim_global_closed_form():
    pred, gt = pair(2, (4, 16, 16))
    x, y = pred[1].ravel(), gt[1].ravel()
    c1, c2 = 1e-4, 9e-4
    mx, my = x.mean(), y.mean()
    want = ((2 * mx * my + c1) * (2 * np.mean((x - mx) * (y - my)) + c2)) / (
        (mx**2 + my**2 + c1) * (x.var() + y.var() + c2)
    )
    assert float(jaxsr.ssim_global(pred, gt)[1]) == pytest.approx(want, rel=1e-5)
    assert float(jaxsr.ssim_global(gt[0], gt[0])) == pytest.approx(1.0, rel=1e-6)


def test_temporal_coherence_hand_built():
    gt = np.zeros((4, 3, 3))
    gt[2:, 0, 0] = 0.5  # pixel (0,0) moves at t=1->2: not static there
    sr = np.zeros((4, 3, 3))
    sr[1, 1, 1] = 0.02  # flickers on 0->1 and 1->2
    sr[3, 2, 2] = 0.005  # below eps
    sr[2:, 0, 0] = 0.5  # follows the moving GT: not counted
    tc = jaxsr.temporal_coherence(sr, gt)
    np.testing.assert_array_equal(tc.counts, [1, 1, 0])
    assert float(tc.mean) == pytest.approx(2 / 3)
    assert float(tc.flicker_fraction) == pytest.approx(2 / (9 * 3 - 1))
    tight = jaxsr.temporal_coherence(sr, gt, eps=1 / 255)
    np.testing.assert_array_equal(tight.counts, [1, 1, 1])
    # the paper's Eq. 4: any change of a static pixel counts, however small
    sr[3, 2, 1] = 1e-6
    paper = jaxsr.temporal_coherence(sr, gt, eps=0.0)
    np.testing.assert_array_equal(paper.counts, [1, 1, 2])


def test_leading_axes_and_vmap():
    pred, gt = pair(3)
    for f in (jaxsr.psnr, jaxsr.ssim, jaxsr.ssim_global):
        full = f(pred, gt)
        np.testing.assert_allclose(jax.vmap(f)(pred, gt), full, rtol=1e-5)
        np.testing.assert_allclose(f(pred[1, 2], gt[1, 2]), full[1, 2], rtol=1e-5)


def test_gradients_finite():
    pred, gt = pair(4, (16, 16))
    for f in (jaxsr.psnr, jaxsr.ssim, jaxsr.ssim_global):
        g = jax.grad(lambda p: f(p, jnp.asarray(gt)))(jnp.asarray(gt))  # perfect prediction: the hardest case
        assert np.all(np.isfinite(g))


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match="equal shape"):
        jaxsr.psnr(np.zeros((4, 4)), np.zeros((4, 5)))
    with pytest.raises(ValueError, match="at least 11x11"):
        jaxsr.ssim(np.zeros((8, 8)), np.zeros((8, 8)))
    with pytest.raises(ValueError, match="T >= 2"):
        jaxsr.temporal_coherence(np.zeros((1, 4, 4)), np.zeros((1, 4, 4)))
