"""`apply_sequence` / `apply_histograms`: super-resolution as a traced function of arrays, inside a user's
jax.jit, jax.vmap and jax.grad, equal to the host-side functions; the host-side functions refuse tracing in the
project's words."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsr
from jaxsr.config import ModelConfig, Sensor
from jaxsr.nn import Model, init_model

TINY = dict(base=8, growth=4, head=16, filter_hidden=16)


def model(tr=1, **kw):
    cfg = ModelConfig(tr=tr, **TINY, **kw)
    return Model(*init_model(jax.random.key(tr), cfg), cfg)


def lr_seq(t=5, seed=0):
    return np.asarray(jax.random.uniform(jax.random.key(seed), (t, 8, 12), minval=0.1, maxval=0.9))


@pytest.mark.parametrize("temporal", ["window", "sequence"])
def test_jit_equals_super_resolve_and_vmap_maps_sequences(temporal):
    m, lr = model(temporal=temporal), lr_seq()
    traced = jax.jit(jaxsr.apply_sequence)(m, lr)
    np.testing.assert_allclose(np.asarray(traced), jaxsr.super_resolve(m, lr), atol=1e-5)
    both = jax.vmap(jaxsr.apply_sequence, in_axes=(None, 0))(m, np.stack([lr, lr[::-1]]))
    np.testing.assert_allclose(np.asarray(both[1]), jaxsr.super_resolve(m, lr[::-1]), atol=1e-5)


@pytest.mark.slow  # about 20 s on 2 cores: a backward pass through TR1 compiled twice
def test_grad_through_the_network_is_finite_and_nan_is_no_return():
    m, lr = model(), lr_seq()
    gt = jnp.full((5, 32, 48), 0.5)
    grad = jax.grad(lambda x: jnp.mean((jaxsr.apply_sequence(m, x) - gt) ** 2))(lr)
    assert grad.shape == lr.shape and np.all(np.isfinite(grad)) and np.abs(grad).max() > 0
    with_nan = lr.copy()
    with_nan[0, 0, 0] = np.nan
    ones = lr.copy()
    ones[0, 0, 0] = 1.0
    np.testing.assert_allclose(np.asarray(jaxsr.apply_sequence(m, with_nan)),
                               np.asarray(jaxsr.apply_sequence(m, ones)), atol=1e-6)


@pytest.mark.slow  # about 19 s on 2 cores
def test_histograms_equal_super_resolve_histograms_and_differentiate_to_the_counts():
    cfg = ModelConfig(tr=0, inputs=("depth", "signal", "background"), no_return_head=True, **TINY)
    m = Model(*init_model(jax.random.key(3), cfg), cfg)
    counts = np.asarray(jax.random.poisson(jax.random.key(1), 2.0, (3, 8, 12, 16)), np.float32)
    sensor = Sensor()
    traced = jax.jit(jaxsr.apply_histograms)(m, counts, sensor)
    np.testing.assert_allclose(np.asarray(traced), jaxsr.super_resolve_histograms(m, counts, sensor), atol=1e-5)
    grad = jax.grad(lambda c: jnp.mean(jaxsr.apply_histograms(m, c, sensor)))(counts)
    assert grad.shape == counts.shape and np.all(np.isfinite(grad))


def test_host_side_functions_refuse_tracing_naming_the_traced_route():
    m, lr = model(), lr_seq()
    with pytest.raises(TypeError, match=r"super_resolve runs on the host .* use jaxsr.apply_sequence"):
        jax.jit(lambda x: jaxsr.super_resolve(m, x))(lr)
    with pytest.raises(TypeError, match=r"super_resolve_histograms runs on the host .* jaxsr.apply_histograms"):
        jax.jit(lambda c: jaxsr.super_resolve_histograms(m, c))(np.ones((2, 8, 12, 16), np.float32))
    with pytest.raises(TypeError, match="runs on the host"):
        jax.jit(lambda x: jaxsr.inference.Stream(m).push(x))(lr[0])
    with pytest.raises(ValueError, match=r"expected an LR sequence \(T, h, w\)"):
        jaxsr.apply_sequence(m, lr[0])


def test_the_host_side_functions_refuse_what_they_cannot_mean():
    """Complex input is refused (the imaginary part was dropped); a batch larger than the frames is cut to them (3
    frames padded to a batch of 10^9 allocated 238 GiB); a dict as the sensor is a TypeError naming Sensor."""
    m, lr = model(), lr_seq(3)
    with pytest.raises(ValueError, match="complex values"):
        jaxsr.super_resolve(m, lr + 0j)
    with pytest.raises(ValueError, match="complex values"):
        jaxsr.super_resolve_histograms(m, np.ones((2, 8, 12, 16), np.complex64))
    with pytest.raises(ValueError, match="complex values"):
        jaxsr.inference.Stream(m).push(lr[0] + 0j)
    np.testing.assert_allclose(jaxsr.super_resolve(m, lr, batch_size=10**9), jaxsr.super_resolve(m, lr), atol=1e-5)
    with pytest.raises(ValueError, match="batch_size must be an integer >= 1"):
        jaxsr.super_resolve(m, lr, batch_size=2.5)
    with pytest.raises(TypeError, match="sensor is a jaxsr.Sensor"):
        jaxsr.super_resolve_histograms(m, np.ones((2, 8, 12, 16)), {"bins": 16})
