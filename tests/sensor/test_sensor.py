"""Conformance of the sensor model with docs/sensor-model.md, sections 1-2, against a slow float64 NumPy reference."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import jaxsr
from jaxsr.sensor import forward as sensor_mod

SMALL = jaxsr.Sensor(optics=jaxsr.Optics.of_hr((16, 24), 4))


def reference_rates(depth, intensity, cfg, snr, mean_signal):
    """docs/sensor-model.md, section 2 written out pixel by pixel, float64, no vectorisation tricks."""
    K, s = cfg.bins, cfg.scale
    H, W = depth.shape[-2:]
    lead = depth.shape[:-2]
    depth = depth.reshape((-1, H, W))
    intensity = intensity.reshape((-1, H, W))
    n = depth.shape[0]
    sig = np.zeros((n, H // s, W // s, K))
    s_sum = np.zeros((n, H // s, W // s))
    a_sum = np.zeros((n, H // s, W // s))
    phi = lambda x: 0.5 * (1 + math.erf(x / math.sqrt(2)))  # noqa: E731
    for f in range(n):
        for y in range(H):
            for x in range(W):
                r, rho = float(depth[f, y, x]), float(intensity[f, y, x])
                p = (f, y // s, x // s)
                a_sum[p] += rho + cfg.ambient_floor
                if not (math.isfinite(r) and 0 <= r <= cfg.d_max):
                    continue
                si = rho / max(r, cfg.r_min) ** 2
                s_sum[p] += si
                tau = K * r / cfg.d_max
                for k in range(K):
                    sig[p + (k,)] += si * (phi((k + 1 - tau) / cfg.irf_sigma) - phi((k - tau) / cfg.irf_sigma))
    valid = s_sum > 0
    gated = sig.sum(-1)  # the signal inside the gate: what the 16 bins hold
    if valid.any():
        alpha = mean_signal / gated[valid].mean()
        beta = alpha * (gated[valid] / a_sum[valid]).mean() / snr
    else:
        alpha, beta = 0.0, mean_signal / (snr * a_sum.mean())
    rates = alpha * sig + beta / K * a_sum[..., None]
    return rates.reshape(lead + rates.shape[1:])


def random_scene(rng, shape, sky_fraction=0.1):
    depth = rng.uniform(0.0, 40.0, shape)
    depth[rng.uniform(size=shape) < sky_fraction] = np.inf
    depth[rng.uniform(size=shape) < 0.02] = np.nan
    near = rng.uniform(size=shape) < 0.02  # inside r_min, where the inverse-square law is floored
    depth[near] = rng.uniform(0.0, 0.6, near.sum())
    intensity = rng.uniform(0.0, 1.0, shape)
    return depth, intensity


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rates_match_float64_reference(seed):
    rng = np.random.default_rng(seed)
    depth, intensity = random_scene(rng, (2,) + SMALL.hr_shape)
    snr, mean_signal = rng.uniform(0.3, 10), rng.uniform(0.5, 50)
    want = reference_rates(depth, intensity, SMALL, snr, mean_signal)
    with jax.enable_x64(True):
        got = np.asarray(jaxsr.expected_histograms(depth, intensity, SMALL, snr=snr, mean_signal=mean_signal))
    assert got.dtype == np.float64
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-12 * want.max())


def test_rates_float32_close_to_reference():
    rng = np.random.default_rng(3)
    depth, intensity = random_scene(rng, SMALL.hr_shape)
    want = reference_rates(depth, intensity, SMALL, 1.3, 4.0)
    got = np.asarray(jaxsr.expected_histograms(depth, intensity, SMALL, snr=1.3, mean_signal=4.0))
    np.testing.assert_allclose(got, want, rtol=2e-4, atol=1e-6 * want.max())


@pytest.mark.parametrize("snr,mean_signal", [(1.3, 4.0), (0.5, 2.0), (8.0, 100.0)])
@pytest.mark.parametrize("near,far", [(3.0, 30.0), (0.0, 1.0), (34.0, 35.0)])
def test_calibration_hits_frame_snr_and_signal(snr, mean_signal, near, far):
    """The paper's SNR counts the photons in the histogram: returns near the gate's ends (0 and d_max) lose up to
    half their IRF outside its 16 bins, and the calibration still hits the target with what is left."""
    rng = np.random.default_rng(4)
    depth = rng.uniform(near, far, (3,) + SMALL.hr_shape)
    depth[:, :4] = np.inf  # a sky band tests the valid-pixel set V
    intensity = rng.uniform(0.05, 1.0, depth.shape)
    alpha, beta = jaxsr.calibrate(depth, intensity, SMALL, snr=snr, mean_signal=mean_signal)
    rates = np.asarray(jaxsr.expected_histograms(depth, intensity, SMALL, snr=snr, mean_signal=mean_signal))
    signal_hist, _, a_sum = sensor_mod._photon_terms(jnp.asarray(depth), jnp.asarray(intensity), SMALL)
    signal = float(alpha) * np.asarray(signal_hist).sum(-1)
    background = float(beta) * np.asarray(a_sum)
    valid = signal > 0
    assert abs(signal[valid].mean() / mean_signal - 1) < 5e-3
    assert abs((signal[valid] / background[valid]).mean() / snr - 1) < 5e-3
    # The rates themselves carry that many photons: total = signal + background.
    np.testing.assert_allclose(rates.sum(-1), signal + background, rtol=5e-3)


def test_all_sky_calibration():
    depth = np.full(SMALL.hr_shape, np.inf)
    intensity = np.full(SMALL.hr_shape, 0.7)
    alpha, beta = jaxsr.calibrate(depth, intensity, SMALL, snr=2.0, mean_signal=6.0)
    assert float(alpha) == 0.0
    a_mean = 16 * (0.7 + SMALL.ambient_floor)
    assert float(beta) == pytest.approx(6.0 / (2.0 * a_mean), rel=1e-6)


def test_poisson_mean_and_variance_over_keys():
    rng = np.random.default_rng(5)
    depth, intensity = random_scene(rng, SMALL.hr_shape)
    rates = np.asarray(jaxsr.expected_histograms(depth, intensity, SMALL, snr=1.0, mean_signal=20.0))
    keys = jax.random.split(jax.random.key(0), 4000)
    draw = jax.jit(jax.vmap(lambda k: jaxsr.simulate_histograms(k, depth, intensity, SMALL, snr=1.0, mean_signal=20.0)))
    counts = np.asarray(draw(keys), np.float64)
    assert np.all(counts == np.round(counts)) and counts.min() >= 0
    n = counts.shape[0]
    se = np.sqrt(rates / n) + 1e-9
    z_mean = (counts.mean(0) - rates) / se
    assert np.abs(z_mean).max() < 5.5 and abs(z_mean.mean()) < 0.1
    var = counts.var(0, ddof=1)
    big = rates > 2
    np.testing.assert_allclose(var[big].mean() / rates[big].mean(), 1.0, atol=0.02)


def test_planar_to_radial_closed_form():
    cfg = jaxsr.Sensor()
    z = np.full(cfg.hr_shape, 10.0)
    r = np.asarray(jaxsr.sensor.planar_to_radial(z, cfg))
    f = (cfg.hr_shape[1] / 2) / math.tan(math.radians(15))
    assert f == pytest.approx(477.7, abs=0.05)
    # corner pixel centre (0.5, 0.5): offsets (0.5 - 128, 0.5 - 64)
    want = 10 * math.sqrt(1 + ((0.5 - 128) / f) ** 2 + ((0.5 - 64) / f) ** 2)
    assert r[0, 0] == pytest.approx(want, rel=1e-6)
    assert r.min() > 10.0 and r.min() == pytest.approx(10 * math.sqrt(1 + 2 * (0.5 / f) ** 2), rel=1e-6)
    # vertical FoV 15.25 deg: the ray through the top edge
    assert math.degrees(2 * math.atan(64 / f)) == pytest.approx(15.25, abs=0.02)  # the docs round 15.26


def test_normalise_depth_conventions():
    cfg = jaxsr.Sensor()
    d = jnp.array([0.0, 17.5, 35.0, 35.01, jnp.inf, jnp.nan, -1.0, 1e6])
    np.testing.assert_allclose(jaxsr.normalise_depth(d, cfg), [0, 0.5, 1, 1, 1, 1, 1, 1])


def test_denormalise_depth_inverts_normalise_depth_inside_the_range():
    cfg = jaxsr.Sensor(gate=jaxsr.Gate.spanning(20.0, 16), depth=jaxsr.DepthScale(0.0, 20.0))
    # up to the last float32 below d_max: the largest depth that is still a return
    d = np.concatenate([np.random.default_rng(0).uniform(0.0, 20.0, 1000), [0.0, np.nextafter(np.float32(20), 0)]])
    back = np.asarray(jaxsr.denormalise_depth(jaxsr.normalise_depth(d.astype(np.float32), cfg), cfg))
    assert np.all(np.isfinite(back))
    np.testing.assert_allclose(back, d, rtol=2e-7, atol=0)


def test_denormalise_depth_no_return_and_nan():
    """Normalised 1.0 and above is no return; just below 1 is a return; NaN is no return; below 0 is 0 m."""
    cfg = jaxsr.Sensor()
    below_one = np.nextafter(np.float32(1), np.float32(0))
    norm = jnp.array([0.5, 1.0, 1.2, below_one, jnp.nan, -0.1])
    out = np.asarray(jaxsr.denormalise_depth(norm, cfg))
    np.testing.assert_array_equal(out[[1, 2, 4]], np.inf)
    np.testing.assert_allclose(out[[0, 3, 5]], [17.5, float(below_one) * 35.0, 0.0], rtol=1e-7)
    # what normalise_depth calls no return (inf, NaN, beyond or at d_max) comes back as inf
    for d in (np.inf, np.nan, 35.0, 40.0):
        assert np.isinf(jaxsr.denormalise_depth(jaxsr.normalise_depth(d, cfg), cfg))
    # jit-compatible, and batched like any elementwise function
    np.testing.assert_array_equal(jax.jit(jaxsr.denormalise_depth)(norm, cfg), out)


def test_sum_over_blocks_is_the_block_sum():
    rng = np.random.default_rng(6)
    x = rng.normal(size=(2, 8, 12))
    got = sensor_mod._sum_over_blocks(lambda v: v, 4, jnp.asarray(x))
    np.testing.assert_allclose(got, x.reshape(2, 2, 4, 3, 4).sum((2, 4)), rtol=1e-6)


# --- transformations -------------------------------------------------------------------------------------


@pytest.mark.slow  # about 10 s: keeps the default suite under 8 minutes on 2 cores
def test_jit_equals_eager_and_vmap_equals_loop():
    rng = np.random.default_rng(7)
    depth, intensity = random_scene(rng, (3,) + SMALL.hr_shape)
    depth, intensity = jnp.asarray(depth, jnp.float32), jnp.asarray(intensity, jnp.float32)
    f = lambda d, i: jaxsr.expected_histograms(d, i, SMALL, snr=1.3, mean_signal=5.0)  # noqa: E731
    np.testing.assert_allclose(jax.jit(f)(depth, intensity), f(depth, intensity), rtol=1e-6)
    # vmap calibrates each sequence on its own, exactly like a loop
    batched = jax.vmap(f)(depth[:, None], intensity[:, None])
    looped = jnp.stack([f(depth[i : i + 1], intensity[i : i + 1]) for i in range(3)])
    np.testing.assert_allclose(batched, looped, rtol=1e-6)
    key = jax.random.key(3)
    sim = lambda k, d, i: jaxsr.simulate_histograms(k, d, i, SMALL, snr=1.3, mean_signal=5.0)  # noqa: E731
    np.testing.assert_array_equal(jax.jit(sim)(key, depth, intensity), sim(key, depth, intensity))


def test_the_sensor_is_a_pytree_with_static_shapes():
    cfg = jaxsr.Sensor()
    leaves, treedef = jax.tree_util.tree_flatten(cfg)
    # bin width, gate start, field of view, pulse sigma, depth offset and span, r_min, ambient floor
    assert len(leaves) == 8
    assert jax.tree_util.tree_unflatten(treedef, leaves) == cfg
    # vmap over a physical parameter: the IRF width
    rng = np.random.default_rng(8)
    depth, intensity = random_scene(rng, SMALL.hr_shape)
    sigmas = jnp.array([0.3, 0.4, 0.6])

    def rates(sigma):
        cfg_s = jaxsr.Sensor(optics=jaxsr.Optics.of_hr(SMALL.hr_shape, 4), pulse=jaxsr.Pulse(sigma))
        return jaxsr.expected_histograms(depth, intensity, cfg_s, snr=1.3, mean_signal=5.0)

    got = jax.vmap(rates)(sigmas)
    np.testing.assert_allclose(got[1], rates(0.4), rtol=1e-5)


def test_gradients_match_finite_differences_float64():
    rng = np.random.default_rng(9)
    depth = rng.uniform(2.0, 30.0, SMALL.hr_shape)
    intensity = rng.uniform(0.1, 1.0, SMALL.hr_shape)
    weights = rng.normal(size=(4, 6, 16))
    with jax.enable_x64(True):
        cfg = jaxsr.Sensor(optics=jaxsr.Optics.of_hr(SMALL.hr_shape, 4), pulse=jaxsr.Pulse(jnp.float64(0.4)))

        def loss(d, i, snr, sigma):
            c = jaxsr.Sensor(optics=jaxsr.Optics.of_hr(SMALL.hr_shape, 4), pulse=jaxsr.Pulse(sigma))
            return jnp.sum(weights * jaxsr.expected_histograms(d, i, c, snr=snr, mean_signal=5.0))

        args = (jnp.asarray(depth), jnp.asarray(intensity), jnp.float64(1.3), cfg.irf_sigma)
        check_grads(loss, args, order=1, modes=["rev"], eps=1e-6, atol=1e-6, rtol=1e-5)


# --- extremes ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("snr", [1e-3, 1.3, 1e4])
@pytest.mark.parametrize("mean_signal", [0.0, 4.0, 1e7])
def test_extremes_are_finite(snr, mean_signal):
    rng = np.random.default_rng(10)
    depth, intensity = random_scene(rng, SMALL.hr_shape)
    depth[0, :3] = [0.0, 1e6, -5.0]
    intensity[1] = 0.0  # black row
    rates = jaxsr.expected_histograms(depth, intensity, SMALL, snr=snr, mean_signal=mean_signal)
    assert np.all(np.isfinite(rates)) and float(rates.min()) >= 0
    counts = jaxsr.simulate_histograms(jax.random.key(0), depth, intensity, SMALL, snr=snr, mean_signal=mean_signal)
    assert np.all(np.isfinite(counts)) and float(counts.min()) >= 0
    com = jaxsr.centre_of_mass(counts, SMALL)
    assert np.all((com >= 0) & (com <= 1))

    def loss(d, i):
        return jnp.sum(jnp.log1p(jaxsr.expected_histograms(d, i, SMALL, snr=snr, mean_signal=mean_signal)))

    grads = jax.grad(loss, argnums=(0, 1))(jnp.asarray(depth, jnp.float32), jnp.asarray(intensity, jnp.float32))
    assert all(np.all(np.isfinite(g)) for g in grads)


def test_black_scene_and_zero_ambient():
    depth = np.full(SMALL.hr_shape, 10.0)
    intensity = np.zeros(SMALL.hr_shape)
    cfg = jaxsr.Sensor(optics=jaxsr.Optics.of_hr(SMALL.hr_shape, 4), ambient_floor=0.0)
    rates = jaxsr.expected_histograms(depth, intensity, cfg, snr=1.0, mean_signal=4.0)
    assert np.all(np.isfinite(rates))
    lit = np.full(SMALL.hr_shape, 0.5)
    lit[:4, :4] = 0.0  # one LR block without any light: no signal and no ambient there

    def loss(i, a0):
        c = jaxsr.Sensor(optics=jaxsr.Optics.of_hr(SMALL.hr_shape, 4), ambient_floor=a0)
        return jnp.sum(jaxsr.expected_histograms(depth, i, c, snr=1.0, mean_signal=4.0))

    grads = jax.grad(loss, argnums=(0, 1))(jnp.asarray(lit, jnp.float32), jnp.float32(0.0))
    assert all(np.all(np.isfinite(g)) for g in grads)


# --- bad input ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "depth_shape,intensity_shape,match",
    [
        ((16, 25), (16, 25), "depth must have shape"),
        ((16,), (16,), "depth must have shape"),
        ((16, 24), (16, 20), "intensity shape"),
    ],
)
def test_bad_shapes_raise(depth_shape, intensity_shape, match):
    with pytest.raises(ValueError, match=match):
        jaxsr.expected_histograms(np.ones(depth_shape), np.ones(intensity_shape), SMALL, snr=1.0)


def test_hr_not_divisible_by_scale_raises():
    with pytest.raises(ValueError, match="divisible by scale"):
        jaxsr.Sensor(optics=jaxsr.Optics.of_hr((18, 24), 4))


@pytest.mark.parametrize("bad", [-0.1, 1.5, np.nan])
def test_intensity_out_of_range_raises(bad):
    intensity = np.full(SMALL.hr_shape, 0.5)
    intensity[2, 3] = bad
    with pytest.raises(ValueError, match=r"intensity must be finite and in \[0, 1\]"):
        jaxsr.simulate_histograms(jax.random.key(0), np.ones(SMALL.hr_shape), intensity, SMALL, snr=1.0)


@pytest.mark.parametrize("kwargs,match", [(dict(snr=0.0), "snr must be finite and > 0"),
                                          (dict(snr=1.0, mean_signal=-1.0), "mean_signal")])
def test_bad_photon_levels_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        jaxsr.calibrate(np.ones(SMALL.hr_shape), np.ones(SMALL.hr_shape), SMALL, **kwargs)


# --- the traced path (jit, vmap, grad): values cannot be checked, so they have defined meanings ---------------


def _scene(seed=11):
    depth, intensity = random_scene(np.random.default_rng(seed), SMALL.hr_shape)
    return depth.astype(np.float32), intensity.astype(np.float32)


@pytest.mark.parametrize("bad,means", [(np.nan, 0.0), (np.inf, 0.0), (-np.inf, 0.0), (-0.5, 0.0), (1.5, 1.0)])
@pytest.mark.parametrize("fn", ["expected_histograms", "calibrate"])
def test_traced_intensity_outside_0_1_is_clipped_and_non_finite_is_black(bad, means, fn):
    """Under jit an intensity the eager call refuses acts on its own pixel only, by the documented rule
    (non-finite -> 0, outside [0, 1] -> clipped), and never poisons the other pixels."""
    depth, intensity = _scene()
    bad_i, clean_i = intensity.copy(), intensity.copy()
    bad_i[[0, 5, 9], [3, 0, 17]] = bad
    clean_i[[0, 5, 9], [3, 0, 17]] = means
    f = lambda d, i: getattr(jaxsr, fn)(d, i, SMALL, snr=1.3, mean_signal=5.0)
    with pytest.raises(ValueError, match=r"intensity must be finite and in \[0, 1\]"):
        f(depth, bad_i)  # eagerly a user error
    got, want = jax.jit(f)(depth, bad_i), f(depth, clean_i)
    np.testing.assert_allclose(got, want, rtol=1e-6)
    assert all(np.all(np.isfinite(x)) for x in jax.tree_util.tree_leaves(got))


# The calls of the no-return cases, with depth and intensity as arguments: the traced cases share their compiles.
RATES_OF = lambda d, i: jaxsr.expected_histograms(d, i, SMALL, snr=1.3, mean_signal=5.0)
SIMULATED = lambda k, d, i: jaxsr.simulate_histograms(k, d, i, SMALL, snr=1.3)
TRACED_RATES_OF, TRACED_SIMULATED = jax.jit(RATES_OF), jax.jit(SIMULATED)


@pytest.mark.parametrize("jit", [False, True])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, -3.0, 1e30])
def test_depth_without_a_return_is_the_same_eager_and_traced(jit, bad):
    """NaN, inf, negative and beyond-d_max depth mean "no return" (signal weight 0) in both paths."""
    depth, intensity = _scene()
    rates = TRACED_RATES_OF if jit else RATES_OF
    f = lambda d: rates(d, intensity)
    bad_d, sky_d = depth.copy(), depth.copy()
    bad_d[2, :] = bad
    sky_d[2, :] = np.inf
    np.testing.assert_allclose(f(bad_d), f(sky_d), rtol=1e-6)
    key = jax.random.key(1)
    sim = TRACED_SIMULATED if jit else SIMULATED
    bad_i = intensity.copy()
    bad_i[0, 0] = np.nan if jit else 0.5  # one NaN pixel used to make every count NaN
    assert np.all(np.isfinite(sim(key, bad_d, bad_i)))


BAD_LEVELS = [
    ({"snr": -1.0}, "snr"), ({"snr": 0.0}, "snr"), ({"snr": np.nan}, "snr"), ({"snr": np.inf}, "snr"),
    ({"snr": 1.3, "mean_signal": -1.0}, "mean_signal"), ({"snr": 1.3, "mean_signal": np.nan}, "mean_signal"),
    ({"snr": 1.3, "mean_signal": np.inf}, "mean_signal"),
]


# The four calls with the photon levels as arguments, jitted once at import: the traced cases share their compiles.
LEVEL_CALLS = {
    "calibrate": lambda k, d, i, s, m: jaxsr.calibrate(d, i, SMALL, snr=s, mean_signal=m),
    "expected_histograms": lambda k, d, i, s, m: jaxsr.expected_histograms(d, i, SMALL, snr=s, mean_signal=m),
    "fast": lambda k, d, i, s, m: jaxsr.simulate_histograms(k, d, i, SMALL, snr=s, mean_signal=m),
    "exact": lambda k, d, i, s, m: jaxsr.simulate_histograms(k, d, i, SMALL, snr=s, mean_signal=m, sampler="exact"),
}
LEVEL_CALLS_JIT = {name: jax.jit(fn) for name, fn in LEVEL_CALLS.items()}


@pytest.mark.parametrize("kwargs,name", BAD_LEVELS,
                         ids=[",".join(f"{k}={v}" for k, v in kw.items()) for kw, _ in BAD_LEVELS])
@pytest.mark.parametrize("jit", [False, True])
def test_invalid_photon_levels_raise_eagerly_and_are_nan_everywhere_traced(kwargs, name, jit):
    depth, intensity = _scene()
    args = (jax.random.key(2), depth, intensity, jnp.float32(kwargs["snr"]),
            jnp.float32(kwargs.get("mean_signal", 5.0)))
    for fn in (LEVEL_CALLS_JIT if jit else LEVEL_CALLS).values():
        if not jit:
            with pytest.raises(ValueError, match=name):
                fn(*args)
            continue
        out = jax.tree_util.tree_leaves(fn(*args))
        assert all(np.all(np.isnan(x)) for x in out), [np.asarray(x).ravel()[:4] for x in out]


@pytest.mark.parametrize("level", ["snr", "mean_signal"])
@pytest.mark.parametrize("jit", [False, True])
def test_an_array_of_photon_levels_is_refused_as_not_a_scalar(level, jit):
    """An array where one number is expected was broadcast into the bins' axis (a TypeError in JAX's
    words): a ValueError saying one number is expected, under jit too."""
    depth, intensity = _scene()
    levels = {"snr": jnp.float32(1.3), "mean_signal": jnp.float32(5.0), level: np.array([1.0, 2.0], np.float32)}
    for fn in (LEVEL_CALLS_JIT if jit else LEVEL_CALLS).values():
        with pytest.raises(ValueError, match=f"{level} must be a scalar .* got an array of shape \\(2,\\); for several "
                           "values, jax.vmap"):
            fn(jax.random.key(2), depth, intensity, levels["snr"], levels["mean_signal"])


@pytest.mark.parametrize(
    "path,value", [(("gate", "bin_width"), 0.0), (("gate", "bin_width"), np.nan), (("depth", "span"), 0.0),
                   (("pulse", "sigma"), 0.0), (("pulse", "sigma"), -0.4), (("r_min",), 0.0),
                   (("ambient_floor",), -0.05), (("ambient_floor",), np.inf)]
)
@pytest.mark.parametrize("jit", [False, True])
def test_invalid_sensor_physics_raises_eagerly_and_is_nan_everywhere_traced(path, value, jit):
    depth, intensity = _scene()

    def rates(v):
        part = v if len(path) == 1 else dataclasses.replace(getattr(SMALL, path[0]), **{path[1]: v})
        cfg = dataclasses.replace(SMALL, **{path[0]: part})
        return jaxsr.expected_histograms(depth, intensity, cfg, snr=1.3, mean_signal=5.0)

    if not jit:
        with pytest.raises(ValueError, match=path[-1]):
            rates(value)
    else:
        assert np.all(np.isnan(jax.jit(rates)(jnp.float32(value))))


@pytest.mark.parametrize(
    "snr,mean_signal,where",
    [(1.3, 0.0, None), (1e-3, 5.0, None), (1e4, 5.0, None), (1.3, 5.0, "depth"), (1.3, 5.0, "intensity")],
)
def test_depth_pipeline_gradients_stay_finite_at_the_extremes(snr, mean_signal, where):
    """d/d(depth, intensity) of centre_of_mass(expected_histograms(...)): zero photons, SNR 1e-3 and 1e4, and
    NaN pixels in the input (under grad, as under jit, by the traced rules) all give finite gradients."""
    depth, intensity = _scene(12)
    depth[0, 0] = np.inf
    if where == "depth":
        depth[[1, 4], [2, 7]] = np.nan
    elif where == "intensity":
        intensity[[1, 4], [2, 7]] = np.nan

    def loss(d, i):
        rates = jaxsr.expected_histograms(d, i, SMALL, snr=snr, mean_signal=mean_signal)
        return jnp.sum(jaxsr.centre_of_mass(rates, SMALL))

    value, grads = jax.value_and_grad(loss, argnums=(0, 1))(jnp.asarray(depth), jnp.asarray(intensity))
    assert np.isfinite(value)
    assert all(np.all(np.isfinite(g)) for g in grads)
    if mean_signal > 0 and where is None:  # the gradient is there, not just finite
        assert np.any(np.asarray(grads[0]) != 0)
