"""Sensor effects (jaxsr.sensor.effects): dark counts, hot and dead pixels, no-return regions, a per-clip IRF
width and clipping background-subtracted counts; closed forms, shapes, jit/vmap, gradients, bad input, extremes."""


import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr.config import Sensor
from jaxsr.sensor import (
    calibrated_rates,
    centre_of_mass,
    clip_negative_counts,
    dark_counts,
    dead_pixels,
    expected_histograms,
    hot_pixels,
    irf_bin_weights,
    no_return_regions,
    sample_poisson,
    thin_returns,
    with_irf_sigma,
)

SENSOR = Sensor()
H, W = SENSOR.hr_shape
h, w = SENSOR.lr_shape
K = SENSOR.bins


def rates(lead=(), value=0.5):
    return jnp.full((*lead, h, w, K), value, jnp.float32)


def scene(frames=2):
    """A wall at 10 m with a ramp of intensity, (frames, H, W)."""
    depth = jnp.full((frames, H, W), 10.0)
    intensity = jnp.broadcast_to(jnp.linspace(0.1, 0.9, W), (frames, H, W))
    return depth, intensity


def test_dark_counts_add_to_the_mean():
    lam = rates((2,), 0.3)
    out = dark_counts(lam, rate_per_bin=0.2)
    np.testing.assert_allclose(out, 0.5, rtol=1e-6)
    counts = sample_poisson(jax.random.key(0), dark_counts(rates((8,), 1.0), rate_per_bin=2.0))
    assert float(counts.mean()) == pytest.approx(3.0, rel=0.01)  # 8 x 32 x 64 x 16 draws
    per_pixel = dark_counts(rates(), rate_per_bin=jnp.arange(w, dtype=jnp.float32)[None, :] * jnp.ones((h, 1)))
    np.testing.assert_allclose(per_pixel[3, 5], 0.5 + 5.0)


@pytest.mark.slow  # 8-10 s on 2 cores: keeps the default suite under 8 minutes
def test_dead_pixels_give_zero_counts_and_no_return():
    lam, mask = dead_pixels(jax.random.key(1), rates((3,), 5.0), fraction=0.3, return_mask=True)
    assert mask.shape == (h, w) and 0.2 < float(mask.mean()) < 0.4
    counts = sample_poisson(jax.random.key(2), lam)
    assert np.all(np.asarray(counts)[:, np.asarray(mask)] == 0)
    assert np.all(np.asarray(counts)[:, ~np.asarray(mask)].sum(-1) > 0)
    depth = centre_of_mass(counts, SENSOR)
    assert np.all(np.asarray(depth)[:, np.asarray(mask)] == 1.0)
    assert not dead_pixels(jax.random.key(1), rates(), fraction=0.0, return_mask=True)[1].any()
    assert dead_pixels(jax.random.key(1), rates(), fraction=1.0, return_mask=True)[1].all()


def test_hot_pixels_raise_the_rate_on_their_pixels_in_every_frame():
    lam = rates((4,), 0.5)
    out, mask = hot_pixels(jax.random.key(3), lam, fraction=0.05, rate=7.0, return_mask=True)
    m = np.asarray(mask)
    assert 0.02 < m.mean() < 0.08
    np.testing.assert_allclose(np.asarray(out)[:, m], 7.5)
    np.testing.assert_allclose(np.asarray(out)[:, ~m], 0.5)
    # the same pixels in every frame (a property of the sensor); another key, other pixels
    other = np.asarray(hot_pixels(jax.random.key(4), lam, fraction=0.05, rate=7.0, return_mask=True)[1])
    assert not np.array_equal(m, other)


def test_no_return_regions_are_inf_where_masked_at_the_fraction_asked():
    depth, _ = scene(3)
    for fraction, sky in ((0.1, 1.0), (0.3, 0.0), (0.5, 0.5), (0.02, 0.3)):
        out, mask = no_return_regions(jax.random.key(5), depth, fraction=fraction, sky=sky, return_mask=True)
        m = np.asarray(mask)
        assert m.shape == (H, W)
        assert abs(m.mean() - fraction) < 1.0 / (H * W) + 1e-6
        assert np.all(np.isinf(np.asarray(out)[:, m])) and np.all(np.asarray(out)[:, ~m] == 10.0)
    # sky = 1: a band of the top rows
    _, band = no_return_regions(jax.random.key(6), depth, fraction=0.25, sky=1.0, return_mask=True)
    rows = np.asarray(band).mean(1)
    assert rows[: H // 4 - 3].min() == 1.0 and rows[H // 4 + 3:].max() == 0.0
    # blobs: not a band, several rows touched
    _, blobs = no_return_regions(jax.random.key(6), depth, fraction=0.25, sky=0.0, return_mask=True)
    assert np.asarray(blobs).any(1).sum() > H // 2
    assert not no_return_regions(jax.random.key(5), depth, fraction=0.0, return_mask=True)[1].any()
    assert no_return_regions(jax.random.key(5), depth, fraction=1.0, return_mask=True)[1].all()


def test_no_return_regions_give_zero_signal():
    depth, intensity = scene(1)
    holed = no_return_regions(jax.random.key(7), depth, fraction=0.4, sky=1.0)
    lam = expected_histograms(holed, intensity, SENSOR, snr=1e4, mean_signal=100.0)
    top = np.asarray(lam)[0, 0]  # the top LR row: sky, background only (flat)
    np.testing.assert_allclose(top, top[..., :1] * np.ones(K), rtol=1e-5)


def test_thin_returns_are_lines_of_the_width_asked():
    key = jax.random.key(2)
    assert not thin_returns(key, (H, W), lines=0).any()
    masks = [np.asarray(thin_returns(key, (H, W), lines=n)) for n in range(4)]
    for fewer, more in zip(masks, masks[1:]):  # the first n lines of the same draws
        assert np.all(more[fewer]) and more.sum() > fewer.sum()
    # one line: its pixels' area over its length (their extent along the line's direction) is its width
    for width in (3.0, 6.0, 12.0):
        one = np.asarray(thin_returns(jax.random.key(4), (H, W), lines=1, width_range=(width, width), max_lines=1))
        yx = np.argwhere(one).astype(float)
        direction = np.linalg.svd(yx - yx.mean(0), full_matrices=False)[2][0]
        length = np.ptp(yx @ direction) + 1.0
        assert one.sum() / length == pytest.approx(width, rel=0.2), width
    traced = jax.jit(jax.vmap(lambda k, n: thin_returns(k, (H, W), lines=n)))(
        jax.random.split(key, 3), jnp.array([0, 2, 8]))
    assert traced.shape == (3, H, W) and not traced[0].any() and traced[2].sum() > traced[1].sum()
    for bad in (dict(lines=9), dict(lines=1, width_range=(0.0, 2.0)), dict(lines=1, width_range=(4.0, 2.0)),
                dict(lines=1, max_lines=-1), dict(lines=1.5)):
        with pytest.raises(ValueError, match="thin_returns"):
            thin_returns(key, (H, W), **bad)


def test_with_irf_sigma_widens_the_pulse_and_traces():
    wide = with_irf_sigma(SENSOR, 2.0)
    assert wide.irf_sigma == 2.0 and SENSOR.replace(irf_sigma=2.0) == wide
    tau = jnp.array(8.0)
    assert float(irf_bin_weights(tau, wide).max()) < float(irf_bin_weights(tau, SENSOR).max())
    depth, intensity = scene(1)

    @jax.jit
    @jax.vmap
    def peak_share(sigma):
        lam = expected_histograms(depth, intensity, with_irf_sigma(SENSOR, sigma), snr=1e4, mean_signal=10.0)
        return lam.max(-1).mean() / lam.sum(-1).mean()

    share = np.asarray(peak_share(jnp.array([0.3, 0.4, 1.0, 3.0])))
    assert np.all(np.diff(share) < 0), share


def test_clip_negative_counts():
    counts = jnp.array([[1.0, -2.0, 3.0, -0.5] + [0.0] * (K - 4), [2.0] * K])
    clipped, n = clip_negative_counts(counts, SENSOR)
    assert int(n) == 2 and float(clipped.min()) == 0.0
    np.testing.assert_array_equal(clipped[1], counts[1])
    with pytest.raises(ValueError, match=">= 0"):
        centre_of_mass(counts, SENSOR)
    assert np.all(np.isfinite(centre_of_mass(clipped, SENSOR)))
    clipped_j, n_j = jax.jit(clip_negative_counts)(counts)
    np.testing.assert_array_equal(clipped_j, clipped) and int(n_j) == 2
    with pytest.raises(ValueError, match="bins"):
        clip_negative_counts(jnp.ones((4, K + 1)), SENSOR)


def test_shapes_jit_and_vmap():
    lam = rates((5,))
    keys = jax.random.split(jax.random.key(8), 5)

    @jax.jit
    def pipeline(key, lam, depth):
        k1, k2, k3 = jax.random.split(key, 3)
        lam = dead_pixels(k1, hot_pixels(k2, dark_counts(lam, rate_per_bin=0.1), fraction=0.1, rate=3.0),
                          fraction=0.1)
        return lam, no_return_regions(k3, depth, fraction=0.2)

    depth, _ = scene(5)
    out, holed = jax.vmap(pipeline, in_axes=(0, None, None))(keys, lam, depth)
    assert out.shape == (5, 5, h, w, K) and holed.shape == (5, 5, H, W)
    # per key its own masks; the same key, the same masks
    assert not np.array_equal(np.isinf(holed[0]), np.isinf(holed[1]))
    np.testing.assert_array_equal(pipeline(keys[2], lam, depth)[0], out[2])
    # traced options: drawn per clip inside vmap
    fractions = jnp.array([0.0, 0.2, 0.6])
    masks = jax.vmap(lambda f: no_return_regions(jax.random.key(9), depth[0], fraction=f, return_mask=True)[1])(
        fractions)
    np.testing.assert_allclose(masks.mean((1, 2)), fractions, atol=1e-4)


def test_gradients_finite():
    lam = rates((2,), 0.5)
    g = jax.grad(lambda d: dark_counts(lam, rate_per_bin=d).sum())(0.3)
    assert float(g) == pytest.approx(2 * h * w * K)
    g = jax.grad(lambda r: hot_pixels(jax.random.key(0), lam, fraction=0.1, rate=r).sum())(2.0)
    assert np.isfinite(float(g)) and float(g) > 0
    g = jax.grad(lambda x: dead_pixels(jax.random.key(0), x, fraction=0.1).sum())(lam)
    assert np.all(np.isin(np.asarray(g), [0.0, 1.0]))
    depth, intensity = scene(1)

    def signal(sigma):
        return calibrated_rates(depth, intensity, 1.0, 0.1, with_irf_sigma(SENSOR, sigma))[..., 4:].sum()

    assert np.isfinite(float(jax.grad(signal)(0.8)))
    g = jax.grad(lambda d: expected_histograms(no_return_regions(jax.random.key(1), d, fraction=0.3), intensity,
                                               SENSOR, snr=1.0).sum())(depth)
    assert np.all(np.isfinite(np.asarray(g)))


@pytest.mark.parametrize("call, message", [
    (lambda: dark_counts(rates(), rate_per_bin=-1.0), "rate_per_bin"),
    (lambda: dark_counts(rates(), rate_per_bin=float("nan")), "rate_per_bin"),
    (lambda: dark_counts(jnp.ones((4, K)), rate_per_bin=1.0), r"\(\.\.\., h, w, K\)"),
    (lambda: hot_pixels(jax.random.key(0), rates(), fraction=1.5, rate=1.0), "fraction"),
    (lambda: hot_pixels(jax.random.key(0), rates(), fraction=0.1, rate=float("inf")), "rate"),
    (lambda: dead_pixels(jax.random.key(0), rates(), fraction=-0.1), "fraction"),
    (lambda: no_return_regions(jax.random.key(0), jnp.ones((H, W)), fraction=2.0), "fraction"),
    (lambda: no_return_regions(jax.random.key(0), jnp.ones((H, W)), fraction=0.2, sky=-1), "sky"),
    (lambda: no_return_regions(jax.random.key(0), jnp.ones((H, W)), fraction=0.2, blob_size=0), "blob_size"),
    (lambda: no_return_regions(jax.random.key(0), jnp.ones(W), fraction=0.2), r"\(\.\.\., H, W\)"),
    (lambda: with_irf_sigma(SENSOR, 0.0), "irf_sigma"),
    (lambda: with_irf_sigma(SENSOR, float("nan")), "irf_sigma"),
])
def test_bad_input_is_refused(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_traced_bad_options_give_nan():
    out = jax.jit(lambda d: dark_counts(rates(), rate_per_bin=d))(-1.0)
    assert np.all(np.isnan(out))
    out = jax.jit(lambda f: dead_pixels(jax.random.key(0), rates(), fraction=f))(2.0)
    assert np.all(np.isnan(out))


@pytest.mark.parametrize("mean_signal, snr", [(0.0, 1.0), (1e6, 1.0), (0.5, 1e-3), (1000.0, 1e4), (1.0, 1e4),
                                              (1000.0, 1e-3)])
def test_extremes_stay_finite(mean_signal, snr):
    depth, intensity = scene(1)
    depth = no_return_regions(jax.random.key(0), depth, fraction=0.3)
    lam = expected_histograms(depth, intensity, with_irf_sigma(SENSOR, 3.0), snr=snr, mean_signal=mean_signal)
    lam = dead_pixels(jax.random.key(1), hot_pixels(jax.random.key(2), dark_counts(lam, rate_per_bin=0.01),
                                                    fraction=0.05, rate=1e3), fraction=0.05)
    counts = sample_poisson(jax.random.key(3), lam)
    assert np.all(np.isfinite(np.asarray(lam))) and np.all(np.isfinite(np.asarray(counts)))
    depth_lr = np.asarray(centre_of_mass(counts, SENSOR))
    assert np.all(np.isfinite(depth_lr)) and depth_lr.min() >= 0 and depth_lr.max() <= 1
    if mean_signal == 0.0:
        # zero photons of signal: all that is left is background, so the depth carries nothing of the wall
        assert float(counts.sum()) > 0
