"""Fine-tuning to a sensor file (`jaxsr finetune`, `jaxsr.training.finetune`, `jaxsr.training.read_sensor_file`):
the TOML reader (a good file, every bad key and value refused by name, the IRF fit recovering a known width),
the wiring from the file to `fit` (fast, with `fit` and the validation stubbed), a run folder as a model, and
one tiny run end to end (slow: compiling the rendered data and the train step takes a minute on 2 cores)."""

import dataclasses
import json

import jax
import numpy as np
import pytest
from hostile_files import claim_terabytes

import jaxsr
from jaxsr import cli
from jaxsr.config import PRESETS, PhotonRegime
from jaxsr.io.checkpoint import resolve_model_path, save_model
from jaxsr.nn import init_model
from jaxsr.nn.model import Model
from jaxsr.training import fit_irf, parse_sensor_file, read_irf_file, read_sensor_file, training_sensor
from jaxsr.training import sensor_file as sf


GOOD = """
description = "a test sensor"

[sensor]
bins = 32
bin_width_ps = 250           # 3.747 cm of range
gate_start_m = 120.0
lr_rows = 24
lr_cols = 40
fov_deg = 20.0
irf_sigma_bins = 0.8

[photons]
signal_range = [2.0, 8.0]
snr_range = [1.0, 10.0]
no_return_prob = 0.2
thin_prob = 0.5
dark_prob = 0.0
motion = "drawn"
"""

TINY_TOML = """
[sensor]
bins = 16
bin_width_m = 2.0
lr_rows = 8
lr_cols = 8
irf_sigma_bins = 0.5

[photons]
signal_range = [2.0, 8.0]
snr_range = [5.0, 20.0]
"""

# a tiny network, so that a run compiles and trains in seconds
TINY = jaxsr.ModelConfig(tr=0, base=8, growth=4, head=16, filter_hidden=16)


def test_a_good_file_gives_the_sensor_the_regime_and_the_gate():
    sensor, regime, info = parse_sensor_file(GOOD, source="good.toml")
    bin_width = 250e-12 * jaxsr.config.METRES_PER_SECOND
    assert sensor.bins == 32 and sensor.scale == 4 and sensor.lr_shape == (24, 40) and sensor.fov_deg == 20.0
    assert sensor.gate == jaxsr.Gate(32, pytest.approx(bin_width), 120.0) and sensor.irf_sigma == 0.8
    assert sensor.depth == jaxsr.DepthScale(120.0, pytest.approx(32 * bin_width))  # the network's 0 .. 1: the gate
    trained = training_sensor(sensor)  # what fine-tuning simulates: the gate from 0 m, the file's pulse
    assert trained.hr_shape == (96, 160) and trained.d_max == pytest.approx(32 * bin_width)
    assert trained.r_min == 120.0  # the inverse-square law seen from the gate's start
    assert trained.irf_sigma == 0.8  # read out (the centre of mass's window) as jaxsr upscale --sensor reads
    assert regime.signal_range == (2.0, 8.0) and regime.snr_range == (1.0, 10.0)
    assert regime.no_return_prob == 0.2 and regime.dark_prob == 0.0 and regime.motion == "drawn"
    assert regime.thin_prob == 0.5 and regime.thin_lines_max == PhotonRegime().thin_lines_max
    assert regime.hot_prob == PhotonRegime().hot_prob  # unset keys: the wide regime's
    assert regime.irf_paper == regime.irf_sigma_range[0] == regime.irf_sigma_range[1] == 0.8
    assert regime.irf_paper_prob == 1.0  # every clip with the sensor's pulse
    assert info["gate"] == {"bins": 32, "bin_width_m": pytest.approx(bin_width), "start_m": 120.0,
                            "span_m": pytest.approx(32 * bin_width)}
    assert info["upscale_options"] == "--bins 32 --bin-width 0.25ns --gate-start 120m --span gate"
    assert info["description"] == "a test sensor" and info["text"] == GOOD
    assert info["lr_shape"] == info["render_lr_shape"] == [24, 40]
    json.dumps(info)  # it goes into the training card
    # the gate's span is outside the scenes' depths: said, not refused
    assert any("gate spans" in w for w in info["warnings"])


def test_a_sensor_file_sets_static_clips():
    _, regime, _ = parse_sensor_file(GOOD + "static_prob = 0.25\n", source="good.toml")
    assert regime.static_prob == 0.25 and regime.thin_prob == 0.5
    with pytest.raises(ValueError, match="static_prob"):
        parse_sensor_file(GOOD + "static_prob = 2.0\n", source="good.toml")


def test_defaults_and_a_large_sensor_rendered_as_a_window():
    text = GOOD.replace("fov_deg = 20.0\n", "").replace("lr_rows = 24", "lr_rows = 300").replace(
        "lr_cols = 40", "lr_cols = 512").replace("bin_width_ps = 250  ", "bin_width_m = 2.0").replace(
        "gate_start_m = 120.0\n", "")
    sensor, _, info = parse_sensor_file(text)
    trained = training_sensor(sensor)
    assert sensor.lr_shape == (300, 512) and sensor.fov_deg == 90.0
    assert info["render_lr_shape"] == [256, 256] and trained.hr_shape == (1024, 1024)
    # the paper's pitch (30 deg / 64 columns), capped at 90 deg, over the sensor's 512 columns; the window keeps it
    assert info["fov_deg"] == trained.fov_deg == pytest.approx(np.degrees(2 * np.arctan(np.tan(np.radians(45)) / 2)))
    assert trained.r_min == jaxsr.Sensor().r_min and info["gate"]["start_m"] == 0.0
    assert any("centred window" in w for w in info["warnings"])
    assert info["upscale_options"] == "--bins 32 --bin-width 2m --gate-start 0m --span gate"


@pytest.mark.parametrize("change,message", [
    (("bins = 32", "bins = 1"), "[sensor] bins: expected an integer from 2 to 4096, got 1"),
    (("bins = 32", "bins = 3.5"), "[sensor] bins: expected an integer from 2 to 4096, got 3.5"),
    (("bins = 32", "bins = true"), "[sensor] bins: expected an integer"),
    (("bins = 32", "bins = 32\nbinz = 3"), "[sensor] unknown key 'binz'; expected one of bins, bin_width_m"),
    (("bins = 32\n", ""), "[sensor] needs bins"),
    (("bin_width_ps = 250", "bin_width_ps = -250"), "[sensor] bin_width_ps: expected a finite number > 0, got -250"),
    (("bin_width_ps = 250", "bin_width_ps = 250\nbin_width_m = 0.03"), "gives bin_width_m and bin_width_ps"),
    (("bin_width_ps = 250", "bin_width = 250"), "[sensor] unknown key 'bin_width'"),
    (("bin_width_ps = 250", ""), "[sensor] needs one of bin_width_m, bin_width_ns, bin_width_ps"),
    (("gate_start_m = 120.0", "gate_start_m = -1.0"), "[sensor] gate_start_m: expected a finite number >= 0"),
    (("gate_start_m = 120.0", "gate_start_m = nan"), "[sensor] gate_start_m: expected a finite number >= 0, got nan"),
    (("lr_rows = 24", "lr_rows = 3"), "[sensor] lr_rows: expected an integer from 4 to 65536, got 3"),
    (("lr_cols = 40", ""), "[sensor] needs lr_cols"),
    (("fov_deg = 20.0", "fov_deg = 180"), "[sensor] fov_deg: expected degrees, a number > 0 and <= 170, got 180"),
    (("fov_deg = 20.0", 'fov_deg = "wide"'), "[sensor] fov_deg: expected degrees"),
    (("irf_sigma_bins = 0.8", "irf_sigma_bins = 0"), "[sensor] irf_sigma_bins: expected bins, a number > 0"),
    (("irf_sigma_bins = 0.8", ""), "[sensor] needs one of irf_sigma_bins, irf_file"),
    (("irf_sigma_bins = 0.8", 'irf_sigma_bins = 0.8\nirf_file = "irf.csv"'), "gives irf_sigma_bins and irf_file"),
    (("irf_sigma_bins = 0.8", "irf_sigma_bins = 0.8\nirf_sample_width_ps = 10"),
     "irf_sample_width_ps applies to irf_file only"),
    (("irf_sigma_bins = 0.8", "irf_sigma_bins = 40"), "the pulse's sigma is 40 bins; expected 0.001 to 32 bins"),
    (("signal_range = [2.0, 8.0]", "signal_range = [8.0, 2.0]"),
     "[photons] signal_range: expected [lo, hi], two finite numbers with 0.001 <= lo <= hi <= 1e+06, got [8.0, 2.0]"),
    (("signal_range = [2.0, 8.0]", "signal_range = [2.0, 1e300]"), "[photons] signal_range: expected [lo, hi]"),
    (("snr_range = [1.0, 10.0]", "snr_range = [1e-300, 10.0]"), "0.001 <= lo <= hi <= 10000, got [1e-300, 10.0]"),
    (("signal_range = [2.0, 8.0]", "signal_range = 5"), "[photons] signal_range: expected [lo, hi]"),
    (("signal_range = [2.0, 8.0]", ""), "[photons] needs signal_range"),
    (("snr_range = [1.0, 10.0]", "snr_range = [0, 10.0]"), "[photons] snr_range: expected [lo, hi]"),
    (("no_return_prob = 0.2", "no_return_prob = 1.5"),
     "[photons] no_return_prob: expected a probability from 0 to 1, got 1.5"),
    (("dark_prob = 0.0", "dark_prob = 0.0\nirf_sigma_range = [0.3, 3.0]"), "[photons] unknown key 'irf_sigma_range'"),
    (('motion = "drawn"', 'motion = "fast"'), "[photons] motion: expected one of 'seen', 'drawn', got 'fast'"),
    (("[photons]", "[photon]"), "unknown table [photon]"),
    (('description = "a test sensor"', "name = 3"), "unknown key 'name'"),
    (('description = "a test sensor"', "description = 3"), "description: expected a non-empty string, got 3"),
    (("[photons]\n", "[photons]\n[photons]\n"), "not valid TOML"),
    (("bin_width_ps = 250", "bin_width_m = 1e300"), "bin_width_m: a bin of 1e+300 m; expected 0.1 mm to 1 km"),
    (("bin_width_ps = 250", "bin_width_ps = 1e-300"), "bin_width_ps: a bin of 1.5e-304 m; expected 0.1 mm"),
])
def test_bad_keys_and_values_are_refused_by_name(change, message):
    old, new = change
    assert old in GOOD
    with pytest.raises(ValueError) as e:
        parse_sensor_file(GOOD.replace(old, new, 1), source="my.toml")
    assert str(e.value).startswith("my.toml") and message in str(e.value), str(e.value)


def test_a_missing_table_is_refused():
    with pytest.raises(ValueError, match=r"needs a \[photons\] table"):
        parse_sensor_file(GOOD.split("[photons]")[0])


@pytest.mark.parametrize("sigma,sample_width", [(0.7, 0.1), (1.3, 1.0), (0.2, 1.0), (0.03, 0.005)])
def test_the_irf_fit_recovers_a_known_width(sigma, sample_width):
    x = np.arange(80.0)
    irf = 3.0 + 1000.0 * sf._binned_gaussian(x, 37.3, sigma / sample_width)
    fit = fit_irf(irf, sample_width_bins=sample_width)
    assert fit["sigma_bins"] == pytest.approx(sigma, rel=1e-4) and fit["residual"] < 1e-6
    assert fit["centre_samples"] == pytest.approx(37.3, abs=1e-3) and fit["background"] == pytest.approx(3.0)


def test_an_irf_file_is_fitted_and_its_residual_reported(tmp_path):
    x = np.arange(60.0)
    counts = np.random.default_rng(0).poisson(2.0 + 20000.0 * sf._binned_gaussian(x, 25.0, 8.0))
    np.savetxt(tmp_path / "irf.csv", counts, fmt="%d", header="time-correlated counts, 100 ps")
    text = GOOD.replace("irf_sigma_bins = 0.8", 'irf_file = "irf.csv"\nirf_sample_width_ps = 100')
    (tmp_path / "s.toml").write_text(text)
    _, regime, info = read_sensor_file(tmp_path / "s.toml")
    # 8 samples of 100 ps = 3.2 bins of 250 ps
    assert info["irf"]["sigma_bins"] == pytest.approx(3.2, rel=0.03) and regime.irf_paper == info["irf"]["sigma_bins"]
    assert info["irf"]["fit"]["residual"] < 0.05 and info["irf"]["fit"]["reduced_chi2"] < 3
    assert not any("not Gaussian" in w for w in info["warnings"])
    assert any("wider than any" in w for w in info["warnings"])  # 3.2 bins: beyond the bundled models' 0.3-3
    # one sample per bin without irf_sample_width; .npy and one row of text read alike
    np.save(tmp_path / "irf.npy", counts)
    (tmp_path / "row.txt").write_text(" ".join(str(int(c)) for c in counts))
    for name in ("irf.npy", "row.txt"):
        np.testing.assert_array_equal(read_irf_file(tmp_path / name), counts)
    _, _, info = parse_sensor_file(GOOD.replace("irf_sigma_bins = 0.8", 'irf_file = "irf.npy"'), base_dir=tmp_path)
    assert info["irf"]["sigma_bins"] == pytest.approx(8.0, rel=0.03)
    # a pulse with a long tail: fitted, and said to be far from Gaussian
    tail = 1000.0 * sf._binned_gaussian(x, 20.0, 1.5) + 300.0 * np.exp(-np.clip(x - 20.0, 0, None) / 8.0) * (x > 20)
    np.savetxt(tmp_path / "tail.txt", tail)
    _, _, info = parse_sensor_file(GOOD.replace("irf_sigma_bins = 0.8", 'irf_file = "tail.txt"'), base_dir=tmp_path)
    assert info["irf"]["fit"]["residual"] > 0.05 and any("not Gaussian" in w for w in info["warnings"])


@pytest.mark.parametrize("content,message", [
    ("1 2\n3 4\n5 6\n7 8\n", "expected one column (or one row) of counts"),
    ("1\n2\nnan\n4\n", "with NaN or inf"),
    ("1\n2\n", "expected at least 4 finite numbers"),
    ("5\n5\n5\n5\n5\n", "no peak above its background"),
    ("1\n2\nthree\n4\n", "expected numbers, got the line 'three'"),
])
def test_bad_irf_files_are_refused(tmp_path, content, message):
    (tmp_path / "irf.txt").write_text(content)
    with pytest.raises(ValueError, match="irf_file") as e:
        parse_sensor_file(GOOD.replace("irf_sigma_bins = 0.8", 'irf_file = "irf.txt"'), base_dir=tmp_path)
    assert message in str(e.value)
    with pytest.raises(FileNotFoundError, match="no such file"):
        parse_sensor_file(GOOD.replace("irf_sigma_bins = 0.8", 'irf_file = "none.txt"'), base_dir=tmp_path)


TINY_CARD = {"steps": 5, "examples": 20, "trained_with": "a test"}  # the training behind the starting model


def _tiny_model(path):
    params, state = init_model(jax.random.key(0), TINY)
    return save_model(path, Model(params, state, TINY), card=TINY_CARD)


def test_a_lineage_never_stops_a_run(tmp_path):
    """The lineage a fine-tune's card gets from its starting checkpoint: the card's stages, then the card; {} for
    an odd card, a missing file or a Model, so that a run starts as it did without one."""
    from jaxsr.training.records import _lineage_after, _run_lineage

    stage = {"steps": 2, "examples": 8}
    card = {"earlier_stages": [stage], "steps": 5, "examples": 20, "total_steps": 7, "total_examples": 28, "x": 1}
    assert _lineage_after(card) == {"earlier_stages": [stage, {"steps": 5, "examples": 20, "x": 1}],
                                    "total_steps": 7, "total_examples": 28}
    for odd in (None, [], "card", {"earlier_stages": None, "steps": 3}, {"earlier_stages": [1]},
                {"steps": "many"}, {"steps": -1}, {"steps": True}):
        assert _lineage_after(odd) == {}
    assert _run_lineage(tmp_path / "run", tmp_path / "missing.npz", False) == {}
    assert _run_lineage(tmp_path / "run", Model(*init_model(jax.random.key(0), TINY), TINY), False) == {}
    assert _run_lineage(tmp_path / "run", _tiny_model(tmp_path / "tiny.npz"), False)["earlier_stages"] == [TINY_CARD]


def test_finetune_builds_on_train_and_records_the_sensor(tmp_path, monkeypatch):
    """The options reach `fit` as a fine-tune of the sensor's data (fit and the validation stubbed: no compiling)."""
    import jaxsr.training.presets as presets

    (tmp_path / "s.toml").write_text(TINY_TOML)
    _tiny_model(tmp_path / "tiny.npz")
    got = {}
    monkeypatch.setattr(presets, "regime_validation", lambda *a, **kw: {"stub": True})
    monkeypatch.setattr(presets, "_start_score", lambda *a, **kw: {"val_loss": 1.0, "val_psnr": 20.0})
    monkeypatch.setattr(presets, "fit", lambda cfg, train_cfg, **kw: (got.update(kw, cfg=cfg, train_cfg=train_cfg),
                                                                     (None, []))[1])
    assert cli.main(["finetune", "--sensor", str(tmp_path / "s.toml"), "--model", str(tmp_path / "tiny.npz"),
                     "--output", str(tmp_path / "run"), "--epochs", "6", "--steps-per-epoch", "3", "--no-progress"]) == 0
    base = PRESETS["bundle"]
    assert got["cfg"] == TINY
    assert got["train_cfg"] == dataclasses.replace(base, lr=base.lr / 10, epochs=6, examples_per_epoch=12,
                                                   patch=(8, 8), decay_epochs=3, patience=3)
    assert got["sensor"].hr_shape == (32, 32) and got["sensor"].d_max == 32.0
    assert "PhotonRegime" in got["make_batch"].description and got["validation"] == {"stub": True}
    card = got["card_extra"]
    assert card["sensor_file"]["text"] == TINY_TOML and card["regime"]["snr_range"] == [5.0, 20.0]
    assert card["sensor_file"]["upscale_options"] == "--bins 16 --bin-width 2m --gate-start 0m --span gate"
    assert card["finetune"]["start"] == {"val_loss": 1.0, "val_psnr": 20.0} and card["finetune"]["photons"] is False
    assert got["init"] == str(tmp_path / "tiny.npz") and not got["resume"] and not (tmp_path / "run").exists()
    # the photon inputs widen the model; a bundled model keeps its TR, in the window form
    jaxsr.training.finetune(tmp_path / "p", sensor_file=tmp_path / "s.toml", init="tr1", photons=True, progress=False)
    assert got["cfg"] == jaxsr.ModelConfig(tr=1, **presets.PHOTON_INPUTS)
    with pytest.raises(ValueError, match="steps_per_epoch must be an integer >= 1"):
        jaxsr.training.finetune(tmp_path / "x", sensor_file=tmp_path / "s.toml", steps_per_epoch=0)


def test_resume_refuses_another_sensor_before_any_work(tmp_path, monkeypatch):
    import jaxsr.training.presets as presets
    from jaxsr.io.checkpoint import save_tree
    from jaxsr.training.sensor_file import card_entry

    (tmp_path / "s.toml").write_text(TINY_TOML)
    _, regime, info = read_sensor_file(tmp_path / "s.toml")
    card = {"sensor_file": card_entry(info), "regime": regime.to_dict()}
    run = tmp_path / "run"
    run.mkdir()
    save_tree(run / "last.npz", {"x": np.zeros(1)}, {"kind": "train_state", "run": {"step": 2}, "card": card})
    # the same sensor, written otherwise (comments, order), is the same; another pulse or regime is not
    for change, what in (("irf_sigma_bins = 0.5", "pulse sigma"), ("[5.0, 20.0]", "photon regime"),
                         ("lr_rows = 8", "lr_shape")):
        new = {"irf_sigma_bins = 0.5": "irf_sigma_bins = 0.6", "[5.0, 20.0]": "[5.0, 30.0]",
               "lr_rows = 8": "lr_rows = 12"}[change]
        (tmp_path / "other.toml").write_text(TINY_TOML.replace(change, new))
        with pytest.raises(ValueError, match=f"describes another sensor .*{what}"):
            jaxsr.training.finetune(run, sensor_file=tmp_path / "other.toml", resume=True, progress=False)
    got = {}
    monkeypatch.setattr(presets, "regime_validation", lambda *a, **kw: {})
    monkeypatch.setattr(presets, "_start_score", lambda *a, **kw: {"val_loss": 1.0, "val_psnr": 20.0})
    monkeypatch.setattr(presets, "fit", lambda *a, **kw: (got.update(kw), (None, []))[1])
    (tmp_path / "same.toml").write_text("# the same sensor\n" + TINY_TOML.replace("bins = 16\n", "") + "\n")
    (tmp_path / "same.toml").write_text((tmp_path / "same.toml").read_text().replace(
        "[sensor]\n", "[sensor]\nbins = 16   # K\n"))
    jaxsr.training.finetune(run, sensor_file=tmp_path / "same.toml", resume=True, progress=False)
    assert got["resume"] and got["card_extra"]["sensor_file"]["text"] != TINY_TOML
    # a card written before a PhotonRegime field existed (static_prob) resumes: the field had its default then
    old_card = dict(card, regime={k: v for k, v in regime.to_dict().items() if k != "static_prob"})
    save_tree(run / "last.npz", {"x": np.zeros(1)}, {"kind": "train_state", "run": {"step": 2}, "card": old_card})
    got.clear()
    jaxsr.training.finetune(run, sensor_file=tmp_path / "s.toml", resume=True, progress=False)
    assert got["resume"]
    save_tree(run / "last.npz", {"x": np.zeros(1)}, {"kind": "train_state", "run": {"step": 2}, "card": {}})
    with pytest.raises(ValueError, match="not a fine-tune to a sensor file"):
        jaxsr.training.finetune(run, sensor_file=tmp_path / "s.toml", resume=True, progress=False)


def test_finetune_user_errors_are_one_line(tmp_path, capsys):
    (tmp_path / "bad.toml").write_text(TINY_TOML.replace("bins = 16", "bins = 1"))
    (tmp_path / "s.toml").write_text(TINY_TOML)
    for args, message in (
            (["--sensor", str(tmp_path / "none.toml")], "no such file"),
            (["--sensor", str(tmp_path / "bad.toml")], "[sensor] bins: expected an integer from 2 to 4096, got 1"),
            (["--sensor", str(tmp_path / "s.toml"), "--model", "tr9"], "no checkpoint at 'tr9'"),
            (["--sensor", str(tmp_path / "s.toml"), "--model", "histnet"], "expected a model of the paper's network"),
            (["--sensor", str(tmp_path / "s.toml"), "--resume"], "nothing to resume")):
        assert cli.main(["finetune", "--output", str(tmp_path / "run"), "--no-progress", *args]) == 2
        err = capsys.readouterr().err
        assert err.startswith("jaxsr finetune: error: ") and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "run").exists()


def test_the_starting_model_inside_out_is_refused_and_kept(tmp_path, capsys):
    """--from inside --out with --force would delete the starting weights at the first save."""
    import shutil

    from jaxsr.io.checkpoint import resolve_model_path

    (tmp_path / "s.toml").write_text(TINY_TOML)
    (tmp_path / "run").mkdir()
    shutil.copy(resolve_model_path("tr1"), tmp_path / "run" / "best.npz")
    before = (tmp_path / "run" / "best.npz").read_bytes()
    for start in (tmp_path / "run", tmp_path / "run" / "best.npz"):
        assert cli.main(["finetune", "--output", str(tmp_path / "run"), "--no-progress", "--sensor",
                         str(tmp_path / "s.toml"), "--model", str(start), "--force"]) == 2
        assert "lies inside -o/--output" in capsys.readouterr().err
    assert (tmp_path / "run" / "best.npz").read_bytes() == before


def test_a_run_folder_is_a_model(tmp_path):
    run = tmp_path / "my_tr4"
    run.mkdir()
    with pytest.raises(FileNotFoundError, match="a folder without best.npz"):
        resolve_model_path(run)
    _tiny_model(run / "best.npz")
    assert resolve_model_path(run) == run / "best.npz"
    assert jaxsr.load_model(run).config == TINY
    assert resolve_model_path("paper-tr4") == resolve_model_path("tr4")  # the aliases stay


def test_upscale_takes_a_run_folder(tmp_path, capsys):
    _tiny_model((tmp_path / "run").mkdir() or tmp_path / "run" / "best.npz")
    depth = np.random.default_rng(0).uniform(0.1, 0.9, (2, 6, 8)).astype(np.float32)
    np.save(tmp_path / "lr.npy", depth)
    assert cli.main(["upscale", str(tmp_path / "lr.npy"), "-o", str(tmp_path / "hr.npy"), "--model", str(tmp_path / "run"),
                     "--no-progress"]) == 0
    assert np.load(tmp_path / "hr.npy").shape == (2, 24, 32)
    capsys.readouterr()


@pytest.mark.slow
def test_finetune_end_to_end_resume_and_upscale(tmp_path, capsys):
    """A tiny fine-tune (8 x 8 LR sensor, a tiny network, 1 epoch of 2 steps), resumed for a second epoch, then
    `jaxsr upscale -m RUN_FOLDER --sensor FILE` on histograms, as the fine-tune printed."""
    (tmp_path / "s.toml").write_text(TINY_TOML)
    _tiny_model(tmp_path / "tiny.npz")
    out = tmp_path / "run"
    args = ["finetune", "--sensor", str(tmp_path / "s.toml"), "--model", str(tmp_path / "tiny.npz"), "--output", str(out),
            "--steps-per-epoch", "2", "--val-batches", "1", "--no-progress"]
    assert cli.main([*args, "--epochs", "1"]) == 0
    printed = capsys.readouterr().out
    assert "best epoch 1" in printed
    assert f"-m {out} --sensor {tmp_path / 's.toml'}" in printed
    assert {"best.npz", "last.npz", "metrics.jsonl"} <= {p.name for p in out.iterdir()}
    card = jaxsr.read_metadata(out / "best.npz")["card"]
    assert card["sensor_file"]["text"] == TINY_TOML and card["regime"]["signal_range"] == [2.0, 8.0]
    assert card["train_config"]["lr"] == pytest.approx(PRESETS["bundle"].lr / 10)
    assert "the starting model" in printed and card["finetune"]["start"]["val_psnr"] > 0
    # the card carries the starting model's training: its card as the stage before, and the sums
    assert card["earlier_stages"] == [TINY_CARD] and card["init"] == str(tmp_path / "tiny.npz")
    assert (card["total_steps"], card["total_examples"]) == (5 + card["steps"], 20 + card["examples"])
    # a changed sensor is refused on resume; the same one continues
    (tmp_path / "other.toml").write_text(TINY_TOML.replace("[5.0, 20.0]", "[1.0, 20.0]"))
    assert cli.main([*args, "--epochs", "2", "--resume", "--sensor", str(tmp_path / "other.toml")]) == 2
    assert "describes another sensor" in capsys.readouterr().err
    assert cli.main([*args, "--epochs", "2", "--resume"]) == 0
    assert len((out / "metrics.jsonl").read_text().splitlines()) == 2
    card = jaxsr.read_metadata(out / "last.npz")["card"]  # resumed: the lineage still there, the sums grown
    assert card["earlier_stages"] == [TINY_CARD] and card["total_steps"] == 5 + card["steps"] == 5 + 4
    counts = np.random.default_rng(0).poisson(0.3, (2, 8, 8, 16)).astype(np.float32)
    counts[..., 5] += 4
    np.save(tmp_path / "counts.npy", counts)
    assert cli.main(["upscale", str(tmp_path / "counts.npy"), "-o", str(tmp_path / "hr.npz"), "-m", str(out),
                     "--sensor", str(tmp_path / "s.toml"), "--no-progress"]) == 0
    assert np.load(tmp_path / "hr.npz")["depth"].shape == (2, 32, 32)


def test_a_sensor_file_nested_too_deeply_or_an_irf_folder_is_one_line(tmp_path):
    deep = GOOD.replace('description = "a test sensor"', "description = " + "[" * 5000 + "]" * 5000)
    with pytest.raises(ValueError, match="my.toml: not valid TOML for a sensor file"):
        parse_sensor_file(deep, source="my.toml")
    (tmp_path / "irf.csv").mkdir()
    with pytest.raises(IsADirectoryError, match="irf.csv is a folder"):
        read_irf_file(tmp_path / "irf.csv")


def test_an_out_holding_a_run_is_refused_before_any_work(tmp_path):
    """Without --resume or --force, a folder holding a run is refused first: before the sensor file is read and
    the validation set drawn (the half minute that took before the refusal came)."""
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "best.npz").write_bytes(b"a run")
    with pytest.raises(FileExistsError, match="holds a training run .*--resume .*--force"):
        jaxsr.training.finetune(tmp_path / "run", sensor_file=tmp_path / "missing.toml", progress=False)
    with pytest.raises(FileExistsError, match="holds a training run"):
        jaxsr.training.train(tmp_path / "run", tr=0, preset="cpu", progress=False)


def test_an_inverted_irf_is_refused_not_fitted_wide():
    """An IRF that dips below its background (a pulse with the wrong sign) was fitted to a sigma of 11.6 bins
    (true 1.5) and trained on with warnings only."""
    x = np.arange(64.0)
    pulse = 500.0 * np.exp(-0.5 * ((x - 20.0) / 1.5) ** 2)
    assert fit_irf(100.0 + pulse)["sigma_bins"] == pytest.approx(1.5, rel=0.05)
    with pytest.raises(ValueError, match="dips .* below its median"):
        fit_irf(1000.0 - pulse)


@pytest.mark.parametrize("damage", ["a header claiming terabytes", "non-finite weights"])
def test_damaged_starting_weights_are_refused_before_the_set_up(tmp_path, monkeypatch, capsys, damage):
    """`finetune --from` and `train --init` read only the starting model's metadata up front: its weights, a
    header claiming 10^12 floats or NaN, were refused in one line only after the validation set was drawn
    (minutes). Now before any data is made, and nothing is written."""
    from jaxsr.training import presets

    cfg = jaxsr.ModelConfig(tr=0, base=4, growth=2, head=4, filter_hidden=4)
    params, state = init_model(jax.random.key(0), cfg)
    if damage == "non-finite weights":
        params = jax.tree_util.tree_map(np.asarray, params)
        params["stem"]["b"] = np.full_like(params["stem"]["b"], np.nan)
    path = save_model(tmp_path / "start.npz", Model(params, state, cfg))
    if damage == "a header claiming terabytes":
        claim_terabytes(path)

    def set_up(*args, **kwargs):
        raise AssertionError("the set-up began")

    for name in ("regime_batches", "regime_validation", "sequence_data", "_fit_in_new_folder"):
        monkeypatch.setattr(presets, name, set_up)
    (tmp_path / "s.toml").write_text(TINY_TOML)
    for command in (["finetune", "--sensor", str(tmp_path / "s.toml"), "--model", str(path)],
                    ["train", "--tr", "0", "--init", str(path)]):
        assert cli.main([*command, "--output", str(tmp_path / "run"), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "start.npz" in err, err
        assert ("claims 4e+12 bytes" if damage == "a header claiming terabytes" else "non-finite") in err, err
    assert not (tmp_path / "run").exists()


def test_an_out_on_a_read_only_file_system_is_refused_before_the_set_up(read_only_tmpfs, tmp_path, monkeypatch,
                                                                        capsys):
    """--out on a read-only file system was refused only at the first write, after 26-33 s of set-up: now first,
    in one line, exit 2, for `finetune` and `train`, a new folder or the mount itself."""
    from jaxsr.training import presets

    def set_up(*args, **kwargs):
        raise AssertionError("the set-up began")

    for name in ("regime_batches", "regime_validation", "read_sensor_file", "_fit_in_new_folder"):
        monkeypatch.setattr(presets, name, set_up)
    (tmp_path / "s.toml").write_text(TINY_TOML)
    for out in (read_only_tmpfs / "run", read_only_tmpfs):
        for command in (["finetune", "--sensor", str(tmp_path / "s.toml")], ["train", "--tr", "0"]):
            assert cli.main([*command, "--output", str(out), "--no-progress"]) == 2
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and f"{read_only_tmpfs} is on a read-only file system" in err, err


def test_the_printed_upscale_command_survives_a_shell(tmp_path, monkeypatch, capsys):
    """The "run it" line names --out as a shell reads it back: a path with a space, a tab or a quote pasted
    whole (the fine-tune itself stubbed: only the printing is under test)."""
    import shlex

    import jaxsr.cli.finetune as command

    monkeypatch.setattr(command, "finetune", lambda *args, **kwargs: (None, []))
    (tmp_path / "s.toml").write_text(TINY_TOML)
    out = str(tmp_path / "my runs\tv1" / "it's here")
    assert cli.main(["finetune", "--sensor", str(tmp_path / "s.toml"), "--output", out, "--no-progress"]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("run it: "))
    words = shlex.split(line.removeprefix("run it: ").split("  (RECORDING")[0])
    assert words == ["jaxsr", "upscale", "RECORDING", "-o", "OUTPUT", "-m", out, "--sensor", str(tmp_path / "s.toml")]


def test_a_byte_order_mark_is_read_past(tmp_path):
    """Notepad and spreadsheets begin UTF-8 files with a byte-order mark: the sensor file was "not valid TOML",
    and an IRF column lost its first sample (taken for a header line) without a word."""
    (tmp_path / "s.toml").write_text("\ufeff" + TINY_TOML, encoding="utf-8")
    sensor, _, _ = read_sensor_file(tmp_path / "s.toml")
    assert sensor.bins == 16
    (tmp_path / "irf.csv").write_text("\ufeff100\n5\n1\n0\n0\n", encoding="utf-8")
    np.testing.assert_array_equal(read_irf_file(tmp_path / "irf.csv"), [100, 5, 1, 0, 0])


@pytest.mark.parametrize("start", ["gate_start_m = 1e300", "gate_start_m = 1e10", "gate_start_ns = 1e300"])
def test_a_gate_beyond_float32_metres_is_refused(start):
    """Float32 metres cannot hold depth within such a gate (training and upscale alike); it was accepted and the
    run's closing command refused by upscale after the training."""
    with pytest.raises(ValueError, match=r"\[sensor\] the gate ends .* float32 metres"):
        parse_sensor_file(TINY_TOML.replace("bins = 16", f"bins = 16\n{start}"))
    parse_sensor_file(TINY_TOML.replace("bins = 16", "bins = 16\ngate_start_m = 200e3"))  # 200 km: 1.6 cm steps


@pytest.mark.parametrize("seeds", [None, "0,1"])
def test_train_refuses_init_weights_inside_out(tmp_path, capsys, monkeypatch, seeds):
    """jaxsr train --init inside -o/--output --force deleted the starting weights at the first save, as
    finetune's -m/--model did; refused before any work, the weights kept."""
    from jaxsr.training import presets

    monkeypatch.setattr(presets, "_fit_in_new_folder", lambda *a, **k: pytest.fail("trained"))
    run = tmp_path / "run"
    folder = run if seeds is None else run / "seed0"
    folder.mkdir(parents=True)
    _tiny_model(folder / "best.npz")
    before = (folder / "best.npz").read_bytes()
    args = ["train", "--tr", "0", "--epochs", "1", "--quiet", "-o", str(run), "--force",
            "--init", str(folder / "best.npz")] + ([] if seeds is None else ["--seeds", seeds])
    assert cli.main(args) == 2
    assert "--init" in (err := capsys.readouterr().err) and "lies inside -o/--output" in err
    assert (folder / "best.npz").read_bytes() == before


def test_resuming_stacked_seeds_without_a_run_says_so_plainly(tmp_path, capsys):
    """It said "no seed folder ... holds no training run", which means the opposite."""
    assert cli.main(["train", "--tr", "0", "-o", str(tmp_path / "run"), "--seeds", "0,1", "--resume",
                     "--no-progress"]) == 2
    assert "no seed folder of" in (err := capsys.readouterr().err) and "(seed0, seed1) holds a training run" in err
