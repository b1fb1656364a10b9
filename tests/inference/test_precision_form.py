"""Inference's `precision` (the convolutions' products: default, float32, bfloat16) and `form` (the temporal form the
network runs in: auto, model, window, sequence): bad values refused with the choices, bfloat16 finite and within its
tolerance of float32, the forms what they say, and the bundled weights within the measured tolerances on a test
scene (experiments/results/inference_forms.md)."""

import dataclasses
import json

import jax
import numpy as np
import pytest

import jaxsr
from jaxsr import cli
from jaxsr.config import ModelConfig, SensorConfig
from jaxsr.app import ModelChoice, Reading, prepare_upscale, upscale, upscale_memory
from jaxsr.inference.video import (DEFAULT_FORM, DEFAULT_PRECISION, SEQUENCE_FORM_MIN_FRAMES, SEQUENCE_FORM_TRS,
                                   Stream, in_form, iter_super_resolve, super_resolve, super_resolve_histograms)
from jaxsr.nn import Model, apply_model_sequence, init_model
from jaxsr.runtime import cpu_bfloat16_features

TINY = dict(base=8, growth=4, head=16, filter_hidden=16)
SENSOR = SensorConfig()
# bfloat16 keeps 8 bits of mantissa: a tiny random network's normalised output moves by up to about 1e-2
BF16_ATOL = 3e-2
# measured on the test sequences (experiments/results/inference_forms.md): bfloat16 within 0.05 dB of float32
BF16_DB = 0.05


def _model(tr, seed=0, **kw):
    cfg = ModelConfig(tr=tr, **TINY, **kw)
    return Model(*init_model(jax.random.key(seed), cfg), cfg)


def _seq(frames, seed=1, shape=(6, 8)):
    return np.asarray(jax.random.uniform(jax.random.key(seed), (frames, *shape)), np.float32)


# --- precision -------------------------------------------------------------------------------------------------


def test_the_defaults_are_the_measured_choices():
    assert DEFAULT_PRECISION == "default" and DEFAULT_FORM == "auto"
    assert SEQUENCE_FORM_TRS == (3, 4)  # the TRs within 0.1 dB in the sequence form, edges included


@pytest.mark.parametrize("bad", ["fp16", "bf16", "", None, 16])
def test_an_unknown_precision_is_refused_naming_the_choices(bad):
    model, seq = _model(1), _seq(3)
    choices = r"precision must be one of 'default', 'float32', 'bfloat16'"
    with pytest.raises(ValueError, match="super_resolve: " + choices):
        super_resolve(model, seq, precision=bad)
    with pytest.raises(ValueError, match="super_resolve: " + choices):
        next(iter_super_resolve(model, iter(seq), precision=bad))
    counts = np.ones((2, 6, 8, SENSOR.bins), np.float32)
    with pytest.raises(ValueError, match="super_resolve_histograms: " + choices):
        super_resolve_histograms(model, counts, precision=bad)
    with pytest.raises(ValueError, match="Stream: " + choices):
        Stream(model, precision=bad)
    with pytest.raises(ValueError, match=r"precision \(--precision\) is one of 'default', 'float32', 'bfloat16'"):
        upscale(seq, None, model=ModelChoice(model, precision=bad))


def test_bfloat16_applies_to_the_duf_network_only():
    histnet = jaxsr.Model(jaxsr.baselines.init_histnet(jax.random.key(0), jaxsr.baselines.HistNetConfig(width=2)),
                          {}, jaxsr.baselines.HistNetConfig(width=2))
    counts = np.ones((2, 8, 8, SENSOR.bins), np.float32)
    with pytest.raises(ValueError, match="precision 'bfloat16' applies to the DUF network's convolutions; a histnet"):
        super_resolve_histograms(histnet, counts, intensity=np.ones((2, 32, 32), np.float32), precision="bfloat16")
    with pytest.raises(ValueError, match="Stream: streams the DUF network's sequence form; got a histnet model"):
        Stream(histnet)


@pytest.mark.slow  # 7 s a case; bfloat16 is emulated on most CPUs
@pytest.mark.parametrize("tr,frames,form", [(0, 5, "window"), (1, 7, "window"), (1, 12, "sequence")])
def test_bfloat16_is_finite_and_near_float32(tr, frames, form):
    model, seq = _model(tr), _seq(frames, seed=tr + frames)
    f32 = super_resolve(model, seq, batch_size=4, precision="float32", form=form)
    bf16 = super_resolve(model, seq, batch_size=4, precision="bfloat16", form=form)
    assert bf16.dtype == np.float32 and bf16.shape == f32.shape and np.all(np.isfinite(bf16))
    assert 0 < np.abs(bf16 - f32).max() < BF16_ATOL  # rounded, so not the same, but close
    # "default" is float32's products on CPU
    if jax.default_backend() == "cpu":
        np.testing.assert_allclose(super_resolve(model, seq, batch_size=4, form=form), f32, atol=1e-6)


@pytest.mark.slow  # 15 s; bfloat16 is emulated on most CPUs
def test_bfloat16_reaches_the_stream_and_the_histograms():
    model, seq = _model(1), _seq(6, seed=3)
    want = super_resolve(model, seq, precision="bfloat16", form="sequence")
    stream = Stream(model, precision="bfloat16")
    got = [hr for hr in (stream.push(f) for f in seq) if hr is not None] + stream.flush()
    np.testing.assert_allclose(np.stack(got), want, atol=2e-3)
    counts = np.asarray(jax.random.poisson(jax.random.key(4), 2.0, (4, 6, 8, SENSOR.bins)), np.float32)
    lr = np.asarray(jaxsr.centre_of_mass(counts, SENSOR))
    np.testing.assert_allclose(super_resolve_histograms(model, counts, precision="bfloat16", batch_size=2),
                               super_resolve(model, lr, precision="bfloat16", batch_size=2), atol=1e-6)


@pytest.mark.slow  # 7 s; bfloat16 is emulated on most CPUs
def test_pipeline_metric_takes_a_precision(model_path):
    model = jaxsr.load_model(model_path)
    sensor = SensorConfig(hr_shape=(32, 32))
    depth = np.full((3, 32, 32), 10.0, np.float32)
    intensity = np.full((3, 32, 32), 0.5, np.float32)
    f32 = jaxsr.pipeline_metric(None, depth, intensity, sensor, model, snr=2.0, precision="float32")
    bf16 = jaxsr.pipeline_metric(None, depth, intensity, sensor, model, snr=2.0, precision="bfloat16")
    assert np.isfinite(bf16) and abs(float(bf16) - float(f32)) < 0.5
    with pytest.raises(ValueError, match="pipeline_metric: precision must be one of 'default', 'float32'"):
        jaxsr.pipeline_metric(None, depth, intensity, sensor, model, snr=2.0, precision="half")


def test_cpu_bfloat16_features_reads_the_flags():
    assert cpu_bfloat16_features(["sse2", "avx512f", "avx512_bf16"]) == ("avx512_bf16",)
    assert cpu_bfloat16_features(["sse2", "amx_bf16", "amx_tile", "avx512_bf16"]) == ("avx512_bf16", "amx_bf16")
    assert cpu_bfloat16_features(["sse2", "avx2"]) == () and cpu_bfloat16_features([]) == ()
    assert isinstance(cpu_bfloat16_features(), tuple)  # this host's, whatever it has


# --- form ------------------------------------------------------------------------------------------------------


def test_in_form_follows_the_measured_rule():
    tr3, tr4, tr1 = _model(3), _model(4), _model(1)
    long, short = SEQUENCE_FORM_MIN_FRAMES, SEQUENCE_FORM_MIN_FRAMES - 1
    assert in_form(tr3, "auto", frames=long).config.temporal == "sequence"
    assert in_form(tr4, "auto", frames=long).config.temporal == "sequence"
    assert in_form(tr3, "auto", frames=None).config.temporal == "sequence"  # a stream: long
    assert in_form(tr3, "auto", frames=short) is tr3
    for tr in (0, 1, 2):  # they lose 0.1-0.6 dB in the sequence form
        model = _model(tr)
        assert in_form(model, "auto", frames=long) is model
    photons = _model(3, inputs=("depth", "signal", "background"))
    assert in_form(photons, "auto", frames=long) is photons  # measured on the depth models only
    assert in_form(tr1, "model") is tr1 and in_form(tr1, "sequence").config.temporal == "sequence"
    seq = in_form(tr3, "sequence")
    assert in_form(seq, "auto", frames=1) is seq and in_form(seq, "window").config == tr3.config
    assert in_form(tr3, "window") is tr3 and in_form(seq, "window").params is tr3.params
    with pytest.raises(ValueError, match=r"form must be one of 'auto', 'model', 'window', 'sequence', got 'seq'"):
        in_form(tr1, "seq")
    histnet = jaxsr.Model({}, {}, jaxsr.baselines.HistNetConfig(width=2))
    assert in_form(histnet, "auto") is histnet and in_form(histnet, "model") is histnet
    with pytest.raises(ValueError, match="form 'sequence' applies to the DUF network"):
        in_form(histnet, "sequence")


@pytest.mark.slow  # 22 s of TR3/TR4 compiles in both forms
def test_whole_arrays_run_in_the_form_auto_picks():
    model = _model(3)
    long = _seq(SEQUENCE_FORM_MIN_FRAMES, seed=5)
    seq_form = dataclasses.replace(model.config, temporal="sequence")
    want = np.asarray(apply_model_sequence(model.params, model.state, long[None], seq_form))[0]
    np.testing.assert_allclose(super_resolve(model, long), want, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(super_resolve(model, long, form="sequence"), want, rtol=1e-5, atol=1e-5)
    window = super_resolve(model, long, form="window")
    assert np.abs(window - want).max() > 1e-3  # random weights: the forms differ
    np.testing.assert_array_equal(super_resolve(model, long, form="model"), window)
    short = long[: SEQUENCE_FORM_MIN_FRAMES - 1]
    np.testing.assert_array_equal(super_resolve(model, short), super_resolve(model, short, form="window"))
    # a stream of frames of unknown length keeps the model's form unless asked
    np.testing.assert_array_equal(np.stack(list(iter_super_resolve(model, iter(long)))), window)
    counts = np.asarray(jax.random.poisson(jax.random.key(6), 2.0, (SEQUENCE_FORM_MIN_FRAMES, 6, 8, SENSOR.bins)))
    lr = np.asarray(jaxsr.centre_of_mass(counts.astype(np.float32), SENSOR))
    np.testing.assert_allclose(super_resolve_histograms(model, counts), super_resolve(model, lr, form="sequence"),
                               atol=1e-6)
    with pytest.raises(ValueError, match="super_resolve: form must be one of"):
        super_resolve(model, long, form="windowed")


# --- upscale and the command -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tr3_path(tmp_path_factory):
    """A TR3 checkpoint of tiny widths with random weights: a TR that `form="auto"` runs in the sequence form."""
    path = tmp_path_factory.mktemp("tr3") / "tiny_tr3.npz"
    jaxsr.save_model(path, _model(3))
    return path


def test_upscale_says_how_the_network_ran(tr3_path, tmp_path, capsys):
    model_path = tr3_path
    lr = _seq(SEQUENCE_FORM_MIN_FRAMES, seed=7, shape=(8, 8))
    job = prepare_upscale(lr, model=model_path, read=Reading(units="normalised"))
    assert job.model.config.temporal == "sequence" and job.precision == "default"
    assert job.note.endswith("model " + str(model_path) + ", sequence form")
    job = prepare_upscale(lr[:3], model=ModelChoice(model_path, precision="bfloat16"), read=Reading(units="normalised"))
    assert job.model.config.temporal == "window" and job.note.endswith(", precision bfloat16")
    auto = upscale(lr, None, model=model_path, read=Reading(units="normalised")).depth
    np.testing.assert_allclose(auto, super_resolve(jaxsr.load_model(model_path), lr, form="sequence"), atol=1e-6)
    window = upscale(lr, None, model=ModelChoice(model_path, form="window"), read=Reading(units="normalised")).depth
    assert np.abs(window - auto).max() > 1e-3
    np.save(tmp_path / "in.npy", lr)
    status = cli.main(["upscale", str(tmp_path / "in.npy"), str(tmp_path / "out.npy"), "--model", str(model_path),
                       "--units", "normalised", "--precision", "bfloat16", "--form", "window", "--no-progress"])
    captured = capsys.readouterr()
    assert status == 0 and json.loads(captured.out)["frames"] == SEQUENCE_FORM_MIN_FRAMES
    assert "precision bfloat16" in captured.err and "sequence form" not in captured.err
    out = np.load(tmp_path / "out.npy")
    assert np.all(np.isfinite(out)) and np.abs(out - np.clip(window, 0, 1)).max() < BF16_ATOL


def test_the_memory_estimate_counts_the_sequence_forms_shared_frames(tr3_path):
    """A window-form output holds its window's 2 TR + 1 frames of features; a sequence-form chunk of B outputs
    holds B + 2R frames for all of them, fewer per output once B > 2R / (2 TR)."""
    lr = _seq(40, seed=8, shape=(8, 8))
    seq = prepare_upscale(lr, model=tr3_path, read=Reading(units="normalised"))
    win = prepare_upscale(lr, model=ModelChoice(tr3_path, form="window"), read=Reading(units="normalised"))
    assert seq.model.config.temporal == "sequence" and win.model.config.temporal == "window"
    assert upscale_memory(seq, batch_size=32, in_memory=False) < upscale_memory(win, batch_size=32, in_memory=False)


@pytest.mark.parametrize("option,bad", [("--precision", "half"), ("--form", "windowed")])
def test_the_command_refuses_an_unknown_choice(option, bad, model_path, tmp_path, capsys):
    np.save(tmp_path / "in.npy", _seq(2, shape=(8, 8)))
    with pytest.raises(SystemExit) as stop:
        cli.main(["upscale", str(tmp_path / "in.npy"), str(tmp_path / "out.npy"), "--model", str(model_path),
                  option, bad])
    assert stop.value.code == 2
    assert f"argument {option}: invalid choice: '{bad}'" in capsys.readouterr().err
    assert not (tmp_path / "out.npy").exists()


def test_upscale_refuses_a_form_or_precision_the_model_cannot_take(tmp_path):
    with pytest.raises(ValueError, match=r"form \(--form\) is one of 'auto', 'model', 'window', 'sequence'"):
        upscale(_seq(2, shape=(8, 8)), None, model=ModelChoice(_model(1), form="both"))


# --- the bundled weights on a test scene ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def scene():
    from harness.scoring import test_clips

    return test_clips(SEQUENCE_FORM_MIN_FRAMES, names=("scene1_street",))["scene1_street"]


def _psnr(sr, gt):
    return float(np.mean(jaxsr.psnr(np.clip(sr, 0, 1), gt)))


@pytest.mark.slow  # 7-25 s per model; bfloat16 is emulated on most CPUs
@pytest.mark.parametrize("name", ["tr0", "tr4"])
def test_bundled_models_in_bfloat16_stay_within_their_tolerance(name, scene):
    model = jaxsr.load_model(name)
    for form in ("window", "sequence"):
        f32 = super_resolve(model, scene.lr, precision="float32", form=form)
        bf16 = super_resolve(model, scene.lr, precision="bfloat16", form=form)
        assert np.all(np.isfinite(bf16))
        assert abs(_psnr(bf16, scene.gt) - _psnr(f32, scene.gt)) < BF16_DB, (name, form)


# measured on the test sequences (experiments/results/inference_forms.md): TR3 and TR4 within 0.1 dB of their
# windowed PSNR in the sequence form, the first and last R frames included
FORM_DB = 0.1


@pytest.mark.slow  # 15 s per bundled model
@pytest.mark.parametrize("name", ["tr3", "tr4"])
def test_bundled_models_auto_picks_keep_their_windowed_psnr(name, scene):
    """`form="auto"` runs them in the sequence form on this 32-frame clip (14 of whose frames are within R of an
    end for TR4), within the measured tolerance of the window form."""
    model = jaxsr.load_model(name)
    auto, window = super_resolve(model, scene.lr), super_resolve(model, scene.lr, form="window")
    np.testing.assert_array_equal(auto, super_resolve(model, scene.lr, form="sequence"))
    assert abs(_psnr(auto, scene.gt) - _psnr(window, scene.gt)) < FORM_DB, name
