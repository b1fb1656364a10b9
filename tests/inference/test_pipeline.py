"""The differentiable pipeline: surrogate derivatives of the photon draw, and `pipeline_metric` under grad/vmap."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsr
from jaxsr.sensor.poisson import NORMAL_ABOVE, poisson_pathwise, sample_poisson

# Small enough that compiling a gradient through the whole pipeline takes seconds: x2, 8 bins, one dense block.
SMALL = jaxsr.Sensor(gate=jaxsr.Gate.spanning(35.0, 8), optics=jaxsr.Optics.of_hr((8, 16), 2))
TINY = jaxsr.ModelConfig(tr=0, scale=2, base=8, growth=4, head=16, filter_hidden=16, same_blocks=1, filter_size=3)
# the sensor's physical leaves, as paths into the Sensor's parts
LEAVES = (("pulse", "sigma"), ("ambient_floor",), ("r_min",), ("gate", "bin_width"), ("depth", "span"))


def _leaf(sensor, path):
    for name in path:
        sensor = getattr(sensor, name)
    return sensor


def _stepped(sensor, path, h):
    """The sensor with the leaf at `path` moved by h."""
    if len(path) == 1:
        return dataclasses.replace(sensor, **{path[0]: getattr(sensor, path[0]) + h})
    return dataclasses.replace(sensor, **{path[0]: _stepped(getattr(sensor, path[0]), path[1:], h)})


def _scene(seed=0, frames=3, sky=True):
    """Piecewise-flat depth (one depth per LR block, moving by a block per frame) and textured intensity."""
    rng = np.random.default_rng(seed)
    blocks = rng.uniform(4.0, 30.0, (SMALL.lr_shape[0], SMALL.lr_shape[1] + frames))
    block = np.ones((SMALL.scale, SMALL.scale))
    depth = np.stack([np.kron(blocks[:, t : t + SMALL.lr_shape[1]], block) for t in range(frames)])
    depth = depth + rng.uniform(0, 0.3, depth.shape)  # sub-block relief: no two HR pixels at one depth
    if sky:
        depth[:, :2, :6] = np.inf
    intensity = rng.uniform(0.2, 0.9, depth.shape)
    return depth.astype(np.float32), intensity.astype(np.float32)


@pytest.fixture(scope="module")
def model():
    params, state = jaxsr.init_model(jax.random.key(3), TINY)
    return jaxsr.Model(params, state, TINY)


# --- the draw's surrogate derivative -----------------------------------------------------------------------

def test_pathwise_derivative_of_a_quadratic_has_the_closed_form_mean():
    """d/dlam E[n^2] = 1 + 2 lam (Poisson). "normal" is unbiased for quadratics where it applies (lam >=
    NORMAL_ABOVE); straight-through gives E[2n] = 2 lam, missing the 1."""
    lams = np.array([0.5, 5.0, 40.0], np.float32)
    rates = jnp.repeat(jnp.asarray(lams), 40_000)

    @jax.jit
    def mean_grads():
        counts = sample_poisson(jax.random.key(1), rates)

        def grad(estimator):
            g = jax.grad(lambda r: jnp.sum(poisson_pathwise(counts, r, estimator=estimator) ** 2))(rates)
            return jnp.mean(g.reshape(len(lams), -1), axis=1)
        return grad("normal"), grad("straight-through")

    normal, straight = map(np.asarray, mean_grads())
    tol = 0.03 * (1 + 2 * lams)  # at least 5 standard errors
    np.testing.assert_array_less(np.abs(straight - 2 * lams), tol)
    np.testing.assert_array_less(np.abs(normal - np.where(lams >= NORMAL_ABOVE, 1 + 2 * lams, 2 * lams)), tol)


def test_gradient_option_keeps_the_counts_and_the_default_stops_gradients():
    depth, intensity = _scene()
    key = jax.random.key(0)
    def total(ms, gradient):
        return jnp.sum(jaxsr.simulate_histograms(key, depth, intensity, SMALL, snr=2.0, mean_signal=ms,
                                                 gradient=gradient))

    @jax.jit
    def run():
        draws = [jaxsr.simulate_histograms(key, depth, intensity, SMALL, snr=2.0, gradient=g)
                 for g in (None, "normal", "straight-through")]
        exact = jax.grad(lambda ms: jnp.sum(jaxsr.expected_histograms(depth, intensity, SMALL, snr=2.0,
                                                                      mean_signal=ms)))(14.0)
        return draws, jax.grad(total)(14.0, None), jax.grad(total)(14.0, "straight-through"), exact

    draws, stopped, straight, exact = run()
    np.testing.assert_array_equal(draws[0], draws[1])
    np.testing.assert_array_equal(draws[0], draws[2])
    assert float(stopped) == 0.0
    # straight through, d sum(n) / d mean_signal = d sum(lambda) / d mean_signal exactly
    assert float(straight) == pytest.approx(float(exact), rel=1e-5)
    with pytest.raises(ValueError, match="gradient must be None or one of"):
        jaxsr.simulate_histograms(key, depth, intensity, SMALL, snr=2.0, gradient="gumbel")
    with pytest.raises(ValueError, match="same shape"):
        poisson_pathwise(jnp.ones(3), jnp.ones(4))


@pytest.mark.slow  # about 8 s; experiments/studies/sensor_design.py measures the same on the full pipeline
def test_surrogate_matches_finite_differences_of_the_monte_carlo_mean_with_plenty_of_photons():
    """d/d irf_sigma of E[mean squared centre-of-mass error]: the "normal" surrogate (mean over keys) against a
    central difference of the Monte-Carlo mean (the same keys on both sides). Where no peak can jump (returns at
    bin centres, bright targets, 400 signal photons, SNR 8) they agree; with 14 photons at SNR 1.3 a peak can
    land on a background bin, and a pathwise derivative cannot see those jumps: the documented bias."""
    bins = np.random.default_rng(5).integers(2, 6, SMALL.lr_shape) + 0.5  # bin centres, in bins
    depth = np.kron(bins * SMALL.bin_width, np.ones((SMALL.scale, SMALL.scale))).astype(np.float32)
    intensity = np.full(SMALL.hr_shape, 0.8, np.float32)
    truth = jnp.asarray(depth[:: SMALL.scale, :: SMALL.scale] / SMALL.d_max)
    keys = jax.random.split(jax.random.key(2), 2000)

    def loss(key, sigma, mean_signal, snr, gradient):
        sensor = SMALL.replace(irf_sigma=sigma)
        counts = jaxsr.simulate_histograms(key, depth, intensity, sensor, snr=snr, mean_signal=mean_signal,
                                           gradient=gradient)
        return jnp.mean((jaxsr.centre_of_mass(counts, sensor) - truth) ** 2)

    @jax.jit
    def compare(mean_signal, snr):
        grads = jax.vmap(jax.grad(loss, argnums=1), (0, None, None, None, None))(keys, 0.4, mean_signal, snr, "normal")
        mc = lambda s: jnp.mean(  # noqa: E731
            jax.vmap(loss, (0, None, None, None, None))(keys, s, mean_signal, snr, None)
        )
        h = 0.02
        return jnp.mean(grads), jnp.std(grads) / np.sqrt(len(keys)), (mc(0.4 + h) - mc(0.4 - h)) / (2 * h)

    est, se, fd = map(float, compare(400.0, 8.0))
    assert fd > 0 and est == pytest.approx(fd, rel=0.05, abs=5 * se)
    est, _, fd = map(float, compare(14.0, 1.3))
    assert 0 < est < 0.2 * fd  # wrong peaks dominate the slope here


# --- the composed graph --------------------------------------------------------------------------------------

def _as_float64(tree):
    return jax.tree.map(lambda x: jnp.asarray(x, jnp.float64) if jnp.issubdtype(x.dtype, jnp.floating) else x, tree)


def test_noise_free_gradient_equals_finite_differences(model):
    """key=None: expected_histograms -> centre_of_mass -> network -> Huber loss, float64, every physical input."""
    depth, intensity = _scene(sky=False)
    with jax.enable_x64(True):
        m = _as_float64(model)
        d, i = jnp.asarray(depth, jnp.float64), jnp.asarray(intensity, jnp.float64)
        sensor = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), SMALL)
        direction = jnp.asarray(np.random.default_rng(1).normal(size=depth.shape))

        def f(sensor, snr, mean_signal, d_step, i_step):
            return jaxsr.pipeline_metric(None, d + d_step * direction, i + i_step * 0.1 * direction, sensor, m,
                                         snr=snr, mean_signal=mean_signal, metric="huber")

        args = (sensor, jnp.float64(1.5), jnp.float64(14.0), jnp.float64(0.0), jnp.float64(0.0))
        value_and_grads = jax.jit(jax.value_and_grad(f, argnums=(0, 1, 2, 3, 4)))
        f = lambda *a: value_and_grads(*a)[0]  # noqa: E731  (one compilation for values and gradients)
        grads = value_and_grads(*args)[1]
        h = 1e-6
        for path in LEAVES:
            fd = (f(_stepped(sensor, path, h), *args[1:]) - f(_stepped(sensor, path, -h), *args[1:])) / (2 * h)
            assert float(_leaf(grads[0], path)) == pytest.approx(float(fd), rel=1e-4, abs=1e-9), path
        for k in range(1, 5):
            up, down = list(args), list(args)
            up[k], down[k] = args[k] + h, args[k] - h
            fd = (f(*up) - f(*down)) / (2 * h)
            assert float(grads[k]) == pytest.approx(float(fd), rel=1e-4, abs=1e-9), k
        assert float(grads[0].irf_sigma) != 0 and float(grads[1]) != 0 and float(grads[3]) != 0


def _psnr(model, depth, intensity, sensor, snr, mean_signal):
    """PSNR of one noisy pass (one draw of a fixed key; the Huber loss is checked on the noise-free path)."""
    return jaxsr.pipeline_metric(jax.random.key(4), depth, intensity, sensor, model, snr=snr, mean_signal=mean_signal)


@pytest.fixture(scope="module")
def score_and_grads(model):
    """The score and its gradient with respect to (depth, intensity, sensor, snr, mean_signal), jitted."""
    return jax.jit(jax.value_and_grad(functools.partial(_psnr, model), argnums=(0, 1, 2, 3, 4)))


def test_vmap_over_sensors_equals_a_loop_and_gradients_are_finite_at_the_extremes(score_and_grads):
    """A batch of sensors and photon levels, from the ordinary to the extremes (zero photons, SNR 1e-3: almost
    only background, SNR 1e4: almost none), in a scene with sky (inf depth): vmap equals a loop of single calls,
    and every value and gradient is finite."""
    depth, intensity = _scene()
    cases = [(0.3, 0.05, 1.3, 14.0), (0.7, 0.0, 1.3, 0.0), (1.2, 0.2, 1e-3, 14.0), (0.4, 0.05, 1e4, 14.0)]
    sensors = [SMALL.replace(irf_sigma=s, ambient_floor=a) for s, a, _, _ in cases]
    snrs, levels = (jnp.asarray([c[k] for c in cases], jnp.float32) for k in (2, 3))
    batch = jax.tree.map(lambda *x: jnp.stack(x), *sensors)
    got = jax.vmap(score_and_grads, (None, None, 0, 0, 0))(depth, intensity, batch, snrs, levels)
    assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(got))
    for j, sensor in enumerate(sensors):
        want = score_and_grads(depth, intensity, sensor, snrs[j], levels[j])
        assert float(got[0][j]) == pytest.approx(float(want[0]), rel=1e-5)
        for g_batch, g_one in zip(jax.tree.leaves(got[1]), jax.tree.leaves(want[1])):
            np.testing.assert_allclose(g_batch[j], g_one, rtol=1e-4, atol=1e-6)
    # no photons at all: every pixel is no return, and nothing depends on the sensor or the levels
    assert float(got[1][3][1]) == 0.0 and float(got[1][2].irf_sigma[1]) == 0.0


def test_pipeline_metric_refuses_bad_input(model):
    depth, intensity = _scene()
    key = jax.random.key(0)
    with pytest.raises(ValueError, match=r"sequences \(T, H, W\)"):
        jaxsr.pipeline_metric(key, depth[0], intensity[0], SMALL, model, snr=1.0)
    with pytest.raises(ValueError, match="snr must be finite and > 0"):
        jaxsr.pipeline_metric(key, depth, intensity, SMALL, model, snr=0.0)
    with pytest.raises(ValueError, match=r"pipeline_metric: snr must be a scalar .* shape \(2,\)"):
        jaxsr.pipeline_metric(key, depth, intensity, SMALL, model, snr=np.array([1.0, 2.0]))
    with pytest.raises(ValueError, match="metric must be one of"):
        jaxsr.pipeline_metric(key, depth, intensity, SMALL, model, snr=1.0, metric="ssim")
    with pytest.raises(ValueError, match="gradient must be one of"):
        jaxsr.pipeline_metric(key, depth, intensity, SMALL, model, snr=1.0, gradient=None)
    with pytest.raises(ValueError, match="model must be a jaxsr.Model"):
        jaxsr.pipeline_metric(key, depth, intensity, SMALL, (model.params, model.state), snr=1.0)
    with pytest.raises(ValueError, match="x2 but the sensor's scale is 4"):
        jaxsr.pipeline_metric(key, depth, intensity, jaxsr.Sensor(gate=jaxsr.Gate.spanning(35.0, 8), optics=jaxsr.Optics.of_hr((8, 16), 4)), model,
                              snr=1.0)


def test_traced_out_of_domain_levels_and_sensor_leaves_give_nan(model):
    """Eagerly such values raise (above); traced, the histograms are NaN and the centre of mass would turn them into
    a plausible score: the result is NaN, for the bad elements only of a jitted vmap over levels and IRF widths."""
    depth, intensity = _scene()

    @jax.jit
    @jax.vmap
    def score(snr, mean_signal, irf_sigma):
        sensor = SMALL.replace(irf_sigma=irf_sigma)
        return jaxsr.pipeline_metric(jax.random.key(0), depth, intensity, sensor, model, snr=snr,
                                     mean_signal=mean_signal)

    cases = np.array([(1.0, 10.0, 0.5), (0.0, 10.0, 0.5), (-1.0, 10.0, 0.5), (np.nan, 10.0, 0.5), (np.inf, 10.0, 0.5),
                      (1.0, -5.0, 0.5), (1.0, 10.0, -1.0), (1.0, 10.0, 0.0), (1.0, 10.0, np.nan), (2.0, 3.0, 1.0)],
                     np.float32)
    got = np.asarray(score(*cases.T))
    assert np.isfinite(got[[0, 9]]).all() and np.isnan(got[1:9]).all(), got
