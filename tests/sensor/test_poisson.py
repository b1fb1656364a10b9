"""The fast Poisson sampler against the exact distribution (scipy.stats)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from jaxsr.sensor.poisson import EXACT_BELOW, sample_poisson


@pytest.mark.parametrize("lam", [0.0, 0.05, 1.0, 4.0, 12.0, EXACT_BELOW - 0.5, EXACT_BELOW, 60.0, 1e4])
def test_fast_sampler_distribution(lam):
    n = 200_000
    draws = np.asarray(sample_poisson(jax.random.key(int(lam * 10)), np.full(n, lam, np.float32)))
    assert np.all(draws == np.round(draws)) and draws.min() >= 0
    if lam == 0:
        assert draws.max() == 0
        return
    ks = np.arange(int(lam + 12 * np.sqrt(lam)) + 12)
    emp = np.bincount(draws.astype(np.int64), minlength=len(ks))[: len(ks)] / n
    tv = 0.5 * np.abs(emp - stats.poisson.pmf(ks, lam)).sum()
    # Sampling noise alone gives TV ~ sqrt(support / n); the Cornish-Fisher branch adds < 1e-3.
    assert tv < 2.0 * np.sqrt(len(ks) / n) / 2 + 1e-3
    assert abs(draws.mean() - lam) < 5 * np.sqrt(lam / n)
    assert draws.var() / lam == pytest.approx(1.0, abs=0.02)


def test_small_rate_search_never_runs_off_the_end():
    # u values within float rounding of 1: the renormalised search must stay in the support
    draws = np.asarray(sample_poisson(jax.random.key(0), np.full(2_000_000, EXACT_BELOW - 0.01, np.float32)))
    assert draws.max() < 72 - 1


def test_exact_method_and_bad_method():
    draws = sample_poisson(jax.random.key(1), np.full(1000, 3.0, np.float32), method="exact")
    assert abs(float(draws.mean()) - 3.0) < 0.3
    with pytest.raises(ValueError, match="'fast' or 'exact'"):
        sample_poisson(jax.random.key(1), np.ones(3), method="gauss")


@pytest.mark.parametrize("method", ["fast", "exact"])
@pytest.mark.parametrize("lam", [1e4, 1e6, 1e8])
def test_huge_rates_have_poisson_mean_and_variance(method, lam):
    """Mean and variance within 1 % of the rate at 1e4-1e8 photons (jax.random.poisson alone spreads 1.46x at
    1e8: "exact" hands such rates to the quantile of the fast method); rates at the limit and below keep the
    draws jax.random.poisson gives with the same key."""
    draws = np.asarray(sample_poisson(jax.random.key(2), np.full(400_000, lam, np.float32), method=method), float)
    assert abs(draws.mean() / lam - 1) < 1e-3 and abs(draws.var() / lam - 1) < 0.01


def test_exact_draws_below_the_limit_are_jax_poisson():
    from jaxsr.sensor.poisson import JAX_POISSON_MAX
    rates = np.array([0.0, 3.0, 500.0, JAX_POISSON_MAX, np.nan, 4 * JAX_POISSON_MAX], np.float32)
    got = np.asarray(sample_poisson(jax.random.key(3), rates, method="exact"))
    want = np.asarray(jax.random.poisson(jax.random.key(3), np.where(rates > JAX_POISSON_MAX, 0.0, rates),
                                         dtype=np.int32), np.float32)
    np.testing.assert_array_equal(got[:4], want[:4])
    assert np.isnan(got[4]) and abs(got[5] / rates[5] - 1) < 0.01


@pytest.mark.parametrize("dtype", [np.int32, np.float16, "bfloat16", np.float32])
def test_exact_takes_integer_and_narrow_rates(dtype):
    """Integer, float16 and bfloat16 rates draw as before the huge-rate branch (which computes in float32);
    an infinite rate gives an infinite count, NaN a NaN."""
    rates = jnp.asarray(np.array([0, 3, 40, 2e5 if dtype != np.float16 else 6e4]), dtype)
    counts = np.asarray(sample_poisson(jax.random.key(4), rates, method="exact"), np.float64)
    assert np.all(np.isfinite(counts)) and counts[0] == 0 and abs(counts[-1] / float(rates[-1]) - 1) < 0.05
    if dtype != np.int32:
        special = np.asarray(sample_poisson(jax.random.key(4), jnp.asarray([np.inf, np.nan], dtype), method="exact"))
        assert np.isinf(special[0]) and np.isnan(special[1])
