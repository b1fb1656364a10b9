"""The fast Poisson sampler against the exact distribution (scipy.stats)."""

import jax
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
