"""experiments/studies/no_return_evidence.py: its detector statistics, pooling, interior and shares on constructed
inputs."""

import jax.numpy as jnp
import no_return_evidence as study  # experiments/studies (pytest's pythonpath)
import numpy as np
import pytest

from jaxsr.config import SensorConfig


def test_excess_is_zero_on_ambient_alone_and_counts_a_peak():
    sensor = SensorConfig()
    flat = jnp.full((sensor.bins,), 5.0)
    peaked = flat.at[7].add(30.0)
    excess = study.statistics(jnp.stack([flat, peaked]), sensor)["excess"]
    assert float(excess[0]) == pytest.approx(0.0, abs=1e-5)
    assert float(excess[1]) == pytest.approx(30.0, abs=1e-4)  # the peak above the bins outside the window
    # a few photons: the median of the bins is 0, the mean outside the window is not
    sparse = jnp.zeros(sensor.bins).at[jnp.array([2, 9, 13])].set(1.0)
    stats = study.statistics(sparse, sensor)
    assert float(stats["excess"]) < float(stats["signal"])


def test_box_sum_is_cut_at_the_edges():
    counts = jnp.arange(2 * 3 * 4 * 1, dtype=jnp.float32).reshape(2, 3, 4, 1)
    got = np.asarray(study.box_sum(counts, 3))
    padded = np.pad(np.asarray(counts), ((0, 0), (1, 1), (1, 1), (0, 0)))
    want = sum(padded[:, dy:dy + 3, dx:dx + 4] for dy in range(3) for dx in range(3))
    np.testing.assert_allclose(got, want)
    np.testing.assert_allclose(np.asarray(study.box_sum(counts, 1)), np.asarray(counts))


def test_interior_needs_a_pure_neighbourhood():
    share = np.zeros((1, 6, 6))
    share[0, :, 3:] = 1.0  # right half without a return
    share[0, 0, 0] = 0.5  # a mixed block in a corner
    inside = study.lr_interior(share)[0]
    assert not inside[:, 2:4].any()  # next to the edge between the halves
    assert inside[2:, 0].all() and inside[:, 4:].all()
    assert not inside[:2, :2].any()  # next to the mixed block


def test_read_as_return_and_rates():
    returns = np.arange(100.0)
    sky = np.array([-1.0, 0.5, 1.5, 50.0])
    assert study.read_as_return(sky, returns, 0.0) == pytest.approx(75.0)  # all but -1 reach the lowest return
    assert study.read_as_return(sky, returns, 2.0) == pytest.approx(25.0)  # threshold 1.98: only 50
    gt = np.array([[1.0, 1.0, 0.3, 0.4]])
    said = np.array([[True, False, True, False]])
    assert study.rates(said, gt) == (50.0, 50.0)
    assert study.rates(said, gt, keep=np.array([[True, True, False, True]])) == (50.0, 0.0)
