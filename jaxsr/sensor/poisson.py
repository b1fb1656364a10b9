"""Poisson photon-count sampling: an exact sampler and a fast one for large batches on CPU.

`jax.random.poisson` runs rejection loops that draw fresh random bits for the whole array at every
iteration; for 32x64x16 histograms that made the draw 4x slower than computing the rates themselves.
The fast sampler uses a single uniform per count:

- lam < `EXACT_BELOW` (24): exact inverse CDF by a fixed-length sequential search (N = 72 terms; the
  truncated tail P(X > 72 | lam = 24) is below 1e-13, and the search is renormalised so no draw can run
  off the end through float rounding);
- lam >= 24: third-order Cornish-Fisher quantile of the Poisson, rounded with continuity correction. Its
  total-variation distance to the exact Poisson is below 1e-3 and its variance is lam + 1/12 (the rounding).

Choose `method="exact"` to get `jax.random.poisson` instead, up to `JAX_POISSON_MAX` (1e5); above, its float32
sampler spreads wider than a Poisson (1.02x the variance at 1e6, 1.46x at 1e8; 2026-11-26, jaxlib 0.10.2), and the
Cornish-Fisher quantile above takes over.

A draw has no derivative with respect to its rate; `poisson_pathwise` gives counts a surrogate one (the
counts themselves unchanged) so that code downstream of a draw can be put under `jax.grad`:

- "normal": the pathwise derivative of the normal approximation n = lam + sqrt(lam) z with z held at the
  value the draw implies, dn/dlam = 1 + (n - lam) / (2 lam) = 1/2 + n / (2 lam), where lam >= `NORMAL_ABOVE`;
  below it the variance term would blow up (n = 1 at lam = 0.01 gives 50), so those bins pass the gradient
  straight through (dn/dlam = 1). For f a polynomial of degree <= 2 in one count the variance term makes the
  estimator unbiased (E[f'(n)(1/2 + n/(2 lam))] = d/dlam E[f(n)]); for f = n^3 it is 1/2 too high (the exact
  derivative is E[f(n+1) - f(n)]). It never sees jumps of f (an argmax that switches bins): that is where
  it is biased downstream (experiments/results/sensor_design.md).
- "straight-through": dn/dlam = 1 everywhere: unbiased only for f linear in the counts (for f = n^2 it
  gives 2 lam of the exact 1 + 2 lam), with no variance of its own.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.scipy.special import ndtri

EXACT_BELOW = 24.0
_SEARCH_TERMS = 72
# "A few photons per bin": from here the normal approximation's variance term (its own variance 1 / (4 lam)
# per bin) is used; below, gradients pass straight through.
NORMAL_ABOVE = 3.0
# `method="exact"` draws with `jax.random.poisson` up to this rate, with the Cornish-Fisher quantile above (module
# docstring): the variance of jax's draws was within 0.1 % of the rate at 1e5, 0.9 % over at 3e5.
JAX_POISSON_MAX = 1e5
PATHWISE_ESTIMATORS = ("normal", "straight-through")


def _pmf_terms(lam):
    """Yield the running CDF F_i = P(X <= i), i = 0 .. _SEARCH_TERMS - 1, by the pmf recursion."""
    p = jnp.exp(-lam)
    cdf = p
    yield cdf
    for i in range(1, _SEARCH_TERMS):
        p = p * lam / i
        cdf = cdf + p
        yield cdf


def _inverse_cdf_small(u, lam):
    """Exact inverse-CDF draw for small lam: the number of i with u * F_max > F_i."""
    *_, total = _pmf_terms(lam)
    target = u * total  # renormalised: strictly below the last partial sum, so k < _SEARCH_TERMS
    k = jnp.zeros_like(lam)
    for cdf in _pmf_terms(lam):
        k = k + (target > cdf)
    return k


def _cornish_fisher_large(u, lam):
    """Cornish-Fisher quantile of Poisson(lam) at probability u (skewness and kurtosis terms)."""
    z = ndtri(u)
    g1 = jax.lax.rsqrt(lam)  # skewness
    w = z + (z**2 - 1) * g1 / 6 + (z**3 - 3 * z) * g1**2 / 24 - (2 * z**3 - 5 * z) * g1**2 / 36
    return jnp.maximum(jnp.floor(lam + jnp.sqrt(lam) * w + 0.5), 0.0)


def sample_poisson(key, rates, *, method: str = "fast"):
    """Draw Poisson counts with the given non-negative rates.

    Args:
      key: a `jax.random` key.
      rates: (...) non-negative float rates (photons).
      method: "fast" (one uniform per count, see the module docstring) or "exact" (`jax.random.poisson` up to
        `JAX_POISSON_MAX`, the fast method's large-rate quantile above, where jax's float32 draws spread too wide).
    Returns:
      (...) counts as floats of the rates' dtype (integers; above 2^24 float32 rounds them). A NaN rate gives a
      NaN count with either method.
    """
    rates = jnp.asarray(rates)
    if method == "exact":
        wide = jnp.promote_types(rates.dtype, jnp.float32)  # the quantile needs float32 or wider (int, float16 rates)
        huge = rates.astype(wide) > JAX_POISSON_MAX  # (in float16, 1e5 itself would be inf)
        # `key` itself for jax's draws: rates up to the limit draw what they drew before it was added
        counts = jax.random.poisson(key, jnp.where(huge, 0, rates), dtype=jnp.int32).astype(rates.dtype)
        u = jax.random.uniform(jax.random.fold_in(key, 1), rates.shape, wide, minval=jnp.finfo(wide).tiny, maxval=1.0)
        large = _cornish_fisher_large(u, jnp.where(huge, rates, EXACT_BELOW).astype(wide))
        counts = jnp.where(huge, jnp.where(jnp.isinf(rates), jnp.inf, large).astype(rates.dtype), counts)
        return jnp.where(jnp.isnan(rates), jnp.nan, counts)  # jax.random.poisson draws -1 for NaN
    if method != "fast":
        raise ValueError(f"sample_poisson: method must be 'fast' or 'exact', got {method!r}")
    small = rates < EXACT_BELOW
    u = jax.random.uniform(key, rates.shape, rates.dtype, minval=jnp.finfo(rates.dtype).tiny, maxval=1.0)
    k_small = _inverse_cdf_small(u, jnp.where(small, rates, 0.0))
    k_large = _cornish_fisher_large(u, jnp.where(small, EXACT_BELOW, rates))
    return jnp.where(small, k_small, k_large)


@jax.custom_jvp
def _normal_pathwise(counts, rates, normal_above):
    return counts


@_normal_pathwise.defjvp
def _normal_pathwise_jvp(primals, tangents):
    counts, rates, normal_above = primals
    # The counts and the threshold carry no derivative: only the rates' tangent is propagated.
    big = rates >= normal_above
    safe = jnp.where(big, rates, 1.0)  # no 1/0 in the branch that `where` discards
    factor = jnp.where(big, 0.5 + 0.5 * counts / safe, 1.0)
    return counts, factor * tangents[1]


@jax.custom_jvp
def _straight_through(counts, rates):
    return counts


@_straight_through.defjvp
def _straight_through_jvp(primals, tangents):
    return primals[0], tangents[1]


def poisson_pathwise(counts, rates, *, estimator: str = "normal", normal_above=NORMAL_ABOVE):
    """Counts drawn from `rates`, given a surrogate derivative with respect to the rates (module docstring).

    The values returned are `counts`, unchanged; only `jax.grad` / `jax.jvp` see a difference: d counts /
    d rates is 1/2 + n / (2 lam) ("normal", where lam >= `normal_above`, else 1) or 1 ("straight-through").
    Derivatives with respect to `counts` are dropped (they are draws).

    Args:
      counts: (...) counts drawn from `rates` (e.g. by `sample_poisson`).
      rates: (...) non-negative rates, the same shape.
      estimator: "normal" or "straight-through".
      normal_above: photons per bin from which "normal" uses its variance term (> 0).
    Returns:
      (...) the counts, with the chosen derivative with respect to the rates.
    """
    counts, rates = jnp.asarray(counts), jnp.asarray(rates)
    if counts.shape != rates.shape:
        raise ValueError(f"poisson_pathwise: counts {counts.shape} and rates {rates.shape} must have the same shape")
    if estimator not in PATHWISE_ESTIMATORS:
        raise ValueError(f"poisson_pathwise: estimator must be one of {PATHWISE_ESTIMATORS}, got {estimator!r}")
    if estimator == "straight-through":
        return _straight_through(counts, rates)
    if not normal_above > 0:
        raise ValueError(f"poisson_pathwise: normal_above must be > 0 photons, got {normal_above}")
    return _normal_pathwise(counts, rates, jnp.asarray(normal_above, rates.dtype))
