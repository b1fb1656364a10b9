"""Centre of mass and maximum-likelihood depth extraction (docs/sensor-model.md, section 3)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from scipy.special import ndtr

import jaxsr
from jaxsr.sensor.peaks import default_window

CFG = jaxsr.Sensor()
K = CFG.bins


def irf_histogram(tau, sigma=0.4, signal=1.0, background=0.0):
    """Closed-form expected histogram of one return at tau (bins) plus a flat background (NumPy, float64)."""
    edges = np.arange(K + 1)
    cdf = ndtr((edges[None, :] - np.asarray(tau)[:, None]) / sigma)
    return signal * (cdf[:, 1:] - cdf[:, :-1]) + background / K


def reference_com(n, w=1):
    """docs/sensor-model.md, section 3, one pixel at a time."""
    out = []
    for h in np.asarray(n, np.float64):
        b = np.median(h)
        kp = int(np.argmax(h))
        ks = np.arange(max(0, kp - w), min(K - 1, kp + w) + 1)
        x = np.maximum(h[ks] - b, 0)
        out.append(1.0 if x.sum() == 0 else float(((ks + 0.5) * x).sum() / x.sum() / K))
    return np.array(out)


def test_noise_free_bias_under_002_bins():
    rng = np.random.default_rng(0)
    tau = rng.uniform(1.5, K - 1.5, 2000)  # random sub-bin positions away from the gate edges
    est = np.asarray(jaxsr.centre_of_mass(irf_histogram(tau), CFG)) * K
    err = est - tau
    assert abs(err.mean()) < 0.02
    assert np.sqrt(np.mean(err**2)) < 0.02  # docs/sensor-model.md: about 0.01 bins RMS


def test_background_subtraction_removes_shrink_to_mid_range():
    tau = np.array([2.15, 13.85])  # near bin edges, far from the window's centre
    hist = irf_histogram(tau, signal=100.0, background=400.0)  # SNR 0.25
    est = np.asarray(jaxsr.centre_of_mass(hist, CFG)) * K
    np.testing.assert_allclose(est, tau, atol=0.03)
    # Without subtraction the background's mass pulls each estimate towards the window's centre.
    k = np.arange(K)
    naive = []
    for h in hist:
        win = np.abs(k - int(np.argmax(h))) <= 1
        naive.append(((k + 0.5) * h * win).sum() / (h * win).sum())
    naive_err = np.abs(np.array(naive) - tau)
    assert np.all(naive_err > 0.1) and np.all(naive_err > 5 * np.abs(est - tau))


def test_matches_reference_on_noisy_histograms():
    rng = np.random.default_rng(1)
    lam = irf_histogram(rng.uniform(0, K, 500), signal=rng.uniform(0, 30, 500)[:, None], background=20.0)
    counts = rng.poisson(lam).astype(np.float32)
    np.testing.assert_allclose(jaxsr.centre_of_mass(counts, CFG), reference_com(counts), atol=1e-6)


def test_empty_and_flat_histograms_are_no_return():
    counts = np.zeros((3, K), np.float32)
    counts[1] = 5.0  # flat: nothing above the median
    depth, valid = jaxsr.centre_of_mass(counts, CFG, return_mask=True)
    np.testing.assert_array_equal(depth, [1.0, 1.0, 1.0])
    assert not np.any(valid)


def test_window_edges_and_ties():
    counts = np.zeros((2, K), np.float32)
    counts[0, 0] = 10.0  # peak at the first bin: window clipped to bins 0..1
    counts[1, [4, 9]] = 7.0  # tie: the first maximum wins
    depth = np.asarray(jaxsr.centre_of_mass(counts, CFG))
    np.testing.assert_allclose(depth * K, [0.5, 4.5], atol=1e-6)


def test_window_default_follows_irf_width():
    assert int(default_window(CFG)) == 1
    assert int(default_window(jaxsr.Sensor(pulse=jaxsr.Pulse(0.6)))) == 2
    hist = irf_histogram(np.array([7.3]), sigma=0.9, signal=100.0)
    wide = float(jaxsr.centre_of_mass(hist, jaxsr.Sensor(pulse=jaxsr.Pulse(0.9)))[0]) * K
    narrow = float(jaxsr.centre_of_mass(hist, CFG, window=1)[0]) * K
    assert abs(wide - 7.3) < abs(narrow - 7.3)


def test_significance_threshold_rejects_weak_peaks():
    rng = np.random.default_rng(2)
    counts = rng.poisson(10.0, size=(400, K)).astype(np.float32)  # background only
    _, valid0 = jaxsr.centre_of_mass(counts, CFG, return_mask=True)
    _, valid3 = jaxsr.centre_of_mass(counts, CFG, z=3.0, return_mask=True)
    assert valid0.mean() > 0.99 and valid3.mean() < 0.5


def test_huge_counts_and_nan_under_jit():
    counts = irf_histogram(np.array([5.25]), signal=1e9, background=1e8).astype(np.float32)
    depth = float(jaxsr.centre_of_mass(counts, CFG)[0]) * K
    assert abs(depth - 5.25) < 0.02
    bad = jnp.array([[jnp.nan] + [1.0] * (K - 1), [jnp.inf] * K])
    out = jax.jit(lambda c: jaxsr.centre_of_mass(c, CFG))(bad)
    np.testing.assert_array_equal(out, [1.0, 1.0])


def test_gradient_finite_and_matches_finite_differences():
    # distinct bin values: the median is not differentiable at ties
    jitter = np.random.default_rng(5).uniform(0, 1, (2, K))
    hist = irf_histogram(np.array([6.3, 0.2]), signal=50.0, background=10.0) + jitter
    with jax.enable_x64(True):
        h64 = jnp.asarray(hist, jnp.float64)
        check_grads(lambda c: jaxsr.centre_of_mass(c, CFG), (h64,), order=1, modes=["rev"], eps=1e-5)
    grad = jax.grad(lambda c: jnp.sum(jaxsr.centre_of_mass(c, CFG)))(jnp.zeros((2, K)))
    assert np.all(np.isfinite(grad))


def test_vmap_equals_loop_and_jit_equals_eager():
    rng = np.random.default_rng(3)
    counts = rng.poisson(irf_histogram(rng.uniform(0, K, 12), signal=15.0, background=15.0)).reshape(3, 4, K)
    counts = jnp.asarray(counts, jnp.float32)
    f = lambda c: jaxsr.centre_of_mass(c, CFG)  # noqa: E731
    np.testing.assert_array_equal(jax.vmap(f)(counts), jnp.stack([f(c) for c in counts]))
    np.testing.assert_array_equal(jax.jit(f)(counts), f(counts))


@pytest.mark.parametrize(
    "counts,match",
    [(np.zeros((4, 15)), r"\(\.\.\., 16\)"), (-np.ones((4, 16)), ">= 0"), (np.full((2, 16), np.nan), "finite")],
)
def test_bad_counts_raise(counts, match):
    with pytest.raises(ValueError, match=match):
        jaxsr.centre_of_mass(counts, CFG)


# --- maximum likelihood --------------------------------------------------------------------------------------


def test_maximum_likelihood_recovers_tau_on_expected_histograms():
    tau = np.array([3.3, 7.77, 11.5])
    hist = irf_histogram(tau, signal=200.0, background=50.0)
    depth, valid, converged = jaxsr.maximum_likelihood_depth(hist, CFG, return_mask=True)
    assert np.all(valid) and np.all(converged)
    np.testing.assert_allclose(np.asarray(depth) * K, tau, atol=5e-3)  # the COM alone is off by ~0.01


def test_maximum_likelihood_beats_centre_of_mass_with_plentiful_photons():
    rng = np.random.default_rng(4)
    tau = rng.uniform(2, K - 2, 400)
    counts = rng.poisson(irf_histogram(tau, signal=300.0, background=300.0)).astype(np.float32)
    com = np.asarray(jaxsr.centre_of_mass(counts, CFG)) * K
    ml, valid, converged = jaxsr.maximum_likelihood_depth(counts, CFG, return_mask=True)
    ml = np.asarray(ml) * K
    rmse = lambda e: np.sqrt(np.mean(e**2))  # noqa: E731
    assert converged.mean() > 0.95
    assert rmse(ml - tau) < 0.95 * rmse(com - tau)


def test_maximum_likelihood_handles_empty_pixels_and_vmap():
    counts = jnp.zeros((2, 3, K))
    depth, valid, converged = jax.jit(
        lambda c: jaxsr.maximum_likelihood_depth(c, CFG, return_mask=True)
    )(counts)
    np.testing.assert_array_equal(depth, np.ones((2, 3)))
    assert depth.shape == valid.shape == converged.shape == (2, 3)


@pytest.mark.parametrize("k", [16, 15, 8, 65, 300])
def test_median_of_bins_equals_numpy_median_with_ties(k):
    from jaxsr.sensor.peaks import median_of_bins

    rng = np.random.default_rng(6)
    x = rng.integers(0, 4, (500, k)).astype(np.float32)  # many ties
    np.testing.assert_array_equal(median_of_bins(jnp.asarray(x)), np.median(x, axis=-1))
    y = rng.normal(size=(50, k))
    g = jax.grad(lambda v: jnp.sum(median_of_bins(v)))(jnp.asarray(y))
    g_ref = jax.grad(lambda v: jnp.sum(jnp.median(v, axis=-1)))(jnp.asarray(y))
    np.testing.assert_allclose(g, g_ref)


def test_median_of_many_bins_takes_memory_linear_in_the_bins():
    """16 frames of 32 x 64 pixels with 2000 bins (`jaxsr upscale --bins 2000`) asked XLA for 540 GB
    (K^2 comparisons per histogram); compiled now, the median's scratch memory is about the input's."""
    from jaxsr.sensor.peaks import median_of_bins

    counts = jax.ShapeDtypeStruct((16, 32, 64, 2000), jnp.float32)
    memory = jax.jit(median_of_bins).lower(counts).compile().memory_analysis()
    assert memory.temp_size_in_bytes < 4 * memory.argument_size_in_bytes


# --- the traced path (jit, vmap, grad): what the eager call refuses has a defined meaning -------------------


# each depth extraction with its mask, jitted once: the traced cases share their compiles
EXTRACTIONS = {fn: (lambda c, fn=fn: getattr(jaxsr, fn)(c, CFG, return_mask=True))
               for fn in ("centre_of_mass", "maximum_likelihood_depth")}
TRACED_EXTRACTIONS = {fn: jax.jit(f) for fn, f in EXTRACTIONS.items()}


@pytest.mark.parametrize("jit", [False, True])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, -1.0, -1e-3])
@pytest.mark.parametrize("fn", ["centre_of_mass", "maximum_likelihood_depth"])
def test_unusable_counts_raise_eagerly_and_are_no_return_traced(jit, bad, fn):
    """A histogram with a non-finite or negative count is refused eagerly; traced it is "no return" (1.0,
    invalid) and leaves every other pixel exactly as it would be without it."""
    rng = np.random.default_rng(7)
    counts = rng.poisson(irf_histogram(rng.uniform(1, K - 1, 6), signal=40.0, background=20.0)).astype(np.float32)
    f = EXTRACTIONS[fn]
    broken = counts.copy()
    broken[[1, 4], [3, 0]] = bad
    if not jit:
        with pytest.raises(ValueError, match=r"finite and >= 0"):
            f(broken)
        return
    depth, valid = TRACED_EXTRACTIONS[fn](broken)[:2]
    want, want_valid = f(counts)[:2]
    np.testing.assert_array_equal(np.asarray(depth)[[1, 4]], [1.0, 1.0])
    assert not np.any(np.asarray(valid)[[1, 4]])
    keep = [0, 2, 3, 5]
    np.testing.assert_allclose(np.asarray(depth)[keep], np.asarray(want)[keep], atol=1e-6)
    np.testing.assert_array_equal(np.asarray(valid)[keep], np.asarray(want_valid)[keep])


@pytest.mark.parametrize("jit", [False, True])
@pytest.mark.parametrize("dtype,scale", [(np.float16, 1e4), (np.float32, 1e38), (np.float32, 1e-30)])
def test_huge_and_tiny_counts_and_narrow_dtypes(jit, dtype, scale):
    """The centre of mass does not depend on the photon scale: float16 counts of 10^4 (whose window sum
    overflows float16) and float32 counts near its maximum give the same depth as moderate counts."""
    tau = np.array([2.3, 7.6, 12.9])
    hist = irf_histogram(tau, signal=1.0, background=0.2)
    f = lambda c: jaxsr.centre_of_mass(c, CFG)
    f = jax.jit(f) if jit else f
    want = np.asarray(jaxsr.centre_of_mass(hist.astype(np.float32), CFG))
    got = np.asarray(f((hist * scale).astype(dtype)))
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, want, atol=2e-3)


@pytest.mark.parametrize("window", ["a", -1, 1.5, [1, 2]])
def test_a_window_that_is_not_a_half_width_is_refused(window):
    counts = np.ones((2, 16), np.float32)
    with pytest.raises(ValueError, match="half-width in bins"):
        jaxsr.centre_of_mass(counts, window=window)


# ------------------------------------------------------------------------------------------ return_significance

def reference_log_pvalue(n, width=3):
    """The scan statistic's Bonferroni p-value, one histogram at a time, from scipy's binomial tail."""
    from scipy.stats import binom
    out = []
    for h in np.asarray(n, np.float64):
        total = h.sum()
        scan = max(h[i:i + width].sum() for i in range(K - width + 1))
        tail = binom.sf(scan - 1, total, width / K) if scan >= 1 else 1.0
        out.append(np.log(max(min((K - width + 1) * tail, 1.0), np.finfo(np.float32).tiny)))
    return np.array(out)


def test_return_significance_matches_the_binomial_scan_bound():
    rng = np.random.default_rng(3)
    counts = rng.poisson(irf_histogram(rng.uniform(1, K - 1, 40), signal=rng.uniform(0, 8, 40)[:, None],
                                       background=rng.uniform(0.5, 30, 40)[:, None])).astype(np.float32)
    np.testing.assert_allclose(np.asarray(jaxsr.sensor.return_significance(counts, CFG)),
                               reference_log_pvalue(counts), rtol=1e-3, atol=1e-4)


@pytest.mark.parametrize("per_bin", [0.15, 2.0, 50.0, 1e5, 1e6, 1e8])
def test_ambient_light_alone_is_a_return_at_most_at_the_false_alarm_rate(per_bin):
    """Valid at every ambient level without knowing it: ambient-only histograms reach log p <= log a in at most
    a share a of pixels (plus three binomial standard errors of the draw); up to 1e8 photons per bin, where the
    Chernoff bound stands in for float32's incomplete beta (NumPy's draws: jax.random.poisson's spread is 1.5x
    Poisson's at 1e8)."""
    counts = np.random.default_rng(0).poisson(per_bin, (100_000 if per_bin < 1e3 else 20_000, K))
    lp = np.asarray(jaxsr.sensor.return_significance(counts.astype(np.float32), CFG))
    for a in (0.1, 0.01, 0.001):
        assert (lp <= np.log(a)).mean() <= a + 3 * np.sqrt(a / lp.size)


@pytest.mark.parametrize("ambient,extra", [(1e4, 500.0), (1e5, 2e3), (1e6, 1e4), (1e7, 3e4)])
def test_many_photons_keep_the_bound_and_stay_close_to_it(ambient, extra):
    """Beyond EXACT_TAIL_MAX_PHOTONS the Chernoff bound: never more significant than the exact binomial bound
    (scipy, float64), and within 4 nats of it for a return 4-6 standard deviations above the ambient light."""
    hist = np.full((1, K), ambient)
    hist[0, 4] += extra
    got = float(np.asarray(jaxsr.sensor.return_significance(hist.astype(np.float32), CFG))[0])
    want = float(reference_log_pvalue(hist)[0])
    assert want - 1e-3 <= got <= want + 4.0


def test_a_weak_return_summed_over_frames_is_found():
    """3 signal photons per frame against 2 ambient ones: one frame finds few returns at a = 0.001, nine frames
    summed find nearly all, and ambient alone summed over nine frames stays at the false-alarm rate."""
    rng = np.random.default_rng(1)
    tau = rng.uniform(1, K - 1, 4000)
    rates = irf_histogram(tau, signal=3.0, background=2.0)
    frames = rng.poisson(np.repeat(rates[None], 9, 0)).astype(np.float32)
    f = lambda c: np.asarray(jaxsr.sensor.return_significance(c, CFG)) <= np.log(1e-3)
    assert f(frames[0]).mean() < 0.1
    assert f(frames.sum(0)).mean() > 0.95
    ambient = rng.poisson(2.0 / K, (9, 4000, K)).astype(np.float32)
    assert f(ambient.sum(0)).mean() < 0.003


@pytest.mark.parametrize("jit", [False, True])
def test_return_significance_at_the_extremes(jit):
    """No photons, one photon, flat histograms of 1e6 and 1e37 photons per bin and a peak of 1e37 photons are
    finite, in [log tiny, 0]; no evidence without photons or from a flat histogram however bright; an
    overwhelming peak at the floor; no gradient (a decision statistic)."""
    f = lambda c: jaxsr.sensor.return_significance(c, CFG)
    f = jax.jit(f) if jit else f
    peak = np.zeros(K, np.float32)
    peak[5] = 1e37
    counts = np.stack([np.zeros(K), np.eye(K)[3], np.full(K, 1e6), np.full(K, 1e37), peak]).astype(np.float32)
    lp = np.asarray(f(counts))
    assert np.all(np.isfinite(lp)) and np.all(lp <= 0) and np.all(lp >= np.log(np.finfo(np.float32).tiny) - 1e-3)
    assert lp[0] == 0.0 and lp[1] == 0.0 and lp[2] == 0.0 and lp[3] == 0.0 and lp[4] < -80
    grad = jax.grad(lambda c: f(c).sum())(counts)
    assert np.all(np.asarray(grad) == 0.0)


def test_return_significance_refuses_bad_counts_eagerly_and_is_no_evidence_traced():
    counts = np.ones((3, K), np.float32)
    counts[1, 2] = np.nan
    with pytest.raises(ValueError, match=r"finite and >= 0"):
        jaxsr.sensor.return_significance(counts, CFG)
    counts[2, 4] = 40.0
    lp = np.asarray(jax.jit(lambda c: jaxsr.sensor.return_significance(c, CFG))(counts))
    assert lp[1] == 0.0 and lp[2] < np.log(1e-3)
    with pytest.raises(ValueError, match="half-width in bins"):
        jaxsr.sensor.return_significance(np.ones((2, K), np.float32), window=1.5)


# ------------------------------------------------------------------------------------------------ ambient_only

def reference_ambient_only(counts, alpha, pixels, frames):
    """The neighbourhood sums, cut at the edges (zero padding), then the scan test."""
    r, q = frames // 2, pixels // 2
    padded = np.pad(np.asarray(counts, np.float64), ((r, r), (q, q), (q, q), (0, 0)))
    t, h, w = counts.shape[:3]
    summed = sum(padded[dt:dt + t, dy:dy + h, dx:dx + w] for dt in range(frames) for dy in range(pixels)
                 for dx in range(pixels))
    return np.asarray(jaxsr.sensor.return_significance(summed.astype(np.float32), CFG)) > np.log(alpha)


@pytest.mark.parametrize("pixels,frames", [(1, 1), (3, 9), (5, 3)])
def test_ambient_only_tests_the_neighbourhood_sum(pixels, frames):
    rng = np.random.default_rng(4)
    counts = rng.poisson(0.3, (6, 5, 7, K)).astype(np.float32)
    counts[:, 1:3, 2:5, 6] += rng.poisson(2.0, (6, 2, 3))
    got = np.asarray(jax.jit(jaxsr.sensor.ambient_only, static_argnames=("pixels", "frames"))(
        counts, alpha=1e-3, pixels=pixels, frames=frames))
    np.testing.assert_array_equal(got, reference_ambient_only(counts, 1e-3, pixels, frames))
    assert got.shape == counts.shape[:3] and got.dtype == bool


def test_ambient_only_finds_a_faint_surface_and_the_sky_beside_it():
    """3 signal photons per pixel and frame against 2 ambient (SNR 1.5) from a slanted surface: summed over 3 x 3
    pixels and 9 frames, the surface's pixels are not flagged and the sky's are, but for the column beside the
    surface, whose neighbourhood holds it, and at most about alpha of the others."""
    rng = np.random.default_rng(5)
    t, h, w = 9, 24, 24
    tau = 5.0 + 0.1 * (np.arange(h)[:, None] + np.arange(w // 2)[None, :])
    rates = np.zeros((h, w, K))
    rates[:, : w // 2] = irf_histogram(tau.ravel(), signal=3.0, background=2.0).reshape(h, w // 2, K)
    rates[:, w // 2:] = 2.0 / K
    counts = rng.poisson(np.broadcast_to(rates, (t, h, w, K))).astype(np.float32)
    flagged = np.asarray(jaxsr.sensor.ambient_only(counts, CFG, alpha=1e-3))
    assert flagged[:, :, : w // 2].mean() < 0.01
    assert flagged[:, :, w // 2 + 1:].mean() > 0.99
    single = np.asarray(jaxsr.sensor.ambient_only(counts, CFG, alpha=1e-3, pixels=1, frames=1))
    assert single[:, :, : w // 2].mean() > 0.5  # one histogram alone holds too few photons


def test_ambient_only_at_the_extremes():
    """No photons: ambient only (nothing to see); huge counts stay finite, a flat histogram of 1e37 per bin is
    ambient and a peak of 1e37 is not, and one huge histogram does not change its neighbours' flags; NaN is
    refused eagerly and, traced, adds nothing to its neighbours."""
    f = jax.jit(jaxsr.sensor.ambient_only, static_argnames=("pixels", "frames"))
    assert np.asarray(f(np.zeros((3, 4, 4, K), np.float32))).all()
    huge = np.full((3, 4, 4, K), 1e37, np.float32)
    assert np.asarray(f(huge)).all()
    huge[:, :2, :, 5] *= 3.0
    flagged = np.asarray(f(huge, pixels=1, frames=1))
    assert not flagged[:, :2].any() and flagged[:, 2:].all()
    counts = np.random.default_rng(6).poisson(0.2, (3, 6, 6, K)).astype(np.float32)
    counts[:, :3, :, 4] += 20.0
    corrupt = counts.copy()
    corrupt[1, 5, 5, 2] = 1e35  # far from the returns: their flags stay
    np.testing.assert_array_equal(np.asarray(f(corrupt))[:, :3], np.asarray(f(counts))[:, :3])
    bad = counts.copy()
    bad[1, 0, 0, 2] = np.nan
    with pytest.raises(ValueError, match=r"ambient_only: counts must be finite"):
        jaxsr.sensor.ambient_only(bad)
    clean, zeroed = counts.copy(), counts.copy()
    zeroed[1, 0, 0] = 0.0
    np.testing.assert_array_equal(np.asarray(f(bad)), np.asarray(f(zeroed)))
    assert not np.asarray(f(clean))[:, :2].any()


def reference_pooled(counts, alpha, frames, pools):
    """Each pixel's own sum over the frames tested, then the sums of the flagged pixels in each pool around it."""
    own = reference_ambient_only(counts, alpha, 1, frames)
    r = frames // 2
    t = counts.shape[0]
    padded = np.pad(np.asarray(counts, np.float64), ((r, r), (0, 0), (0, 0), (0, 0)))
    summed = sum(padded[dt:dt + t] for dt in range(frames)) * own[..., None]
    quiet = own.copy()
    for k in pools:
        quiet &= reference_ambient_only(summed.astype(np.float32), alpha / len(pools), k, 1)
    return quiet


def _dim_wall_and_sky(seed, signal):
    """9 frames of 24 x 24 pixels: a wall at bin 5 on the left half whose pixels each get `signal` photons a
    frame (SNR signal / 2), bright returns (20 photons) in the right half's top rows, and sky below them."""
    rng = np.random.default_rng(seed)
    t, h, w = 9, 24, 24
    rates = np.full((h, w, K), 2.0 / K)
    rates[:, : w // 2] = irf_histogram(np.full(h * (w // 2), 5.0), signal=signal, background=2.0).reshape(
        h, w // 2, K)
    rates[:6, w // 2:] = irf_histogram(np.full(6 * (w - w // 2), 9.0), signal=20.0, background=2.0).reshape(
        6, w - w // 2, K)
    return rng.poisson(np.broadcast_to(rates, (t, h, w, K))).astype(np.float32)


def test_pools_find_a_dim_wall_that_no_pixel_shows_and_leave_the_sky_beside_bright_returns():
    """A wall too dim for any pixel's own 9 frames (0.4 signal photons a frame against 2 ambient): flagged as
    ambient alone pixel by pixel, found by pooling the flagged pixels around each (but at the wall's edge with the
    sky, which its pools reach); sky beside bright returns stays flagged, since the bright pixels are not pooled."""
    counts = _dim_wall_and_sky(7, 0.4)
    f = jax.jit(jaxsr.sensor.ambient_only, static_argnames=("pixels", "frames", "pools"))
    own = np.asarray(f(counts, CFG, alpha=1e-3, pixels=1))[4]
    pooled = np.asarray(f(counts, CFG, alpha=1e-3, pixels=1, pools=jaxsr.sensor.QUIET_POOLS))[4]
    assert own[:, :12].mean() > 0.5  # one pixel's 9 frames hold too few photons
    assert pooled[:, :10].mean() < 0.02  # the pools find the wall
    assert not own[:6, 12:].any() and not pooled[:6, 12:].any()  # bright returns
    assert pooled[6:, 15:].all()  # sky right below bright returns and beyond the wall's pools: ambient alone
    assert not pooled[6:, 12].all()  # the cost: sky within a pool's reach of the dim wall shows its photons
    np.testing.assert_array_equal(np.asarray(f(counts, CFG, alpha=1e-3, pixels=1, pools=(3, 5))),
                                  reference_pooled(counts, 1e-3, 9, (3, 5)))


@pytest.mark.slow  # 8-32 s on 2 cores: keeps the default suite under 8 minutes
def test_pools_stream_as_the_whole_sequence_and_stay_finite_at_huge_counts():
    counts = _dim_wall_and_sky(8, 0.4)[:, :12, :16]
    whole = np.asarray(jaxsr.sensor.ambient_only(counts, CFG, alpha=1e-3, pixels=1, pools=(3, 5)))
    streamed = np.stack(list(jaxsr.inference.iter_ambient_only(iter(counts), CFG, alpha=1e-3, pixels=1,
                                                               pools=(3, 5))))
    np.testing.assert_array_equal(streamed, whole)
    huge = np.full((9, 6, 6, K), 1e37, np.float32)
    assert np.asarray(jaxsr.sensor.ambient_only(huge, CFG, pixels=1, pools=(3, 5))).all()  # flat: ambient
    huge[:, :, :3, 5] *= 3.0
    flagged = np.asarray(jaxsr.sensor.ambient_only(huge, CFG, pixels=1, pools=(3, 5)))
    assert not flagged[:, :, :3].any() and flagged[:, :, 4:].all()


def test_a_lone_flagged_pixel_is_not_no_return_but_a_region_of_two_is():
    flags = np.zeros((2, 6, 7), bool)
    flags[0, 2, 3] = True  # alone amid returns
    flags[0, 0, 0] = True  # alone at the corner: the frame's edge is no neighbour
    flags[1, 1, 1] = flags[1, 2, 2] = True  # two touching at a corner: a region, enclosed
    flags[1, 4:, 4:] = True  # a block at the edge
    got = np.asarray(jax.jit(jaxsr.sensor.without_holes, static_argnames="max_pixels")(flags, max_pixels=1))
    want = flags.copy()
    want[0] = False
    np.testing.assert_array_equal(got, want)
    assert np.asarray(jaxsr.sensor.without_holes(np.ones((3, 3), bool))).all()
    assert not np.asarray(jaxsr.sensor.without_holes(np.ones((1, 1), bool))).any()


def test_an_enclosed_quiet_region_is_filled_up_to_its_size_and_one_at_the_edge_never():
    """A region that returns enclose (not reaching the frame's edge) is filled while it holds at most max_pixels
    pixels; a region reaching the edge (sky) stays however small, down to two pixels."""
    flags = np.zeros((12, 16), bool)
    flags[2:5, 2:5] = True  # 9 pixels, enclosed
    flags[7:9, 9:13] = True  # 8 pixels, enclosed
    flags[0, 14:] = True  # 2 pixels on the top edge
    flags[10:, 0:3] = True  # 6 pixels in a corner
    edge = np.zeros_like(flags)
    edge[0, 14:] = edge[10:, 0:3] = True
    for max_pixels, filled_too in ((7, None), (8, (slice(7, 9), slice(9, 13))), (9, "all")):
        got = np.asarray(jaxsr.sensor.without_holes(flags, max_pixels))
        want = flags.copy()
        if filled_too == "all":
            want = edge
        elif filled_too is not None:
            want[filled_too] = False
        np.testing.assert_array_equal(got, want, err_msg=f"max_pixels {max_pixels}")
    assert np.asarray(jaxsr.sensor.without_holes(flags)).sum() == edge.sum()  # HOLE_PIXELS fills both


def test_regions_are_scipys_8_connected_components():
    """`without_holes` on random masks against scipy.ndimage.label's 8-connected components, with frames stacked
    in leading axes and under jit; a one-pixel-wide snake, the longest path a label spreads along, converges too."""
    ndi = pytest.importorskip("scipy.ndimage")
    rng = np.random.default_rng(0)

    def expected(f, max_pixels):
        label, n = ndi.label(f, structure=np.ones((3, 3)))
        out = np.zeros_like(f)
        for c in range(1, n + 1):
            r = label == c
            at_edge = r[0].any() or r[-1].any() or r[:, 0].any() or r[:, -1].any()
            if r.sum() >= 2 and (at_edge or r.sum() > max_pixels):
                out |= r
        return out

    fill = jax.jit(jaxsr.sensor.without_holes, static_argnames="max_pixels")
    for _ in range(6):
        flags = rng.random((2, 3, 17, 23)) < rng.uniform(0.2, 0.7)
        max_pixels = int(rng.integers(1, 40))
        got = np.asarray(fill(flags, max_pixels=max_pixels))
        for index in np.ndindex(2, 3):
            np.testing.assert_array_equal(got[index], expected(flags[index], max_pixels))
    snake = np.zeros((15, 20), bool)
    snake[1:-1:2, 1:-1] = True
    snake[2:-1:4, -2] = snake[4:-1:4, 1] = True
    label, size = jaxsr.sensor.regions(jnp.asarray(snake))
    assert int(size[int(label[1, 1])]) == snake.sum() and len(np.unique(np.asarray(label)[snake])) == 1
    np.testing.assert_array_equal(np.asarray(fill(snake, max_pixels=snake.sum() - 1)), snake)
    assert not np.asarray(fill(snake, max_pixels=int(snake.sum()))).any()


@pytest.mark.parametrize("max_pixels", [0, -3, 2.5, True, None])
def test_without_holes_refuses_a_size_that_is_not_a_count(max_pixels):
    with pytest.raises(ValueError, match="max_pixels"):
        jaxsr.sensor.without_holes(np.ones((3, 3), bool), max_pixels)


def test_beside_sky_adds_the_border_of_a_large_region_only():
    """The LR pixels around a flagged region of more than min_pixels (8-connected, corners included) join it; a
    region of min_pixels or fewer (a hole's size) gets no border; 0 borders every region."""
    flags = np.zeros((2, 10, 12), bool)
    flags[:, :, 8:] = True  # 40 pixels of sky at the right edge
    flags[:, 4:6, 2:4] = True  # 4 pixels
    want = flags.copy()
    want[:, :, 7] = True
    got = np.asarray(jax.jit(jaxsr.sensor.beside_sky, static_argnames="min_pixels")(flags, min_pixels=16))
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(np.asarray(jaxsr.sensor.beside_sky(flags, 40)), flags)  # not more than 40
    around = want.copy()
    around[:, 3:7, 1:5] = True
    np.testing.assert_array_equal(np.asarray(jaxsr.sensor.beside_sky(flags, 0)), around)
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="min_pixels"):
            jaxsr.sensor.beside_sky(flags, bad)


def test_iter_quiet_is_the_pooled_test_without_holes_and_names_the_holes():
    counts = _dim_wall_and_sky(9, 0.4)
    counts[:, 9, 14] = 0.0  # a pixel that sends back no photon amid the sky: still a region with the sky
    counts[:, 2:4, 16:18] = np.random.default_rng(1).poisson(2.0 / K, (9, 2, 2, K))  # black, amid bright returns
    flags = jaxsr.sensor.ambient_only(counts, CFG, alpha=1e-3, pixels=1, pools=jaxsr.sensor.QUIET_POOLS)
    whole = jaxsr.sensor.without_holes(flags)
    assert np.asarray(flags)[:, 2:4, 16:18].all() and not np.asarray(whole)[:, 2:4, 16:18].any()  # a hole, filled
    assert np.asarray(whole)[:, 9, 14].all()
    got = list(jaxsr.inference.iter_quiet(iter(counts), CFG, alpha=1e-3))
    np.testing.assert_array_equal(np.stack([q.quiet for q in got]), np.asarray(whole))
    holes = np.stack([q.holes for q in got])
    np.testing.assert_array_equal(holes, np.asarray(jaxsr.sensor.hole_pixels(flags)))
    np.testing.assert_array_equal(holes, np.asarray(flags) & ~np.asarray(whole))  # the hole, and nothing quiet else
    assert holes[:, 2:4, 16:18].all() and not holes[:, 9, 14].any()
    assert not np.stack([q.black for q in got]).any()  # the hole holds ambient light as its neighbours do
    np.testing.assert_array_equal(np.asarray(jaxsr.sensor.quiet_pixels(counts, CFG, alpha=1e-3)), np.asarray(whole))


@pytest.mark.slow  # compiles the streamed and the whole-sequence test: 10-40 s on 2 cores
def test_iter_quiet_names_the_black_holes_as_the_whole_sequence_does():
    counts = _dim_wall_and_sky(9, 0.4)
    counts[:, 2:4, 16:18] = np.random.default_rng(1).poisson(2.0 / K, (9, 2, 2, K))  # ambient as around: not black
    for black_patch in (False, True):
        if black_patch:
            counts[:, 2:4, 16:18] = 0.0  # no photon at all amid the returns' ambient light
        black = np.stack([q.black for q in jaxsr.inference.iter_quiet(iter(counts), CFG, alpha=1e-3)])
        np.testing.assert_array_equal(black, np.asarray(jaxsr.sensor.black_hole_pixels(counts, CFG, alpha=1e-3)))
        assert black.sum() == (4 * len(counts) if black_patch else 0) and black[:, 2:4, 16:18].all() == black_patch


@pytest.mark.parametrize("pools", [(2,), (3, 4), [3, 5], (0,), (True,)])
def test_pools_refused_unless_a_tuple_of_odd_sides(pools):
    with pytest.raises(ValueError, match="pools"):
        jaxsr.sensor.ambient_only(np.zeros((2, 4, 4, K), np.float32), pools=pools)


@pytest.mark.parametrize("kwargs,match", [({"pixels": 2}, "odd integer"), ({"frames": 0}, "odd integer"),
                                          ({"pixels": True}, "odd integer"), ({"alpha": 0.0}, "false-alarm rate"),
                                          ({"alpha": 1.0}, "false-alarm rate"), ({"alpha": 1e-35}, r"\[1e-30, 1\)"),
                                          ({"alpha": "0.001"}, "false-alarm rate")])
def test_ambient_only_refuses_bad_settings(kwargs, match):
    with pytest.raises(ValueError, match=match):
        jaxsr.sensor.ambient_only(np.zeros((2, 4, 4, K), np.float32), **kwargs)
    with pytest.raises(ValueError, match=r"\(T, h, w, 16\)"):
        jaxsr.sensor.ambient_only(np.zeros((4, 4, K), np.float32))
