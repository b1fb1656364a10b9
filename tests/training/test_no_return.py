"""The no-return decision threshold (`ModelConfig.no_return_logit`): the config field and its checks, the decision
honouring it, old checkpoints loading at the default with identical outputs, the sweep of thresholds
(`no_return_table`), the rule (`choose_no_return_logit`), the whole calibration on a tiny model, and the study
script end to end (slow)."""

import dataclasses
import importlib.util
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr.config import ModelConfig, Optics, PhotonRegime, Sensor, TrainConfig
from jaxsr.io.checkpoint import load_model, read_metadata, save_model, save_tree
from jaxsr.nn import Model, apply_model, apply_model_raw, init_model, merge_no_return
from jaxsr.training import (calibrate_no_return, choose_no_return_logit, no_return_outputs, no_return_table,
                            regime_batches, regime_draws)
from jaxsr.training.duf import initial_weights, model_loss
from jaxsr.training.presets import _init_config

ROOT = Path(__file__).resolve().parents[2]
PHOTONS = ("depth", "signal", "background")
TINY = dict(base=8, growth=4, head=16, filter_hidden=16, same_blocks=1)


def _tiny_photon_model(seed=0, **cfg):
    cfg = ModelConfig(tr=0, inputs=PHOTONS, no_return_head=True, **TINY, **cfg)
    params, state = init_model(jax.random.key(seed), cfg)
    head = params["no_return"]["conv2"]  # logits spread around 0, not the new head's -4 everywhere
    params["no_return"]["conv2"] = {"w": 2.0 * jax.random.normal(jax.random.key(seed + 1), head["w"].shape),
                                    "b": head["b"] + 4.0}
    return Model(params, state, cfg)


def _windows(n, seed=0, h=6, w=10):
    x = jax.random.uniform(jax.random.key(seed), (n, 1, h, w, 3))
    return np.asarray(x)


def test_config_field_defaults_and_checks():
    assert ModelConfig().no_return_logit == 0.0
    cfg = ModelConfig(no_return_head=True, no_return_logit=1)
    assert cfg.no_return_logit == 1.0 and isinstance(cfg.no_return_logit, float)
    assert hash(cfg) == hash(ModelConfig(no_return_head=True, no_return_logit=1.0))
    assert ModelConfig(no_return_logit=np.float32(-2.5)).no_return_logit == -2.5
    for bad in (float("nan"), float("inf"), -float("inf"), "0", None, True):
        with pytest.raises(ValueError, match="no_return_logit"):
            ModelConfig(no_return_head=True, no_return_logit=bad)


def test_merge_no_return_honours_the_threshold():
    out = jnp.stack([jnp.full((1, 5), 0.25), jnp.array([[-1.0, 0.0, 0.5, 1.5, 2.0]])], axis=-1)
    at = {t: np.asarray(merge_no_return(out, ModelConfig(no_return_head=True, no_return_logit=t)))[0]
          for t in (0.0, 1.5, -1.0)}
    np.testing.assert_array_equal(at[0.0], [0.25, 0.25, 1.0, 1.0, 1.0])  # logit > 0, as before the field
    np.testing.assert_array_equal(at[1.5], [0.25, 0.25, 0.25, 0.25, 1.0])  # strictly above the threshold
    np.testing.assert_array_equal(at[-1.0], [0.25, 1.0, 1.0, 1.0, 1.0])
    depth_only = ModelConfig(no_return_logit=3.0)  # without a head the field changes nothing
    np.testing.assert_array_equal(merge_no_return(out[..., 0], depth_only), out[..., 0])
    # apply_model takes the decision with the config's threshold on apply_model_raw's output
    model = _tiny_photon_model()
    x = _windows(2)
    raw = np.asarray(apply_model_raw(model.params, model.state, x, model.config))
    assert raw.shape == (2, 24, 40, 2)
    for t in (0.0, 2.0):
        got = np.asarray(apply_model(model.params, model.state, x, dataclasses.replace(model.config,
                                                                                      no_return_logit=t)))
        np.testing.assert_array_equal(got, np.where(raw[..., 1] > t, 1.0, raw[..., 0]))
    assert 0.05 < np.mean(raw[..., 1] > 0) < 0.95  # the tiny head marks some pixels and not others


def test_the_training_loss_reads_the_raw_logit():
    out = jnp.stack([jnp.full((1, 4, 4), 0.4), jnp.linspace(-3, 3, 16).reshape(1, 4, 4)], axis=-1)
    gt = jnp.full((1, 4, 4), 0.4).at[:, :2].set(1.0)
    losses = {t: float(model_loss(out, gt, ModelConfig(no_return_head=True, no_return_logit=t), TrainConfig()))
              for t in (0.0, -2.0, 3.0)}
    assert losses[0.0] == losses[-2.0] == losses[3.0]


def test_old_checkpoints_load_at_the_default_with_identical_outputs(tmp_path):
    model = _tiny_photon_model()
    d = dataclasses.asdict(model.config)
    old = {k: v for k, v in d.items() if k != "no_return_logit"}  # a file written before the field
    path = save_tree(tmp_path / "old.npz", {"params": model.params, "state": model.state},
                     {"kind": "model", "architecture": "duf", "config": old, "card": {}, "storage_dtype": "float32"})
    assert "no_return_logit" not in read_metadata(path)["config"]
    loaded = load_model(path)
    assert loaded.config == model.config and loaded.config.no_return_logit == 0.0
    x = _windows(2, seed=3)
    raw = np.asarray(apply_model_raw(model.params, model.state, x, model.config))
    before = np.where(raw[..., 1] > 0, 1.0, raw[..., 0])  # the decision as it was: logit > 0
    np.testing.assert_array_equal(np.asarray(apply_model(loaded.params, loaded.state, x, loaded.config)), before)
    # a calibrated threshold survives the round trip, float16 storage included
    calibrated = dataclasses.replace(model, config=dataclasses.replace(model.config, no_return_logit=-1.25))
    back = load_model(save_model(tmp_path / "cal.npz", calibrated, storage_dtype="float16"))
    assert back.config.no_return_logit == -1.25
    # the bundled photon models decide at the uncalibrated default (tr0-photons saved before the field, tr4-photons
    # after it, with 0.0)
    for name in ("tr0-photons", "tr4-photons", "tr0-ambient", "tr4-ambient"):
        assert read_metadata(ROOT / "jaxsr" / "weights" / f"{name}.npz")["config"].get("no_return_logit", 0.0) == 0.0
        assert load_model(name).config.no_return_logit == 0.0


def test_a_calibrated_model_is_a_valid_init(tmp_path):
    """The threshold is no part of the architecture: a calibrated model starts a run of the default config, and a
    fine-tune from it starts uncalibrated (the calibration held for other weights)."""
    model = _tiny_photon_model()
    calibrated = dataclasses.replace(model, config=dataclasses.replace(model.config, no_return_logit=2.0))
    assert _init_config(save_model(tmp_path / "cal.npz", calibrated), None) == model.config
    params, _ = initial_weights(jax.random.key(0), model.config, calibrated)
    np.testing.assert_array_equal(params["no_return"]["conv2"]["b"], model.params["no_return"]["conv2"]["b"])
    with pytest.raises(ValueError, match="head 16 .training 32"):  # other fields still must agree
        initial_weights(jax.random.key(0), dataclasses.replace(model.config, head=32), calibrated)


def test_a_fine_tune_with_photons_keeps_what_its_init_reads():
    """--photons adds the photon inputs to a model's own: a depth model gets them, an ambient model keeps its fourth
    channel (narrowing it would fail only once the run has built its data)."""
    assert _init_config("tr1", True).inputs == ("depth", "signal", "background")
    assert _init_config("tr4-ambient", True).inputs == ("depth", "signal", "background", "ambient")
    assert _init_config("tr4-ambient", None).no_return_head


def test_table_counts_pixels_as_the_benchmark_reads_them():
    #            sky    sky    sky    sky   ret   ret   ret    ret (depth at the far end)
    gt = np.array([[1.0, 1.0, 1.0, 1.0, 0.5, 0.5, 0.5, 0.5]])
    depth = np.array([[0.3, 0.3, 0.995, np.nan, 0.5, 0.5, 0.5, 0.999]])
    logit = np.array([[-1.0, 1.0, -5.0, -5.0, -2.0, 0.5, np.nan, -5.0]])
    t = no_return_table(depth, logit, gt, [14.0], [-3.0, 0.0, 2.0], edges=(10, 30))
    assert t["bands"].tolist() == [[10.0, 30.0]] and t["windows"].tolist() == [1]
    # as depth: sky pixels whose depth reads as depth (< 0.99) and whose logit is not above t
    np.testing.assert_allclose(t["as_depth"][0], [0.0, 25.0, 50.0])
    # dropped: returns read as no return by their depth (0.999), or by a logit above t (a NaN logit never)
    np.testing.assert_allclose(t["dropped"][0], [75.0, 50.0, 25.0])
    assert t["no_return_pixels"].tolist() == [4] and t["return_pixels"].tolist() == [4]


def test_table_bands_and_monotone_shares():
    rng = np.random.default_rng(0)
    n = 12
    gt = np.where(rng.random((n, 8, 8)) < 0.3, 1.0, rng.random((n, 8, 8)) * 0.9)
    depth = np.clip(gt + 0.05 * rng.normal(size=gt.shape), 0, 1.2)
    logit = 3.0 * (gt >= 1) - 1.5 + rng.normal(size=gt.shape)
    photons = np.array([2.9999998, 3.0, 4.0, 6.0, 9.0, 20.0, 50.0, 200.0, 999.99, 1000.0001, 0.7, 5000.0])
    t = no_return_table(depth, logit, gt, photons, np.linspace(-4, 4, 33))
    assert t["bands"][:, 0].tolist() == [0.5, 3.0, 5.0, 10.0, 30.0, 100.0, 300.0]  # 1-3 empty, 5000 beyond
    assert t["windows"].tolist() == [1, 3, 2, 1, 1, 1, 2]  # float32 draws at an edge go in the band above
    assert np.all(np.diff(t["as_depth"], axis=1) >= 0) and np.all(np.diff(t["dropped"], axis=1) <= 0)
    with pytest.raises(ValueError, match="thresholds"):
        no_return_table(depth, logit, gt, photons, [0.0, np.nan])
    with pytest.raises(ValueError, match="one shape"):
        no_return_table(depth, logit[:3], gt, photons)


def _table(as_depth, dropped, bands=((1, 3), (3, 10), (10, 100)), thresholds=(-1.0, 0.0, 1.0, 2.0)):
    return {"thresholds": np.array(thresholds), "bands": np.array(bands, float),
            "as_depth": np.array(as_depth, float), "dropped": np.array(dropped, float)}


def test_rule_picks_the_least_as_depth_within_the_dropped_target():
    as_depth = [[90, 95, 99, 100], [1, 2, 4, 8], [0.5, 1, 3, 6]]
    dropped = [[50, 30, 10, 5], [6, 2.5, 1.5, 0.5], [3, 2.0, 1, 0.2]]
    c = choose_no_return_logit(_table(as_depth, dropped))
    # the band 1-3 is not counted (below 3 photons); worst dropped: 6, 2.5, 1.5, 0.5 -> feasible from t = 1
    assert c["no_return_logit"] == 1.0 and c["met"]
    assert (c["as_depth"], c["dropped"]) == (4.0, 1.5) and c["bands"] == [[3.0, 10.0], [10.0, 100.0]]
    assert choose_no_return_logit(_table(as_depth, dropped), target_dropped=2.5)["no_return_logit"] == 0.0
    assert choose_no_return_logit(_table(as_depth, dropped), min_photons=1.0)["no_return_logit"] == 2.0
    # no threshold within the target: the one that drops least, flagged
    c = choose_no_return_logit(_table(as_depth, dropped), target_dropped=0.1)
    assert c["no_return_logit"] == 2.0 and not c["met"]
    # ties in "as depth": the smaller "dropped"; then the smaller threshold
    c = choose_no_return_logit(_table([[0, 0, 0, 0]] * 3, [[9, 1, 1, 0.5]] * 3))
    assert c["no_return_logit"] == 2.0
    c = choose_no_return_logit(_table([[0, 0, 0, 0]] * 3, [[9, 1, 1, 1]] * 3))
    assert c["no_return_logit"] == 0.0
    with pytest.raises(ValueError, match="no band"):
        choose_no_return_logit(_table(as_depth, dropped), min_photons=200.0)


def test_calibration_of_a_tiny_model():
    model = _tiny_photon_model(seed=2)
    x = _windows(6, seed=5)
    rng = np.random.default_rng(1)
    gt = np.where(rng.random((6, 24, 40)) < 0.4, 1.0, 0.5).astype(np.float32)
    validation = {"windows": x, "gt": gt, "photons": np.array([3.5, 3.5, 14.0, 14.0, 100.0, 1.5])}
    thresholds = np.linspace(-6, 6, 49)
    result = calibrate_no_return(model, validation, thresholds, target_dropped=20.0, batch=4)
    table, choice = result["table"], result["choice"]
    assert table["bands"].tolist() == [[1.0, 3.0], [3.0, 5.0], [10.0, 30.0], [100.0, 300.0]]
    assert np.all(np.diff(table["as_depth"], axis=1) >= 0) and np.all(np.diff(table["dropped"], axis=1) <= 0)
    # the rule by brute force over the bands from 3 photons up: least "as depth", then least "dropped", then least t
    worst_a, worst_d = table["as_depth"][1:].max(axis=0), table["dropped"][1:].max(axis=0)
    ok = worst_d <= 20.0
    assert ok.any() and not ok.all()  # the tiny head makes the target bind
    want = min((a, d, t) for a, d, t, o in zip(worst_a, worst_d, table["thresholds"], ok) if o)
    assert (choice["as_depth"], choice["dropped"], choice["no_return_logit"]) == want and choice["met"]
    # the shares at the chosen threshold are those of the model saved with it, band by band
    cal = dataclasses.replace(model.config, no_return_logit=choice["no_return_logit"])
    out = np.asarray(apply_model(model.params, model.state, x, cal))
    k = list(table["thresholds"]).index(choice["no_return_logit"])
    for b, (lo, hi) in enumerate(table["bands"]):
        pick = (validation["photons"] >= lo) & (validation["photons"] < hi)
        o, g = out[pick], gt[pick]
        assert table["as_depth"][b, k] == pytest.approx(100 * np.mean(o[g >= 1] < 0.99))
        assert table["dropped"][b, k] == pytest.approx(100 * np.mean(o[g < 1] >= 0.99))
    assert result["current"]["no_return_logit"] == 0.0
    k0 = list(table["thresholds"]).index(0.0)
    assert result["current"]["dropped"] == pytest.approx(table["dropped"][1:, k0].max())
    with pytest.raises(ValueError, match="no-return head"):
        no_return_outputs(Model(*init_model(jax.random.key(0), ModelConfig(tr=0, **TINY)),
                                ModelConfig(tr=0, **TINY)), x[..., 0])


@pytest.mark.slow
def test_regime_draws_give_each_clips_parameters():
    """regime_draws(key) names the photon level and SNR each clip of make_batch(key) was drawn with."""
    sensor = Sensor(optics=Optics.of_hr((32, 64)))
    regime = PhotonRegime(signal_range=(0.5, 1000.0), snr_range=(20.0, 20.0), irf_paper_prob=1.0, dark_prob=0.0,
                          hot_prob=0.0, dead_prob=0.0, no_return_prob=0.0)
    cfg = dataclasses.replace(TrainConfig(), batch_size=6, patch=None)
    key = jax.random.key(7)
    x, _ = regime_batches(0, cfg, regime, sensor=sensor, inputs=PHOTONS)(key)
    drawn = regime_draws(key, 6, regime)
    assert set(drawn) >= {"mean_signal", "snr"} and drawn["mean_signal"].shape == (6,)
    np.testing.assert_allclose(drawn["snr"], 20.0, rtol=1e-5)
    signal = np.expm1(np.asarray(x[:, 0, ..., 1]) * np.log1p(1000.0)).mean(axis=(1, 2))
    assert np.argsort(signal).tolist() == np.argsort(np.asarray(drawn["mean_signal"])).tolist()


def _script():
    spec = importlib.util.spec_from_file_location("no_return_threshold",
                                                  ROOT / "experiments" / "studies" / "no_return_threshold.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_script_calibrates_and_writes_a_copy(tmp_path, capsys):
    model = _tiny_photon_model(seed=4)
    source = save_model(tmp_path / "tiny.npz", model, card={"steps": 7})
    out = tmp_path / "cal" / "tiny.npz"
    args = ["--model", str(source), "--draws", "3", "--batch", "2", "--frame", "32", "64", "--seed", "5"]
    _script().main(args + ["--write", str(out)])
    text = capsys.readouterr().out
    assert "chosen threshold" in text and "worst dropped %" in text and "<- chosen" in text
    saved = load_model(out)
    meta = read_metadata(out)
    entry = meta["card"]["no_return_calibration"]
    assert meta["storage_dtype"] == "float16" and meta["card"]["steps"] == 7  # the model's own card kept
    assert saved.config == dataclasses.replace(model.config, no_return_logit=entry["no_return_logit"])
    assert entry["draws"] == 3 and entry["seed"] == 5 and entry["target_dropped_pct"] == 2.0
    assert sum(entry["table"]["windows"]) == 3 and json.dumps(entry)
    assert all(lo >= 3.0 for lo, _ in entry["table"]["bands"])
    with pytest.raises(SystemExit, match="exists"):  # refused before any work
        _script().main(args + ["--write", str(out)])
