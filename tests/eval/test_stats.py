"""The paired block-bootstrap interval against answers known in closed form."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr import paired_interval
from jaxsr.eval import ratio_interval
from jaxsr.eval.stats import _resampled_means


def ar1(key, n_series, frames, phi, sigma=1.0):
    """(n_series, frames) stationary AR(1) noise x_t = phi x_{t-1} + e_t with unit marginal scale times sigma."""
    e = jax.random.normal(key, (frames, n_series)) * sigma * np.sqrt(1 - phi**2)
    x0 = jax.random.normal(jax.random.fold_in(key, 1), (n_series,)) * sigma
    _, xs = jax.lax.scan(lambda x, et: (phi * x + et, phi * x + et), x0, e)
    return xs.T


def test_independent_frames_give_the_textbook_interval():
    """Independent differences of sd 1 over 400 frames: mean +- 1.96 / 20 (to a few % of the width)."""
    rng = np.random.default_rng(0)
    d = rng.normal(0.5, 1.0, 400)
    got = paired_interval(jax.random.key(0), d, np.zeros_like(d), block=1, n_resamples=8000)
    assert float(got.mean) == pytest.approx(d.mean(), abs=1e-5)
    half = 1.96 * d.std() / np.sqrt(len(d))
    assert float(got.high - got.low) == pytest.approx(2 * half, rel=0.06)
    assert float(got.low) < d.mean() < float(got.high)


def test_a_constant_difference_has_no_width():
    a = np.linspace(20, 30, 50)
    got = paired_interval(jax.random.key(1), a + 0.25, a, block=5)
    np.testing.assert_allclose([got.mean, got.low, got.high], 0.25, atol=1e-5)


@pytest.mark.slow
def test_blocks_cover_correlated_frames_that_independent_draws_miss():
    """200 sequences of 400 AR(1) differences (phi 0.8: neighbours alike over about 5 frames, true mean 0.3):
    the 95 % interval of blocks of 20 contains 0.3 in most of them (89 % measured: block bootstraps run a little
    narrow), the ordinary bootstrap (block 1) in about half, since it ignores the correlation in time."""
    true_mean, n, frames = 0.3, 200, 400
    d = true_mean + ar1(jax.random.key(2), n, frames, phi=0.8)

    def coverage(block):  # paired_interval's estimator, vmapped over the series (one compile, not 200 calls)
        stats = jax.vmap(lambda k, x: _resampled_means(k, x[None], block, 400))(jax.random.split(key, n), d)
        low, high = jnp.percentile(stats, jnp.array([2.5, 97.5]), axis=1)
        return float(jnp.mean((low <= true_mean) & (true_mean <= high)))

    key = jax.random.key(3)
    assert paired_interval(key, d[0], jnp.zeros(frames), block=20).low == pytest.approx(
        float(jnp.percentile(_resampled_means(key, d[:1], 20, 4000), 2.5)))  # the same estimator
    blocked, independent = coverage(20), coverage(1)
    assert blocked >= 0.84, blocked
    assert independent <= 0.6, independent


def test_sequences_are_resampled_apart_and_averaged():
    """Two sequences with mean differences 1 and 3: the statistic is their average, 2; a sequence of noise-free
    differences adds no width, so the interval is half the width of the noisy one's alone."""
    rng = np.random.default_rng(4)
    noisy = 1.0 + rng.normal(0, 1, 300)
    both = np.stack([noisy, np.full(300, 3.0)])
    key = jax.random.key(5)
    got = paired_interval(key, both, np.zeros_like(both), block=1)
    alone = paired_interval(key, noisy, np.zeros(300), block=1)
    assert float(got.mean) == pytest.approx((noisy.mean() + 3) / 2, abs=1e-5)
    assert float(got.high - got.low) == pytest.approx(float(alone.high - alone.low) / 2, rel=0.1)


@pytest.mark.parametrize("a,b,kw,match", [
    (np.zeros(5), np.zeros(6), {}, "one shape"),
    (np.zeros((2, 3, 4)), np.zeros((2, 3, 4)), {}, "one shape"),
    (np.zeros(5), np.zeros(5), {"block": 6}, "block"),
    (np.zeros(5), np.zeros(5), {"block": 0}, "block"),
    (np.zeros(5), np.zeros(5), {"block": 1, "level": 1.0}, "level"),
    (np.array([1.0, np.inf, 2.0]), np.zeros(3), {"block": 1}, "finite"),
])
def test_bad_input_is_refused(a, b, kw, match):
    with pytest.raises(ValueError, match=match):
        paired_interval(jax.random.key(0), a, b, **kw)


def test_an_exact_ratio_has_no_width():
    b = np.random.default_rng(6).uniform(50, 150, 60)
    got = ratio_interval(jax.random.key(7), 2 * b, b, block=5)
    np.testing.assert_allclose([got.mean, got.low, got.high], 2.0, rtol=1e-5)


def test_the_ratio_interval_matches_the_delta_method():
    """Independent frames, a ~ 200 +- 10 and b ~ 100 +- 10 over 400 frames: the ratio of means is near 2 with
    standard error sqrt(var_a + r^2 var_b) / (mean_b sqrt(T)) = sqrt(100 + 400) / (100 * 20)."""
    rng = np.random.default_rng(8)
    a, b = rng.normal(200, 10, 400), rng.normal(100, 10, 400)
    got = ratio_interval(jax.random.key(9), a, b, block=1, n_resamples=8000)
    assert float(got.mean) == pytest.approx(a.mean() / b.mean(), rel=1e-5)
    half = 1.96 * np.sqrt(a.var() + (a.mean() / b.mean()) ** 2 * b.var()) / (b.mean() * np.sqrt(400))
    assert float(got.high - got.low) == pytest.approx(2 * half, rel=0.1)


def test_a_ratio_to_a_zero_mean_is_refused():
    with pytest.raises(ValueError, match="positive"):
        ratio_interval(jax.random.key(0), np.ones(5), np.zeros(5), block=1)
    with pytest.raises(ValueError, match="one shape"):
        ratio_interval(jax.random.key(0), np.ones(5), np.ones(4), block=1)
