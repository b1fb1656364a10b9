"""Inference's `precision` (the convolutions' products: default, float32, bfloat16) and `form` (the temporal form the
network runs in: auto, model, window, sequence): bad values refused with the choices, bfloat16 finite and within its
tolerance of float32, the forms what they say ("auto" the model's choice, from its card, never the recording's
length), and the bundled weights within the measured tolerances on a test scene
(experiments/results/inference_forms.md)."""

import dataclasses
import json

import jax
import numpy as np
import pytest

import jaxsr
from jaxsr import cli
from jaxsr.config import ModelConfig, Optics, Sensor
from jaxsr.app import ModelChoice, Reading, prepare_upscale, upscale, upscale_memory
from jaxsr.inference import (DEFAULT_FORM, DEFAULT_PRECISION, FORM_TOLERANCE_DB, Stream, in_form, iter_super_resolve,
                             measure_form_equivalence, super_resolve, super_resolve_histograms)
from jaxsr.nn import Model, apply_model_sequence, init_model
from jaxsr.runtime import cpu_bfloat16_features

TINY = dict(base=8, growth=4, head=16, filter_hidden=16)
SENSOR = Sensor()
# bfloat16 keeps 8 bits of mantissa: a tiny random network's normalised output moves by up to about 1e-2
BF16_ATOL = 3e-2
# measured on the test sequences (experiments/results/inference_forms.md): bfloat16 within 0.05 dB of float32
BF16_DB = 0.05
# a recording's length, and one frame more: the form "auto" picks depends on neither
FRAMES = 32
# a card's record of the two forms measured equivalent (what `measure_form_equivalence` writes, in short)
MEASURED = {"forms": {"sequence": {"equivalent": True, "psnr_difference_db": 0.0, "measured": "a test's say-so"}}}


def _model(tr, seed=0, **kw):
    cfg = ModelConfig(tr=tr, **TINY, **kw)
    return Model(*init_model(jax.random.key(seed), cfg), cfg)


def _seq(frames, seed=1, shape=(6, 8)):
    return np.asarray(jax.random.uniform(jax.random.key(seed), (frames, *shape)), np.float32)


# --- precision -------------------------------------------------------------------------------------------------


def test_the_defaults_are_the_measured_choices():
    assert DEFAULT_PRECISION == "default" and DEFAULT_FORM == "auto"
    assert FORM_TOLERANCE_DB == 0.1  # TR3 and TR4 within it in the sequence form, edges included; TR0-TR2 not


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
    sensor = Sensor(optics=Optics.of_hr((32, 32)))
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


def _measured(model):
    """`model` as `load_model` gives it from a card that records its two forms measured equivalent."""
    return dataclasses.replace(model, equivalent_forms=("sequence",))


def test_in_form_auto_moves_only_measured_weights():
    tr3, tr4, tr1 = _model(3), _model(4), _model(1)
    for model in (tr3, tr4, tr1, _model(3, inputs=("depth", "signal", "background"))):
        assert in_form(model, "auto") is model  # a user's own weights: the form they were trained in
        assert in_form(model, "auto", frames=FRAMES) is model  # whatever the recording's length
    measured = _measured(tr3)
    for frames in (None, 1, FRAMES - 1, FRAMES):  # the length, where a caller still gives it, changes nothing
        seq = in_form(measured, "auto", frames=frames)
        assert seq.config.temporal == "sequence" and seq.params is tr3.params and seq.equivalent_forms == ("sequence",)
    assert in_form(seq, "auto") is seq  # a sequence-form model stays in it
    assert in_form(tr1, "model") is tr1 and in_form(tr1, "sequence").config.temporal == "sequence"
    seq = in_form(tr3, "sequence")
    assert in_form(seq, "auto") is seq and in_form(seq, "window").config == tr3.config
    assert in_form(tr3, "window") is tr3 and in_form(seq, "window").params is tr3.params
    with pytest.raises(ValueError, match=r"form must be one of 'auto', 'model', 'window', 'sequence', got 'seq'"):
        in_form(tr1, "seq")
    histnet = jaxsr.Model({}, {}, jaxsr.baselines.HistNetConfig(width=2))
    assert in_form(histnet, "auto") is histnet and in_form(histnet, "model") is histnet
    with pytest.raises(ValueError, match="form 'sequence' applies to the DUF network"):
        in_form(histnet, "sequence")


@pytest.mark.slow  # 10 s of TR3 compiles
def test_a_users_own_network_gives_the_same_frames_whatever_the_recordings_length():
    """An untrained TR3 through `jaxsr.super_resolve` (form "auto"): a recording of 31 frames and the same one with
    its last frame held one frame longer give the same 31 frames (the window form's edge replication), not the
    sequence form's on the longer one."""
    model = _model(3)
    short = _seq(FRAMES - 1, seed=5)
    longer = np.concatenate([short, short[-1:]])
    np.testing.assert_array_equal(jaxsr.super_resolve(model, longer)[: FRAMES - 1], jaxsr.super_resolve(model, short))
    np.testing.assert_array_equal(jaxsr.super_resolve(model, short), super_resolve(model, short, form="window"))


@pytest.mark.slow  # 22 s of TR3/TR4 compiles in both forms
def test_whole_arrays_and_streams_run_in_the_form_auto_picks():
    model = _model(3)
    frames = _seq(FRAMES, seed=5)
    seq_form = dataclasses.replace(model.config, temporal="sequence")
    want = np.asarray(apply_model_sequence(model.params, model.state, frames[None], seq_form))[0]
    measured = _measured(model)
    np.testing.assert_allclose(super_resolve(measured, frames), want, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(super_resolve(model, frames, form="sequence"), want, rtol=1e-5, atol=1e-5)
    window = super_resolve(model, frames, form="window")
    assert np.abs(window - want).max() > 1e-3  # random weights: the forms differ
    np.testing.assert_array_equal(super_resolve(model, frames), window)
    np.testing.assert_array_equal(super_resolve(measured, frames, form="model"), window)
    # a stream of frames of unknown length runs in the form the whole recording does
    np.testing.assert_array_equal(np.stack(list(iter_super_resolve(measured, iter(frames), form="auto"))),
                                  super_resolve(measured, frames))
    short = frames[:3]  # as short as a recording gets, in the same form
    np.testing.assert_array_equal(super_resolve(measured, short), super_resolve(model, short, form="sequence"))
    counts = np.asarray(jax.random.poisson(jax.random.key(6), 2.0, (FRAMES, 6, 8, SENSOR.bins)))
    lr = np.asarray(jaxsr.centre_of_mass(counts.astype(np.float32), SENSOR))
    np.testing.assert_allclose(super_resolve_histograms(measured, counts), super_resolve(model, lr, form="sequence"),
                               atol=1e-6)
    with pytest.raises(ValueError, match="super_resolve: form must be one of"):
        super_resolve(model, frames, form="windowed")


def test_the_card_says_whether_auto_may_move_the_weights(tmp_path):
    """Weights whose card records the two forms measured equivalent run in the sequence form under "auto"; the same
    weights saved without the record, or with it saying they are not, in the window form."""
    model = _model(3)
    not_equivalent = {"forms": {"sequence": {"equivalent": False, "psnr_difference_db": -0.4}}}
    for card, forms in ((MEASURED, ("sequence",)), (None, ()), (not_equivalent, ()), ({"forms": "yes"}, ())):
        loaded = jaxsr.load_model(jaxsr.save_model(tmp_path / "tr3.npz", model, card=card))
        assert loaded.equivalent_forms == forms, card
        assert in_form(loaded, "auto").config.temporal == ("sequence" if forms else "window"), card
    seq = jaxsr.load_model(jaxsr.save_model(tmp_path / "tr3.npz", model, card=MEASURED), temporal="sequence")
    assert seq.config.temporal == "sequence" and seq.equivalent_forms == ("sequence",)


def test_measure_form_equivalence_compares_the_forms_on_the_frames_given():
    model = _model(1)
    lr, gt = _seq(9, seed=11), _seq(9, seed=12, shape=(24, 32))
    record = measure_form_equivalence(model, [(lr, gt), (lr[:4], gt[:4])])
    window = super_resolve(model, lr, form="window")
    assert record["psnr_window_db"] == pytest.approx(
        np.mean([np.mean(jaxsr.psnr(np.clip(window, 0, 1), gt)),
                 np.mean(jaxsr.psnr(np.clip(super_resolve(model, lr[:4], form="window"), 0, 1), gt[:4]))]), abs=1e-4)
    assert record["frames"] == [9, 4] and record["scenes"] == 2 and record["tolerance_db"] == FORM_TOLERANCE_DB
    assert record["psnr_difference_db"] == pytest.approx(record["psnr_db"] - record["psnr_window_db"], abs=2e-4)
    assert record["equivalent"] == (abs(record["psnr_difference_db"]) <= FORM_TOLERANCE_DB
                                    and abs(record["edges_difference_db"]) <= FORM_TOLERANCE_DB)
    json.dumps(record)  # a card's entry
    strict = measure_form_equivalence(model, [(lr, gt)], tolerance_db=0.0)
    assert strict["equivalent"] is (strict["psnr_difference_db"] == 0 == strict["edges_difference_db"])
    with pytest.raises(ValueError, match="no scenes given"):
        measure_form_equivalence(model, [])
    with pytest.raises(ValueError, match="compares a network's window form with another of its forms"):
        measure_form_equivalence(model, [(lr, gt)], form="window")


# --- upscale and the command -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tr3_path(tmp_path_factory):
    """A TR3 checkpoint of tiny widths with random weights whose card records the two forms measured equivalent:
    `form="auto"` runs it in the sequence form."""
    path = tmp_path_factory.mktemp("tr3") / "tiny_tr3.npz"
    jaxsr.save_model(path, _model(3), card=MEASURED)
    return path


def test_upscale_says_how_the_network_ran(tr3_path, tmp_path, capsys):
    model_path = tr3_path
    lr = _seq(FRAMES, seed=7, shape=(8, 8))
    job = prepare_upscale(lr, model=model_path, read=Reading(units="normalised"))
    assert job.model.config.temporal == "sequence" and job.precision == "default"
    assert job.note.endswith("model " + str(model_path) + ", sequence form")
    job = prepare_upscale(lr[:3], model=ModelChoice(model_path, precision="bfloat16"), read=Reading(units="normalised"))
    assert job.model.config.temporal == "sequence" and job.note.endswith(", sequence form, precision bfloat16")
    unmeasured = jaxsr.save_model(tmp_path / "unmeasured.npz", jaxsr.load_model(model_path))
    job = prepare_upscale(lr, model=unmeasured, read=Reading(units="normalised"))
    assert job.model.config.temporal == "window" and "sequence form" not in job.note
    auto = upscale(lr, None, model=model_path, read=Reading(units="normalised")).depth
    np.testing.assert_allclose(auto, super_resolve(jaxsr.load_model(model_path), lr, form="sequence"), atol=1e-6)
    window = upscale(lr, None, model=ModelChoice(model_path, form="window"), read=Reading(units="normalised")).depth
    assert np.abs(window - auto).max() > 1e-3
    np.save(tmp_path / "in.npy", lr)
    status = cli.main(["upscale", str(tmp_path / "in.npy"), "-o", str(tmp_path / "out.npy"), "--model", str(model_path),
                       "--units", "normalised", "--precision", "bfloat16", "--form", "window", "--no-progress"])
    captured = capsys.readouterr()
    assert status == 0 and json.loads(captured.out)["frames"] == FRAMES
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
        cli.main(["upscale", str(tmp_path / "in.npy"), "-o", str(tmp_path / "out.npy"), "--model", str(model_path),
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

    return test_clips(FRAMES, names=("scene1_street",))["scene1_street"]


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


@pytest.mark.parametrize("name", ["tr3", "tr4"])
def test_the_bundled_tr3_and_tr4_carry_the_measured_equivalence(name):
    record = jaxsr.read_metadata(jaxsr.io.resolve_model_path(name))["card"]["forms"]["sequence"]
    assert record["equivalent"] is True and abs(record["psnr_difference_db"]) <= record["tolerance_db"]
    assert abs(record["edges_difference_db"]) <= record["tolerance_db"] and "test_clips" in record["measured"]
    model = jaxsr.load_model(name)
    assert model.equivalent_forms == ("sequence",) and in_form(model, "auto").config.temporal == "sequence"


@pytest.mark.slow  # 15 s per bundled model
@pytest.mark.parametrize("name", ["tr3", "tr4"])
def test_bundled_models_auto_picks_keep_their_windowed_psnr(name, scene):
    """`form="auto"` runs them in the sequence form on this 32-frame clip (14 of whose frames are within R of an
    end for TR4), within the measured tolerance of the window form (experiments/results/inference_forms.md on 100
    frames spread over each test scene; their cards' record on the first frames)."""
    model = jaxsr.load_model(name)
    auto, window = super_resolve(model, scene.lr), super_resolve(model, scene.lr, form="window")
    np.testing.assert_array_equal(auto, super_resolve(model, scene.lr, form="sequence"))
    assert abs(_psnr(auto, scene.gt) - _psnr(window, scene.gt)) < FORM_TOLERANCE_DB, name
