"""`jaxsr upscale` with another sensor: other frame sizes, histograms over a gate, photon time tags;
each output checked against the library pipeline it should equal."""

import json

import jax
import numpy as np
import pytest

from jaxsr import cli
from jaxsr.io.checkpoint import load_model, save_model
from jaxsr.config import DepthScale, Gate, ModelConfig
from jaxsr.sensor.gates import data_span, from_network_depth, gate_depth, gate_warnings, to_network_depth
from jaxsr.inference import super_resolve
from jaxsr.nn import Model, init_model
from jaxsr.sensor.timetags import histogram_time_tags, read_time_tags

TINY = dict(base=8, growth=4, head=16, filter_hidden=16)


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    cfg = ModelConfig(tr=1, **TINY)
    path = tmp_path_factory.mktemp("model") / "tiny.npz"
    save_model(path, Model(*init_model(jax.random.key(0), cfg), cfg), card={"data": "none: random weights"})
    return path


def upscale(*args):
    return cli.main(["upscale", str(args[0]), "-o", *map(str, args[1:]), "--no-progress"])


def test_depth_of_another_size(tmp_path, model_path):
    lr = np.random.default_rng(0).uniform(0, 1, (2, 48, 80)).astype(np.float32)
    np.save(tmp_path / "in.npy", lr)
    assert upscale(tmp_path / "in.npy", tmp_path / "out.npy", "--model", model_path) == 0
    out = np.load(tmp_path / "out.npy")
    assert out.shape == (2, 192, 320)
    np.testing.assert_allclose(out, np.clip(super_resolve(load_model(model_path), lr), 0, 1), atol=1e-6)


@pytest.mark.slow  # about 10 s: keeps the default suite under 8 minutes on 2 cores
def test_time_tags_over_a_gate_far_away(tmp_path, model_path, capsys):
    """A 12 x 20 table of time tags (ns) of a slanted wall 1.5 km away, gate given in time: the output in metres
    equals histogram -> gate_depth -> the network at offset = gate start, span 35 m -> metres."""
    rng = np.random.default_rng(2)
    h, w = 12, 20
    truth = 1500.0 + np.linspace(5, 25, w)[None, :].repeat(h, 0)           # metres
    per_pixel = rng.poisson(20, h * w)
    pixel = np.repeat(np.arange(h * w), per_pixel)
    t_ns = truth.ravel()[pixel] / 0.149896229 + rng.normal(0, 5.8, pixel.size)  # IRF sigma 0.4 bins
    noise = rng.integers(0, h * w, 2000)
    pixel = np.concatenate([pixel, noise])
    t_ns = np.concatenate([t_ns, rng.uniform(10007, 10230, noise.size)])
    np.savez(tmp_path / "tags.npz", pixel=pixel, time=t_ns, shape=np.array([h, w]), time_unit_s=1e-9)
    args = ["--kind", "timetags", "--bins", "16", "--bin-width", "14.5ns", "--gate-start", "10.007us"]
    assert upscale(tmp_path / "tags.npz", tmp_path / "out.npz", "--model", model_path, *args) == 0
    captured = capsys.readouterr()
    assert "warning" not in captured.err  # a 35 m gate on the span fitted to the wall
    summary = json.loads(captured.out)
    gate = Gate.from_time(16, 14.5e-9, 10.007e-6)
    counts = histogram_time_tags(read_time_tags(tmp_path / "tags.npz"), gate)
    lr_m = np.asarray(gate_depth(counts, gate))
    span = data_span(lr_m, gate)  # 16 bins: never coarser than the trained 1/16 of the span, the whole gate
    assert summary["gate"]["start_m"] == pytest.approx(gate.start) and summary["scale"]["span_m"] == pytest.approx(span)
    assert span == pytest.approx(gate.length)
    assert np.median(np.abs(lr_m - truth)) < 0.25 * gate.bin_width  # the centre of mass finds the wall
    scale = DepthScale.for_gate(gate, span)
    want = from_network_depth(super_resolve(load_model(model_path), to_network_depth(lr_m, scale)), scale)
    got = np.load(tmp_path / "out.npz")["depth"]
    assert got.shape == (1, 48, 80)
    np.testing.assert_allclose(got, want, rtol=1e-6)


def test_a_span_that_cuts_the_returns_warns(tmp_path, model_path, capsys):
    """Returns spread over a 128 m gate, the span given as 35 m: most of them read as no return, and the warning
    says how many; left to its default the span covers them and nothing is said."""
    counts = np.random.default_rng(3).poisson(1.0, (1, 8, 8, 32)).astype(np.uint16)
    np.save(tmp_path / "h.npy", counts)
    gate = ["--bins", "32", "--bin-width", "4m"]
    assert upscale(tmp_path / "h.npy", tmp_path / "o.npy", "--model", model_path, *gate, "--span", "35") == 0
    err = capsys.readouterr().err
    assert "of the returns in the first frames lie outside the depth scale's [0, 35) m" in err
    assert "coarser" not in err
    assert upscale(tmp_path / "h.npy", tmp_path / "o2.npy", "--model", model_path, *gate) == 0
    assert "warning" not in capsys.readouterr().err


def test_data_span():
    gate = Gate(200, 0.0375, 1.0)  # 7.5 m from 1 m
    depth = 1.0 + np.linspace(0.5, 4.5, 1000)
    assert data_span(np.append(depth, np.inf), gate) == pytest.approx(np.percentile(depth - 1.0, 99) * 1.1)
    assert data_span(np.full(10, 1.01), gate) == pytest.approx(16 * 0.0375)  # at least 16 bins
    assert data_span(np.full(10, 8.4), gate) == pytest.approx(7.5)  # at most the gate
    assert data_span(np.array([np.inf]), gate) == pytest.approx(7.5)  # no return seen: the gate


def test_the_span_warnings_say_what_the_returns_show():
    """A short-range scene (1.5-6 m) in a 7.5 m gate: the gate's own length and the fitted span draw no warning
    about the span; the trained 35 m does (its depth steps look 5x smaller to the network)."""
    gate = Gate(200, 0.0375, 0.0)
    returns = np.random.default_rng(0).uniform(1.5, 6.0, 5000)
    assert gate_warnings(gate, DepthScale.for_gate(gate, data_span(returns, gate)), returns=returns) == []
    assert gate_warnings(gate, DepthScale.for_gate(gate, gate.length), returns=returns) == []
    (line,) = gate_warnings(gate, DepthScale.for_gate(gate, 35.0), returns=returns)
    assert "fit a depth span of 6.5" in line and "leave --span out" in line


def test_the_fitted_span_is_the_sensor_the_network_reads_with(model_path):
    """A wall 3-6 m away in a 35 m gate of 128 bins: the job's depth scale spans the metres data_span fits (not the
    trained 35 m), and the network's input is the centre of mass on that scale, the scale the output's metres and
    the confidence's bins read too. A sensor file's own depth scale is kept as given."""
    from jaxsr import Sensor
    from jaxsr.app import prepare_upscale
    from jaxsr.app.specs import Reading

    gate = Gate(128, 35.0 / 128, 0.0)
    rng = np.random.default_rng(5)
    wall = np.linspace(3.0, 6.0, 16)[None, None, :].repeat(8, 1)  # (1, 8, 16) metres
    peak = (wall / gate.bin_width).astype(int)[..., None] == np.arange(128)
    counts = rng.poisson(0.02 + 20.0 * peak, (2, 8, 16, 128)).astype(np.uint16)
    job = prepare_upscale(counts, model=model_path, read=Reading(kind="histograms", bins=128, bin_width=gate.bin_width))
    lr_m = np.asarray(gate_depth(counts[0], gate))
    span = data_span(lr_m, gate)
    assert span < 10.0 and float(job.scale.span) == pytest.approx(span)
    np.testing.assert_allclose(next(job.lr_frames()), to_network_depth(lr_m, job.scale), atol=1e-6)
    own = Sensor(gate=gate, depth=DepthScale(0.0, 35.0))
    job = prepare_upscale(counts, model=model_path, read=Reading(kind="histograms", sensor=own))
    assert float(job.scale.span) == 35.0
    # the span warning's advice fits what was given: --span is not the way under --sensor
    (line,) = [w for w in job.warnings if "fit a depth span" in w]
    assert "sensor file" in line and "leave --span out to fit it" in line and "in place of --sensor" in line
