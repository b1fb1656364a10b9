"""Throughput of the sensor model and depth extraction: LR frames per second.

Run: pytest benchmarks/bench_sensor.py --benchmark-enable
"""

import jax
import jax.numpy as jnp
import pytest

import jaxsr

SENSOR = jaxsr.Sensor()


def scene_batch(n_frames):
    k1, k2 = jax.random.split(jax.random.key(0))
    depth = jax.random.uniform(k1, (n_frames,) + SENSOR.hr_shape, minval=1.0, maxval=40.0)
    intensity = jax.random.uniform(k2, (n_frames,) + SENSOR.hr_shape)
    return depth, intensity


@pytest.mark.parametrize("sampler", ["fast", "exact"])
@pytest.mark.parametrize("n_frames", [64])
def test_simulate_and_centre_of_mass(timed, n_frames, sampler):
    depth, intensity = scene_batch(n_frames)

    @jax.jit
    def lr_frames(key, d, i):
        counts = jaxsr.simulate_histograms(key, d, i, SENSOR, snr=1.3, sampler=sampler)
        return jaxsr.centre_of_mass(counts, SENSOR)

    timed(lr_frames, jax.random.key(1), depth, intensity, items=n_frames)


@pytest.mark.parametrize("stage", ["rates", "poisson", "centre_of_mass"])
def test_stages(timed, stage):
    n = 64
    depth, intensity = scene_batch(n)
    rates = jaxsr.expected_histograms(depth, intensity, SENSOR, snr=1.3)
    counts = jaxsr.sensor.sample_poisson(jax.random.key(2), rates)
    fn, args = {
        "rates": (jax.jit(lambda d, i: jaxsr.expected_histograms(d, i, SENSOR, snr=1.3)), (depth, intensity)),
        "poisson": (jax.jit(jaxsr.sensor.sample_poisson), (jax.random.key(3), rates)),
        "centre_of_mass": (jax.jit(lambda c: jaxsr.centre_of_mass(c, SENSOR)), (counts,)),
    }[stage]
    timed(fn, *args, items=n)


def test_bicubic(timed):
    lr = jnp.zeros((64,) + SENSOR.lr_shape)
    timed(jax.jit(lambda x: jaxsr.bicubic(x, scale=4)), lr, items=64)
