"""One sensor description (`jaxsr.Sensor`): the command's flags, a sensor's TOML file and Python build the same
object; the simulator, the readers and the super-resolution functions take it, jitted and vmapped; depth in metres
goes in and comes out."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsr
from jaxsr import cli
from jaxsr.app import Reading
from jaxsr.config import METRES_PER_SECOND, ModelConfig
from jaxsr.nn import Model, init_model
from jaxsr.sensor.camera import Intrinsics
from jaxsr.sensor.gates import from_network_depth, to_network_depth
from jaxsr.spad import DepthScale, Gate, Optics, Pulse, Sensor, SensorConfig
from jaxsr.training.sensor_file import parse_sensor_file, read_sensor, training_sensor

TINY = dict(base=8, growth=4, head=16, filter_hidden=16)

# a sensor 776 m away: 32 bins of 250 ps from 5180 ns, the network's 0 .. 1 over the gate
TOML = """
[sensor]
bins = 32
bin_width_ps = 250
gate_start_ns = 5180
lr_rows = 32
lr_cols = 64
fov_deg = 30.0
irf_sigma_bins = 0.4
"""
FLAGS = ["upscale", "rec.npz", "-o", "out.npz", "--bins", "32", "--bin-width", "250ps", "--gate-start", "5180ns",
         "--span", "gate"]


def python_sensor():
    gate = Gate(32, 250e-12 * METRES_PER_SECOND, 5180e-9 * METRES_PER_SECOND)
    return Sensor(gate=gate, optics=Optics((32, 64), 4, 30.0), pulse=Pulse(0.4), depth=DepthScale(gate.start,
                                                                                                   gate.length))


def flags_sensor(argv):
    args = cli.build_parser().parse_args(argv)
    return Reading(bins=args.bins, bin_width=args.bin_width, gate_start=args.gate_start, span=args.span,
                   sensor=args.sensor).sensor_for()


def test_flags_toml_and_python_build_the_same_sensor(tmp_path):
    from_toml = parse_sensor_file(TOML, photons=False)[0]
    from_flags = flags_sensor(FLAGS)
    python = python_sensor()
    for got in (from_toml, from_flags):
        assert got.gate.bins == python.gate.bins and got.optics == python.optics and got.pulse == python.pulse
        for leaf, want in zip(jax.tree.leaves(got), jax.tree.leaves(python), strict=True):
            assert leaf == pytest.approx(want, rel=1e-12)
    assert from_toml.gate.start == pytest.approx(776.46, abs=0.01)  # 5180 ns of round trip: c t / 2
    # the file given to --sensor is that sensor too
    (tmp_path / "s.toml").write_text(TOML)
    assert flags_sensor(["upscale", "rec.npz", "-o", "o.npz", "--sensor", str(tmp_path / "s.toml")]) == from_toml
    assert read_sensor(tmp_path / "s.toml") == from_toml
    with pytest.raises(ValueError, match="--sensor gives the gate"):
        Reading(bins=16, sensor=tmp_path / "s.toml")


def test_a_sensor_is_a_pytree_that_jits_vmaps_and_round_trips_as_json():
    sensor = python_sensor()
    leaves, tree = jax.tree.flatten(sensor)
    assert len(leaves) == 8 and jax.tree.unflatten(tree, leaves) == sensor
    assert Sensor.from_dict(sensor.to_dict()) == sensor
    # the optics in OpenCV's terms, as point clouds take them: the HR frame's pinhole, the SPAD frame's 4x coarser
    hr, lr = Intrinsics.of_optics(sensor.optics), Intrinsics.of_optics(sensor.optics, hr=False)
    assert hr.fx == pytest.approx(float(sensor.focal_px)) and lr.scaled(4) == pytest.approx(hr)
    widths = jnp.array([0.5, 1.0, 2.0])
    ends = jax.vmap(lambda w: jax.jit(lambda s: s.d_max)(sensor.replace(gate=Gate(32, w, 10.0))))(widths)
    np.testing.assert_allclose(ends, 10.0 + 32 * widths)
    # a gradient is a Sensor of derivatives, however negative
    grad = jax.grad(lambda s: -s.gate.bin_width - s.r_min)(sensor)
    assert float(grad.gate.bin_width) == -1.0 and float(grad.r_min) == -1.0
    with pytest.raises(ValueError, match="bin_width"):
        Gate(16, -1.0)
    with pytest.raises(TypeError, match="gate is a jaxsr.Gate"):
        Sensor(gate=16)


def test_the_old_flat_sensor_is_a_deprecated_name_for_the_same_sensor():
    with pytest.warns(DeprecationWarning, match="SensorConfig is deprecated"):
        old = SensorConfig(hr_shape=(64, 128), bins=32, d_max=20.0, irf_sigma=0.6)
    assert old == Sensor(gate=Gate.spanning(20.0, 32), optics=Optics((16, 32)), pulse=Pulse(0.6),
                         depth=DepthScale(0.0, 20.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert Sensor() == Sensor(gate=Gate(16, 35.0 / 16), depth=DepthScale(0.0, 35.0))


def test_the_simulator_bins_a_wall_on_a_far_gate():
    """A wall at the centre of bin 5 of a gate starting at 776 m lands in bin 5, and reads back in metres."""
    sensor = python_sensor().replace(optics=Optics((4, 4), 4), irf_sigma=0.2)
    r = sensor.gate.start + 5.5 * sensor.gate.bin_width
    depth = jnp.full(sensor.hr_shape, r)
    rates = jaxsr.expected_histograms(depth, jnp.full(sensor.hr_shape, 0.5), sensor, snr=100.0, mean_signal=50.0)
    assert np.all(np.argmax(np.asarray(rates), axis=-1) == 5)
    norm = jaxsr.centre_of_mass(rates, sensor)
    np.testing.assert_allclose(np.asarray(from_network_depth(norm, sensor.depth)), r, rtol=1e-6)
    # before the gate opens and after it closes: no return, as the gate is what the sensor records
    for outside in (sensor.gate.start - 10.0, sensor.gate.end + 10.0):
        assert np.all(np.asarray(jaxsr.normalise_depth(jnp.full((2, 2), outside), sensor)) == 1.0)


def test_the_super_resolution_functions_take_the_sensor_and_metres():
    cfg = ModelConfig(tr=1, **TINY)
    model = Model(*init_model(jax.random.key(0), cfg), cfg)
    sensor = Sensor(gate=Gate(16, 1.0, 100.0), depth=DepthScale(100.0, 16.0))  # 100-116 m
    metres = np.array(jax.random.uniform(jax.random.key(1), (4, 8, 12), minval=101.0, maxval=115.0))
    metres[0, 0, 0] = np.inf  # no return
    got = jaxsr.super_resolve(model, metres, units="m", sensor=sensor)
    want = np.asarray(from_network_depth(jaxsr.super_resolve(model, to_network_depth(metres, sensor.depth)),
                                         sensor.depth))
    np.testing.assert_allclose(got, want, rtol=1e-6)
    assert np.all((got > 100.0) | np.isinf(got)) and np.all((got < 116.0) | np.isinf(got))
    traced = jax.jit(lambda x: jaxsr.apply_sequence(model, x, units="m", sensor=sensor))(metres)
    np.testing.assert_allclose(np.asarray(traced), got, rtol=1e-5)
    with pytest.raises(ValueError, match="give units='m' with it"):
        jaxsr.super_resolve(model, metres, sensor=sensor)
    with pytest.raises(ValueError, match="units is 'normalised'"):
        jaxsr.super_resolve(model, metres, units="mm")

    # histograms over that gate: the same metres by the host and the traced route
    rates = jaxsr.expected_histograms(jnp.repeat(jnp.repeat(jnp.asarray(metres), 4, 1), 4, 2),
                                      jnp.full((4, 32, 48), 0.5), sensor.replace(optics=Optics((8, 12))),
                                      snr=20.0, mean_signal=40.0)
    counts = np.asarray(jax.random.poisson(jax.random.key(2), rates), np.float32)
    host = jaxsr.super_resolve_histograms(model, counts, sensor, units="m")
    traced = jax.jit(lambda c: jaxsr.apply_histograms(model, c, sensor, units="m"))(counts)
    np.testing.assert_allclose(np.asarray(traced), host, rtol=1e-5)
    finite = np.isfinite(host)
    assert finite.mean() > 0.9 and np.all((host[finite] > 100.0) & (host[finite] < 116.0))
    normalised = jaxsr.super_resolve_histograms(model, counts, sensor)
    np.testing.assert_allclose(np.asarray(from_network_depth(normalised, sensor.depth)), host, rtol=1e-6)


def test_fine_tuning_simulates_the_files_sensor_moved_to_the_scenes_range():
    sensor = parse_sensor_file(TOML, photons=False)[0]
    trained = training_sensor(sensor)
    assert trained.gate == Gate(32, sensor.gate.bin_width, 0.0) and trained.depth == DepthScale(0.0,
                                                                                                sensor.gate.length)
    assert trained.pulse == sensor.pulse and trained.lr_shape == (32, 64) and trained.r_min == sensor.gate.start
