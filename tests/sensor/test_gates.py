"""Histograms over any gate (jaxsr.sensor.gates): range on the gate's grid, the explicit metres <-> network scale, and
the warnings for what the models never saw."""

import jax
import numpy as np
import pytest

from jaxsr.config import METRES_PER_SECOND, DepthScale, Gate, Sensor
from jaxsr.sensor.gates import from_network_depth, gate_depth, gate_warnings, to_network_depth
from jaxsr.sensor.peaks import centre_of_mass
from jaxsr.sensor.forward import irf_bin_weights, normalise_depth

# Jitted (the gate is a pytree, its bin count static): one compilation per shape instead of op-by-op dispatch.
gate_depth_jit = jax.jit(gate_depth, static_argnames=("window", "return_mask"))


def synthetic_histogram(range_m, gate, *, signal=500.0, background=2.0):
    """Noise-free counts of one surface at `range_m` over `gate` (Gaussian IRF of sigma 0.4 bins,
    docs/sensor-model.md)."""
    tau = (range_m - gate.start) / gate.bin_width
    h = np.asarray(irf_bin_weights(np.float32(tau), Sensor(gate=Gate.spanning(35.0, gate.bins))))
    return (signal * h + background).astype(np.float32)


GATES = [Gate(32, 0.15, 9790.0),                # a 4.8 m gate 9.79 km away
         Gate.from_time(32, 250e-12, 5.18e-6)]  # 32 bins of 250 ps from 5.18 us


def test_a_gate_not_starting_at_zero_gives_the_right_range():
    """Targets at known ranges inside a gate far from 0 m are found there (the tolerance, 0.05 bins, is 5x the
    centre of mass's systematic error of about 0.01 bins RMS), and not at the range the default gate would give."""
    fracs = np.array([0.31, 0.5, 0.77, 0.123])
    for gate in GATES:
        r = gate.start + fracs * gate.length
        counts = np.stack([synthetic_histogram(x, gate) for x in r])
        got = np.asarray(gate_depth_jit(counts, gate))
        np.testing.assert_array_less(np.abs(got - r), 0.05 * gate.bin_width)


def test_gate_from_time_uses_the_round_trip():
    gate = Gate.from_time(16, 1e-9, 2e-6)
    assert gate.bin_width == pytest.approx(0.1498962, rel=1e-6)  # c * 1 ns / 2
    assert gate.start == pytest.approx(2e-6 * METRES_PER_SECOND) and gate.end == gate.start + 16 * gate.bin_width


def test_default_gate_is_the_paper_sensor():
    """With the paper's gate and scale, metres and normalised depth are the existing convention."""
    rng = np.random.default_rng(0)
    counts = rng.poisson(2.0, (4, 16)).astype(np.float32)
    counts[0] = 0  # no return
    gate = Gate.of_sensor(Sensor())
    com = np.asarray(jax.jit(centre_of_mass)(counts))
    np.testing.assert_allclose(gate_depth_jit(counts, gate), np.where(com < 1, com * 35.0, np.inf), rtol=1e-6)
    d = np.array([0.0, 3.0, 34.9, 35.0, 40.0, np.inf, np.nan], np.float32)
    np.testing.assert_array_equal(to_network_depth(d), normalise_depth(d))


def test_scale_round_trip_and_no_return():
    scale = DepthScale(offset=9790.0, span=35.0)
    r = np.array([9790.0, 9800.5, 9824.9], np.float64)
    np.testing.assert_allclose(from_network_depth(to_network_depth(r, scale), scale), r, rtol=1e-6)
    n = to_network_depth(np.array([np.inf, np.nan, 9826.0, 9700.0]), scale)
    np.testing.assert_array_equal(n, [1.0, 1.0, 1.0, 0.0])  # no return, no return, beyond the span, before it
    assert np.isinf(from_network_depth(np.array([1.0, 1.2, np.nan]), scale)).all()


def test_empty_histogram_is_no_return():
    gate = Gate(8, 1.0, 100.0)
    depth, valid = gate_depth_jit(np.zeros((4, 8), np.float32), gate, return_mask=True)
    assert np.isinf(depth).all() and not valid.any()


def test_warnings_say_what_the_models_never_saw():
    assert gate_warnings(Gate(), DepthScale()) == []
    gate = Gate(16, 2.0, 1000.0)  # 32 m from 1 km: inside the trained span once offset to the gate
    assert gate_warnings(gate, DepthScale.for_gate(gate)) == []
    long = Gate(16, 10.0, 0.0)  # 160 m
    said = " ".join(gate_warnings(long, DepthScale.for_gate(long)))
    assert "extends past" in said and "no return" in said and "coarser" in said
    # a span far from the trained 35 m is no fault in itself: the gate's own length draws no warning
    assert gate_warnings(long, DepthScale.for_gate(long, span=long.length)) == []
    fine = Gate(160, 1.0, 0.0)  # 160 m in 1 m bins
    near = np.linspace(2.0, 20.0, 500)  # but returns within 20 m of a 160 m span look 7x flatter than fitted
    assert gate_warnings(fine, DepthScale.for_gate(fine, span=fine.length), returns=np.full(9, 150.0)) == []
    (line,) = gate_warnings(fine, DepthScale.for_gate(fine, span=fine.length), returns=near)
    assert "fit a depth span of 21.8 m" in line and "7.34x smaller" in line
    with pytest.raises(ValueError, match="lies outside the depth scale"):
        gate_warnings(gate, DepthScale())  # a gate at 1 km read with the network's 0 at 0 m


@pytest.mark.parametrize("make,match", [(lambda: Gate(1, 1.0, 0.0), "bins"), (lambda: Gate(8, 0.0, 0.0), "bin_width"),
                                        (lambda: Gate(8, 1.0, float("nan")), "start"),
                                        (lambda: DepthScale(0.0, -1.0), "span")])
def test_bad_gates_are_refused(make, match):
    with pytest.raises(ValueError, match=match):
        make()
