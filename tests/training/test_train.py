"""Training: Huber's closed form, Adam and the decay boundary by hand, the presets' schedules, a short run that
learns, bit-identical resume (also from a checkpoint of an older version), sharded == unsharded, and the data
sources and validation set of `jaxsr.training.data`."""

import dataclasses
import functools
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxsr.io.checkpoint import load_model, read_metadata, save_tree
from jaxsr.config import PRESETS, ModelConfig, Optics, Sensor, TrainConfig
from jaxsr.training.data import random_crop, sequence_batches, validation_set
from jaxsr.eval.metrics import psnr
from jaxsr.nn import apply_model, apply_model_train, init_model
from jaxsr.training.optim import adam_init, adam_update, step_decay
from jaxsr.scenes import test_sequences
from jaxsr.sensor.forward import calibrate, calibrated_rates, expected_histograms, normalise_depth
from jaxsr.eval.metrics import huber_loss
from jaxsr.training import evaluate, fit, lr_schedule, resume_config

# momentum 0.9: running BN statistics settle within the few dozen steps of these runs (0.99 needs hundreds)
TINY = ModelConfig(tr=1, base=8, growth=4, head=16, filter_hidden=16, bn_momentum=0.9)
LR_SHAPE = (8, 16)


@functools.lru_cache(maxsize=None)
def toy_batches(tr, batch, *, lr_shape=LR_SHAPE, scale=4, noise=0.1):
    """A stand-in data source: a rectangle at a random depth before a far wall (HR), its 4x4 block mean plus
    Gaussian noise in every frame of the window (LR). Pure and jittable, like the real one. One function object
    per setting (cached), so that the tests' runs share their compiled train steps (`fit` caches them per data
    source)."""
    hh, ww = lr_shape[0] * scale, lr_shape[1] * scale
    yy, xx = jnp.mgrid[:hh, :ww]

    def example(key):
        k = jax.random.split(key, 6)
        y0 = jax.random.randint(k[0], (), 0, hh - 8)
        x0 = jax.random.randint(k[1], (), 0, ww - 8)
        h = jax.random.randint(k[2], (), 5, hh // 2)
        w = jax.random.randint(k[3], (), 5, ww // 2)
        d = jax.random.uniform(k[4], (), minval=0.1, maxval=0.6)
        hr = jnp.where((yy >= y0) & (yy < y0 + h) & (xx >= x0) & (xx < x0 + w), d, 0.9)
        lr = hr.reshape(lr_shape[0], scale, lr_shape[1], scale).mean(axis=(1, 3))
        return lr[None] + noise * jax.random.normal(k[5], (2 * tr + 1, *lr_shape)), hr

    def make_batch(key):
        return jax.vmap(example)(jax.random.split(key, batch))

    return make_batch


def toy_validation(tr, n=8):
    windows, gt = jax.jit(toy_batches(tr, n))(jax.random.key(123))  # eagerly, each op compiles alone: 5 s
    return {"windows": windows, "gt": gt, "lr": windows[:, tr], "names": ["toy"]}


def tiny_train_cfg(**kw):
    base = dict(batch_size=4, examples_per_epoch=40, epochs=3, patience=5, decay_epochs=10, lr=3e-3,
                val_frames=8, seed=0)
    return TrainConfig(**{**base, **kw})


# --- loss and optimiser -----------------------------------------------------------------------------------

def test_huber_closed_form_and_grads():
    e = jnp.array([-0.03, -0.01, -0.004, 0.0, 0.002, 0.01, 0.5])
    d = 0.01
    np.testing.assert_allclose(huber_loss(e, jnp.zeros_like(e), delta=d), _huber_closed_form(e, d).mean(), rtol=1e-6)
    # slope: e inside the band, delta * sign(e) outside
    g = jax.grad(lambda p: huber_loss(p, jnp.zeros_like(p), delta=d))(e)
    np.testing.assert_allclose(g * e.size, np.clip(np.asarray(e), -d, d), rtol=1e-5, atol=1e-9)
    with jax.enable_x64(True):
        pred = jnp.array([[0.3, 0.5], [0.2, 0.9]], jnp.float64)  # away from the kinks |e| = delta
        gt = jnp.array([[0.305, 0.1], [0.197, 0.95]], jnp.float64)
        check_grads(lambda p, g: huber_loss(p, g, delta=0.01), (pred, gt), order=2, modes=["fwd", "rev"])


def _huber_closed_form(e, d):
    e = np.abs(np.asarray(e, np.float64))
    return np.where(e <= d, 0.5 * e**2, d * (e - d / 2))


@pytest.mark.slow  # 8-32 s on 2 cores: keeps the default suite under 8 minutes
def test_huber_per_frame_and_in_validation():
    """`axis` averages per frame; `evaluate` reports the same loss as `huber_loss` on the network's output."""
    d = 0.01
    e = np.random.default_rng(0).choice([-0.05, -0.01, -0.003, 0.0, 0.004, 0.02], size=(3, 4, 5))
    got = huber_loss(jnp.asarray(e, jnp.float32), jnp.zeros(e.shape), delta=d, axis=(-2, -1))
    assert got.shape == (3,)
    np.testing.assert_allclose(got, _huber_closed_form(e, d).mean(axis=(1, 2)), rtol=1e-5)
    # 5 frames in chunks of 4: the padded last chunk must not count
    params, state = init_model(jax.random.key(0), TINY)
    val = toy_validation(TINY.tr, n=5)
    hr = jax.jit(apply_model, static_argnames="cfg")(params, state, val["windows"], cfg=TINY)
    res = evaluate(params, state, val["windows"], val["gt"], TINY, delta=d, batch_size=4)
    assert res["loss"] == pytest.approx(float(huber_loss(hr, val["gt"], delta=d)), rel=1e-5)
    assert res["psnr"] == pytest.approx(float(jnp.mean(psnr(hr, val["gt"]))), rel=1e-5)


def test_adam_matches_hand_computation():
    lr, b1, b2, eps = 0.1, 0.9, 0.999, 1e-7
    params = {"a": jnp.array([1.0, -2.0]), "b": [jnp.array(3.0)]}
    g1 = {"a": jnp.array([0.5, -0.2]), "b": [jnp.array(0.0)]}
    g2 = {"a": jnp.array([-1.0, 0.3]), "b": [jnp.array(2.0)]}
    opt = adam_init(params)
    p1, opt = adam_update(g1, opt, params, lr=lr, b1=b1, b2=b2, eps=eps)
    # first step, closed form: p - lr * g / (|g| + eps / sqrt(1 - b2)); zero gradient -> no move
    ga = np.array([0.5, -0.2])
    np.testing.assert_allclose(p1["a"], np.array([1.0, -2.0]) - lr * ga / (np.abs(ga) + eps / np.sqrt(1 - b2)),
                               rtol=1e-6)
    assert float(p1["b"][0]) == 3.0
    p2, opt = adam_update(g2, opt, p1, lr=lr, b1=b1, b2=b2, eps=eps)
    # second step by hand (float64), Keras's form
    m = b1 * (1 - b1) * ga + (1 - b1) * np.array([-1.0, 0.3])
    v = b2 * (1 - b2) * ga**2 + (1 - b2) * np.array([1.0, 0.09])
    alpha = lr * np.sqrt(1 - b2**2) / (1 - b1**2)
    np.testing.assert_allclose(p2["a"], np.asarray(p1["a"], np.float64) - alpha * m / (np.sqrt(v) + eps), rtol=1e-6)
    assert int(opt.count) == 2


def test_step_decay_exactly_at_epoch_boundaries():
    spe = 7
    lr = step_decay(1e-3, factor=0.1, every=10 * spe)
    got = [float(lr(s)) for s in (0, 69, 70, 139, 140)]
    np.testing.assert_allclose(got, [1e-3, 1e-3, 1e-4, 1e-4, 1e-5], rtol=1e-6)
    np.testing.assert_allclose(jax.jit(lr)(70), 1e-4, rtol=1e-6)


def test_random_crop_is_aligned():
    lr = jnp.arange(8 * 16, dtype=jnp.float32).reshape(1, 8, 16)
    hr = jnp.repeat(jnp.repeat(lr[0], 4, 0), 4, 1)
    w, g = random_crop(jax.random.key(3), lr, hr, (4, 6), 4)
    assert w.shape == (1, 4, 6) and g.shape == (16, 24)
    np.testing.assert_array_equal(jnp.repeat(jnp.repeat(w[0], 4, 0), 4, 1), g)


@pytest.mark.slow  # 8-32 s on 2 cores: keeps the default suite under 8 minutes
def test_patch_rates_are_the_crop_of_the_whole_clips():
    """A training patch is simulated alone (`calibrated_rates` with the whole clip's calibration): its rates
    must be that window of `expected_histograms` of the whole clip (the reference, computed whole)."""
    sensor = Sensor()
    h, w = sensor.hr_shape
    rng = np.random.default_rng(0)
    depth = rng.uniform(2.0, 40.0, (2, h, w)).astype(np.float32)
    depth[:, : h // 4] = np.inf  # some sky, so that the calibration differs from the patch's own
    intensity = rng.uniform(0.0, 1.0, (2, h, w)).astype(np.float32)
    full = expected_histograms(depth, intensity, sensor, snr=0.7, mean_signal=3.0)
    alpha, beta = calibrate(depth, intensity, sensor, snr=0.7, mean_signal=3.0)
    y0, x0, ph, pw, r = 5, 9, 16, 32, sensor.scale
    win = (slice(None), slice(y0 * r, (y0 + ph) * r), slice(x0 * r, (x0 + pw) * r))
    part = calibrated_rates(depth[win], intensity[win], alpha, beta, sensor)
    np.testing.assert_allclose(part, full[:, y0 : y0 + ph, x0 : x0 + pw], rtol=1e-5, atol=1e-7)


@pytest.mark.slow  # 8-32 s on 2 cores: keeps the default suite under 8 minutes
def test_patch_batches_align_lr_with_gt():
    """With a patch, the LR windows are drawn for the crop whose GT they return: at a high photon count the
    centre of mass of each LR pixel is its HR block's normalised depth (a shift by one LR pixel would not be)."""
    sensor = Sensor()
    h, w = sensor.lr_shape
    rng = np.random.default_rng(1)
    blocks = rng.uniform(3.0, 30.0, (3, h, w)).astype(np.float32)  # one depth per LR pixel, 3 frames
    depth = np.repeat(np.repeat(blocks, sensor.scale, 1), sensor.scale, 2)
    cfg = dataclasses.replace(PRESETS["cpu"], batch_size=3, snr_range=(1e3, 1e3), mean_signal_range=(1e4, 1e4))
    windows, gt = jax.jit(sequence_batches(depth, np.ones_like(depth), 1, cfg, sensor=sensor))(jax.random.key(2))
    assert windows.shape == (3, 3, *cfg.patch) and gt.shape == (3, cfg.patch[0] * 4, cfg.patch[1] * 4)
    err = np.abs(np.asarray(windows[:, 1]) - np.asarray(gt[:, ::4, ::4]))
    assert np.median(err) < 0.01, np.median(err)


# What the scaled-down presets may change (config.PRESETS: "sized so that ...", "scaled down with the epochs"):
# the amount of data and epochs, the schedule with them, crops, and the validation length. Never the loss,
# the optimiser, the data distribution or the seed.
SCALED_DOWN = {"examples_per_epoch", "epochs", "patience", "decay_epochs", "patch", "val_frames"}


def test_paper_preset_follows_the_paper():
    """15500 examples in batches of 4 per epoch; lr 1e-3 cut to 1e-4 exactly at the first step of epoch 11,
    to 1e-5 at epoch 21 (1-based), through the schedule the train step uses."""
    cfg = PRESETS["paper"]
    spe = cfg.steps_per_epoch
    assert spe * cfg.batch_size == 15500 and cfg.batch_size == 4
    lr = lr_schedule(cfg)

    def first_step(epoch):  # of a 1-based epoch
        return (epoch - 1) * spe

    got = [float(lr(s)) for s in (first_step(1), first_step(10), first_step(11) - 1, first_step(11),
                                  first_step(20), first_step(21))]
    np.testing.assert_allclose(got, [1e-3, 1e-3, 1e-3, 1e-4, 1e-4, 1e-5], rtol=1e-6)
    assert (cfg.huber_delta, cfg.epochs, cfg.patience) == (0.01, 100, 5)


@pytest.mark.parametrize("name", ["cpu", "bundle", "long"])
def test_scaled_presets_change_only_the_amount_of_training(name):
    cfg, paper = PRESETS[name], PRESETS["paper"]
    differ = {f.name for f in dataclasses.fields(TrainConfig) if getattr(cfg, f.name) != getattr(paper, f.name)}
    assert differ <= SCALED_DOWN, differ - SCALED_DOWN
    # the schedule scaled with the epochs: one cut, before the last epoch; early stopping can still act
    lr, spe = lr_schedule(cfg), cfg.steps_per_epoch
    assert float(lr(cfg.decay_epochs * spe - 1)) == pytest.approx(cfg.lr)
    assert float(lr(cfg.epochs * spe - 1)) == pytest.approx(cfg.lr * cfg.lr_decay)
    assert cfg.patience < cfg.epochs
    # the crops fit the sensor's LR frame (random_crop refuses larger ones)
    assert all(p <= s for p, s in zip(cfg.patch, Sensor().lr_shape))


@pytest.mark.parametrize("change,message", [
    ({"batch_size": 8, "examples_per_epoch": 4}, "examples_per_epoch >= batch_size"),
    ({"batch_size": 0}, "batch_size >= 1"),
    ({"epochs": 0}, "epochs, patience and decay_epochs must be >= 1"),
    ({"patience": 0}, "epochs, patience and decay_epochs must be >= 1"),
    ({"decay_epochs": 0}, "epochs, patience and decay_epochs must be >= 1"),
    ({"snr_range": (2.0, 1.0)}, r"snr_range must be 0 < lo <= hi, got \(2.0, 1.0\)"),
    ({"snr_range": (0.0, 1.0)}, "snr_range must be 0 < lo <= hi"),
    ({"mean_signal_range": (28.0, 7.0)}, "mean_signal_range must be 0 < lo <= hi"),
])
def test_train_config_refuses_inconsistent_settings(change, message):
    with pytest.raises(ValueError, match=message):
        TrainConfig(**change)


# --- fitting ----------------------------------------------------------------------------------------------

@pytest.mark.slow  # 8-32 s on 2 cores: keeps the default suite under 8 minutes
def test_short_run_learns_and_beats_bicubic(tmp_path):
    from jaxsr.baselines.interpolation import bicubic

    cfg = tiny_train_cfg(epochs=3, examples_per_epoch=400)
    val = toy_validation(TINY.tr)
    model, history = fit(TINY, cfg, out=tmp_path, make_batch=toy_batches(TINY.tr, 4), validation=val, progress=False)
    assert len(history) == 3
    assert history[-1]["train_loss"] < 0.75 * history[0]["train_loss"], history
    assert min(r["val_loss"] for r in history[1:]) < history[0]["val_loss"]
    bicubic_psnr = float(jnp.mean(psnr(bicubic(val["lr"], scale=4), val["gt"])))
    best = min(history, key=lambda r: r["val_loss"])
    assert best["val_psnr"] > bicubic_psnr + 1.0, (best["val_psnr"], bicubic_psnr)
    # logs and checkpoints
    lines = (tmp_path / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(l)["epoch"] for l in lines] == [1, 2, 3]
    loaded = load_model(tmp_path / "best.npz")
    for a, b in zip(jax.tree_util.tree_leaves(model), jax.tree_util.tree_leaves(loaded)):
        np.testing.assert_array_equal(a, b)
    card = read_metadata(tmp_path / "best.npz")["card"]
    assert card["steps"] >= cfg.steps_per_epoch and card["validation"]["psnr"] == pytest.approx(best["val_psnr"])
    assert card["hardware"]["backend"] == "cpu" and card["train_config"]["lr"] == cfg.lr


class Killed(Exception):
    pass


def _add_legacy_conv3d_impl(path):
    """Rewrite a checkpoint's metadata as older jaxsr wrote it: `conv3d_impl` in the model config, no sums or time
    of an unfinished epoch in the run."""
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["__metadata__"]))
    meta["config"]["conv3d_impl"] = "auto"
    for key in ("epoch_loss_sum", "epoch_psnr_sum", "epoch_train_s"):
        del meta["run"][key]
    arrays["__metadata__"] = np.array(json.dumps(meta))
    np.savez(path, **arrays)


def test_a_folder_holding_a_run_is_refused_without_resume_or_overwrite(tmp_path):
    # the kill tests' steps and schedule (shared compiled train step), one epoch
    cfg = tiny_train_cfg(examples_per_epoch=12, epochs=1, decay_epochs=1)
    val = toy_validation(TINY.tr, n=4)
    make_batch = toy_batches(TINY.tr, 4)
    fit(TINY, cfg, out=tmp_path, make_batch=make_batch, validation=val, progress=False)
    files = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert set(files) == {"metrics.jsonl", "best.npz", "last.npz"}
    with pytest.raises(FileExistsError, match=r"holds a training run .*resume=True \(--resume\).*overwrite=True"):
        fit(TINY, cfg, out=tmp_path, make_batch=make_batch, validation=val, progress=False)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == files  # nothing replaced
    with pytest.raises(ValueError, match="exclude each other"):
        fit(TINY, cfg, out=tmp_path, make_batch=make_batch, validation=val, progress=False, resume=True,
            overwrite=True)
    fit(TINY, dataclasses.replace(cfg, seed=1), out=tmp_path, make_batch=make_batch, validation=val, progress=False,
        overwrite=True)
    assert (tmp_path / "best.npz").read_bytes() != files["best.npz"]


@pytest.mark.slow  # 8-32 s on 2 cores: keeps the default suite under 8 minutes
def test_a_run_that_diverges_keeps_the_run_it_was_to_replace(tmp_path):
    """A non-finite loss stops the run at once with a clear error; with --force over a good run, the good run's
    files stay as they were (they are set aside at the new run's first save, and put back)."""
    from jaxsr.training.epochs import TrainingDiverged

    cfg = tiny_train_cfg(examples_per_epoch=12, epochs=1, decay_epochs=1)
    val = toy_validation(TINY.tr, n=4)
    fit(TINY, cfg, out=tmp_path, make_batch=toy_batches(TINY.tr, 4), validation=val, progress=False)
    files = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    nan_batches = toy_batches(TINY.tr, 4, noise=float("nan"))
    with pytest.raises(TrainingDiverged, match="the loss of step 1 is nan"):
        fit(TINY, cfg, out=tmp_path, make_batch=nan_batches, validation=val, progress=False, overwrite=True,
            checkpoint_every_s=0.0)  # a save after every step: the good run is set aside first
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == files


def test_a_diverged_run_puts_back_the_run_it_set_aside(tmp_path):
    """What a run that diverged leaves: the replaced run back in place of its own files where it set one aside;
    everything as it is otherwise (a resumed run's earlier files, a fresh run's finite saves)."""
    from jaxsr.training.loop import REPLACED_FOLDER, _keep_what_was_there

    (tmp_path / REPLACED_FOLDER).mkdir()
    (tmp_path / REPLACED_FOLDER / "best.npz").write_bytes(b"good")
    (tmp_path / "resume.npz").write_bytes(b"new")
    _keep_what_was_there(tmp_path)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == {"best.npz": b"good"}
    (tmp_path / "resume.npz").write_bytes(b"a resumed run's")
    _keep_what_was_there(tmp_path)
    assert {p.name for p in tmp_path.iterdir()} == {"best.npz", "resume.npz"}


def test_resume_refuses_a_run_without_its_train_state_and_a_folder_without_a_run(tmp_path):
    """best.npz and metrics.jsonl without last.npz / resume.npz: resuming would start over and replace them. The
    CLI path (`train`) also refuses --resume where there is nothing to resume; fit itself (scripts that always
    resume) starts afresh in a folder with no run files. All refused before any work."""
    from jaxsr.cli import main
    from jaxsr.training import train

    for name in ("best.npz", "metrics.jsonl"):
        (tmp_path / name).write_bytes(b"the only copy")
    with pytest.raises(FileExistsError, match=r"holds a run without its train state .*--force\) starts over"):
        fit(TINY, tiny_train_cfg(), out=tmp_path, make_batch=toy_batches(TINY.tr, 4), validation={}, resume=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["best.npz", "metrics.jsonl"]
    assert (tmp_path / "best.npz").read_bytes() == b"the only copy"
    for out in (tmp_path / "missing", tmp_path / "empty"):
        (tmp_path / "empty").mkdir(exist_ok=True)
        with pytest.raises(FileNotFoundError, match="nothing to resume"):
            train(out, tr=0, resume=True, progress=False)
    assert not (tmp_path / "missing").exists() and not any((tmp_path / "empty").iterdir())
    assert main(["train", "--tr", "0", "--output", str(tmp_path / "missing"), "--resume", "--no-progress"]) == 2


def test_resuming_a_run_that_has_its_epochs_warns_that_there_is_nothing_to_train(tmp_path, monkeypatch, capsys):
    import jaxsr.cli.train as cli_train
    import jaxsr.training.loop as loop
    from jaxsr.cli import main
    from jaxsr.training.run_state import _Run

    real = loop._start_or_resume  # as the loop calls it

    def two_epochs_done(*args, **kw):  # the saved run of a 2-epoch fit, without training one
        ts, _ = real(*args, **dict(kw, resume=False))
        return ts, _Run(epoch=2, step=2 * tiny_train_cfg().steps_per_epoch, finished=False)

    monkeypatch.setattr(loop, "_start_or_resume", two_epochs_done)
    with pytest.warns(UserWarning, match=r"already has 2 epochs \(epochs=1\); nothing to train: give more epochs"):
        _, history = fit(TINY, tiny_train_cfg(epochs=1), out=tmp_path, make_batch=toy_batches(TINY.tr, 4),
                         validation={}, progress=False, resume=True)
    assert history == [] and not any(tmp_path.iterdir())  # nothing written, and the lock released
    # the CLI says it on one line, exit 0
    monkeypatch.setattr(cli_train, "train", lambda *a, **k: (__import__("warnings").warn("the run in X already has "
                        "2 epochs (epochs=1); nothing to train", stacklevel=2), (None, []))[1])
    assert main(["train", "--output", str(tmp_path), "--resume", "--epochs", "1", "--no-progress"]) == 0
    assert capsys.readouterr().err == ("jaxsr train: warning: the run in X already has 2 epochs (epochs=1); nothing "
                                       "to train\n")


def test_a_second_run_on_a_locked_folder_fails_at_once(tmp_path):
    """Two runs on one folder would overwrite each other's files: fit holds OUT/.lock (flock) while it runs."""
    from jaxsr.io.files import LOCK_FILE, folder_lock

    with folder_lock(tmp_path, what="training run"):
        assert (tmp_path / LOCK_FILE).exists()
        with pytest.raises(FileExistsError, match=f"{tmp_path} is in use by another run .*{LOCK_FILE}"):
            with folder_lock(tmp_path):
                pass
        with pytest.raises(FileExistsError, match="in use by another training run"):
            fit(TINY, tiny_train_cfg(), out=tmp_path, make_batch=toy_batches(TINY.tr, 4), validation={})
        # another process too
        code = f"from jaxsr.io.files import folder_lock\nwith folder_lock({str(tmp_path)!r}): pass"
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
        assert done.returncode == 1 and "is in use by another run" in done.stderr
    assert not (tmp_path / LOCK_FILE).exists()
    with folder_lock(tmp_path):  # released: free again
        pass


def test_kill_and_resume_equals_uninterrupted(tmp_path):
    # decay every epoch and patience 1 so the schedule and the early-stopping counters cross the restart
    cfg = tiny_train_cfg(examples_per_epoch=12, epochs=4, decay_epochs=1, patience=2)
    val = toy_validation(TINY.tr, n=4)
    make_batch = toy_batches(TINY.tr, 4)
    ref, ref_hist = fit(TINY, cfg, out=tmp_path / "a", make_batch=make_batch, validation=val, progress=False)

    def kill_after_2(record):
        if record["epoch"] == 2:
            raise Killed

    with pytest.raises(Killed):
        fit(TINY, cfg, out=tmp_path / "b", make_batch=make_batch, validation=val, progress=False, callback=kill_after_2)
    _add_legacy_conv3d_impl(tmp_path / "b" / "last.npz")  # as written before conv3d_impl left ModelConfig
    got, hist = fit(TINY, cfg, out=tmp_path / "b", make_batch=make_batch, validation=val, progress=False, resume=True)
    for a, b in zip(jax.tree_util.tree_leaves(ref), jax.tree_util.tree_leaves(got)):
        np.testing.assert_array_equal(a, b)
    strip = lambda h: [{k: v for k, v in r.items() if "time" not in k and "per_s" not in k} for r in h]
    assert strip(hist) == strip(ref_hist)
    assert [r["lr"] for r in ref_hist][:3] == pytest.approx([3e-3, 3e-4, 3e-5])
    last_a = read_metadata(tmp_path / "a" / "last.npz")["run"]
    last_b = read_metadata(tmp_path / "b" / "last.npz")["run"]
    assert {k: v for k, v in last_a.items() if k not in ("wall_time_s", "history")} == \
        {k: v for k, v in last_b.items() if k not in ("wall_time_s", "history")}
    # a run given a larger epoch budget later continues exactly like one that had it from the start
    fit(TINY, dataclasses.replace(cfg, epochs=2), out=tmp_path / "c", make_batch=make_batch, validation=val,
        progress=False)
    extended, ext_hist = fit(TINY, cfg, out=tmp_path / "c", make_batch=make_batch, validation=val, progress=False,
                             resume=True)
    for a, b in zip(jax.tree_util.tree_leaves(ref), jax.tree_util.tree_leaves(extended)):
        np.testing.assert_array_equal(a, b)
    assert strip(ext_hist) == strip(ref_hist)
    # any other change of settings cannot resume this run, and the error names it
    with pytest.raises(ValueError, match=r"cannot resume .*train\.lr"):
        fit(TINY, dataclasses.replace(cfg, lr=1.0), out=tmp_path / "b", make_batch=make_batch, validation=val,
            progress=False, resume=True)


def test_a_run_killed_inside_an_epoch_resumes_from_its_last_checkpoint(tmp_path, monkeypatch):
    """checkpoint_every_s=0 saves the state after every step (resume.npz inside an epoch, last.npz at its end); a
    run killed just after a save resumes there and ends bit-identical to the uninterrupted run, logging the same
    epochs. Also a run started over an old one (overwrite) and killed inside its first epoch."""
    import jaxsr.training.run_state as train_mod

    cfg = tiny_train_cfg(examples_per_epoch=12, epochs=3, decay_epochs=1, patience=3)
    spe = cfg.steps_per_epoch
    val = toy_validation(TINY.tr, n=4)
    make_batch = toy_batches(TINY.tr, 4)
    ref, ref_hist = fit(TINY, cfg, out=tmp_path / "a", make_batch=make_batch, validation=val, progress=False)
    strip = lambda h: [{k: v for k, v in r.items() if "time" not in k and "per_s" not in k} for r in h]
    real_save = train_mod._save_state

    def killed_at(step, saved):
        def save_then_kill(path, ts, run, settings, card):
            real_save(path, ts, run, settings, card)
            saved.append((path.name, run.step))
            if run.step == step:
                raise Killed
        return save_then_kill

    def resume_and_compare(out):
        got, hist = fit(TINY, cfg, out=out, make_batch=make_batch, validation=val, progress=False, resume=True,
                        checkpoint_every_s=None)
        for a, b in zip(jax.tree_util.tree_leaves(ref), jax.tree_util.tree_leaves(got)):
            np.testing.assert_array_equal(a, b)
        assert strip(hist) == strip(ref_hist)  # a resumed epoch's train loss and PSNR are over all its steps
        assert sorted(p.name for p in out.iterdir()) == ["best.npz", "last.npz", "metrics.jsonl"]
        return hist

    saved = []
    monkeypatch.setattr(train_mod, "_save_state", killed_at(spe + 2, saved))
    with pytest.raises(Killed):
        fit(TINY, cfg, out=tmp_path / "b", make_batch=make_batch, validation=val, progress=False,
            checkpoint_every_s=0)
    # inside epoch 1 after steps 1 and 2, its end (3), inside epoch 2 after step 4, then 5: killed
    assert saved == [("resume.npz", 1), ("resume.npz", 2), ("last.npz", spe), ("resume.npz", spe + 1),
                     ("resume.npz", spe + 2)]
    meta = read_metadata(tmp_path / "b" / "resume.npz")
    assert meta["run"]["step"] == spe + 2 and meta["run"]["epoch"] == 1 and meta["card"]["steps"] == spe + 2
    assert meta["run"]["epoch_loss_sum"] > 0 and meta["run"]["epoch_train_s"] > 0
    assert read_metadata(tmp_path / "b" / "last.npz")["run"]["step"] == spe  # the epoch's end stays apart
    monkeypatch.setattr(train_mod, "_save_state", real_save)
    assert resume_config(tmp_path / "b", cfg) == cfg
    hist = resume_and_compare(tmp_path / "b")
    assert hist[1]["epoch_time_s"] > meta["run"]["epoch_train_s"]
    last = read_metadata(tmp_path / "b" / "last.npz")["run"]
    assert last["step"] == 3 * spe and last["epoch_loss_sum"] == last["epoch_train_s"] == 0.0

    # a new run in place of an old one: the old run's files are set aside (.replaced) at its first save, so a kill
    # inside its first epoch leaves the new run's state beside them, resuming continues the new run, and its first
    # epoch's end removes them
    saved = []
    fit(TINY, dataclasses.replace(cfg, seed=1, epochs=1), out=tmp_path / "c", make_batch=make_batch, validation=val,
        progress=False)
    monkeypatch.setattr(train_mod, "_save_state", killed_at(2, saved))
    with pytest.raises(Killed):
        fit(TINY, cfg, out=tmp_path / "c", make_batch=make_batch, validation=val, progress=False, overwrite=True,
            checkpoint_every_s=0)
    assert sorted(p.name for p in (tmp_path / "c").iterdir()) == [".replaced", "resume.npz"]
    monkeypatch.setattr(train_mod, "_save_state", real_save)
    resume_and_compare(tmp_path / "c")
    assert not (tmp_path / "c" / ".replaced").exists()


def _with_tests_folder(pythonpath):
    """PYTHONPATH with this tests folder first, for a subprocess that imports a test module."""
    return os.pathsep.join([str(Path(__file__).parent), *filter(None, [pythonpath])])


_SHARDED_SCRIPT = textwrap.dedent(
    """
    import os, json
    os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
    import jax, numpy as np
    from test_train import TINY, toy_batches, tiny_train_cfg
    from jaxsr.nn import init_model
    from jaxsr.training.optim import adam_init
    from jaxsr.training import data_mesh, make_train_step
    assert jax.device_count() == 2, jax.devices()
    cfg = tiny_train_cfg()
    make_batch = toy_batches(TINY.tr, cfg.batch_size)
    out = []
    for mesh in (None, data_mesh()):
        params, state = init_model(jax.random.key(0), TINY)
        opt = adam_init(params)
        step = make_train_step(TINY, cfg, make_batch, mesh=mesh)
        losses = []
        for i in range(3):
            params, state, opt, m = step(params, state, opt, jax.random.key(i), i)
            losses.append(float(m["loss"]))
        out.append((jax.tree_util.tree_leaves((params, state)), losses))
    (a, la), (b, lb) = out
    err = max(float(np.max(np.abs(np.asarray(x) - np.asarray(y)))) for x, y in zip(a, b))
    sharded = str(b[0].sharding)
    print(json.dumps(dict(err=err, la=la, lb=lb, sharding=sharded)))
    """
)


@pytest.mark.slow  # a subprocess with 2 host devices compiles two train steps: about 40 s on 2 busy cores
def test_sharded_equals_single_device():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu",
               PYTHONPATH=_with_tests_folder(os.environ.get("PYTHONPATH")))  # the script imports test_train
    proc = subprocess.run([sys.executable, "-c", _SHARDED_SCRIPT], capture_output=True,
                          text=True, env=env, timeout=300, cwd=str(Path(__file__).resolve().parents[2]))
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    np.testing.assert_allclose(res["la"], res["lb"], rtol=1e-4)
    assert res["err"] < 1e-4, res


@pytest.mark.slow  # two gradient compilations; tests/nn/test_layers.py checks the layer's gradients fast
def test_stacked_layers_gradients_through_the_taps_equal_the_stacked_ones(monkeypatch):
    """`layers.STACKED_GRADIENT` ("taps", the faster one in training) changes how the gradients of the layers
    that conv3d(impl="auto") stacks are computed, not what they are: the train loss's gradients agree with the
    stacked form's own to float32 rounding (TR1's 3-frame "same" blocks are stacked on CPU)."""
    from jaxsr.nn import layers

    windows, gt = toy_batches(1, 2)(jax.random.key(3))
    params, state = init_model(jax.random.key(4), TINY)

    def grads(how):
        monkeypatch.setattr(layers, "STACKED_GRADIENT", how)

        def loss(p):
            return huber_loss(apply_model_train(p, state, windows, TINY)[0], gt)

        return jax.tree_util.tree_leaves(jax.jit(jax.grad(loss))(params))

    assert layers.stacked_use(3, "same") >= layers.STACKED_MIN_USE  # the stacked path is the one compared
    new, old = grads("taps"), grads("stacked")
    # biases before a batch norm have a gradient of exactly 0 (rounding noise ~1e-11): tolerance from the largest
    scale = max(float(jnp.max(jnp.abs(b))) for b in old)
    for a, b in zip(new, old):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6 * scale)


# --- data sources -----------------------------------------------------------------------------------------

@pytest.mark.slow  # 8-32 s on 2 cores: keeps the default suite under 8 minutes
def test_sequence_batches_from_hr_arrays():
    sensor = Sensor(optics=Optics.of_hr((16, 32)))
    rng = np.random.default_rng(0)
    depth = np.full((2, 6, 16, 32), 10.0, np.float32)
    depth[:, :, :, 16:] = 20.0
    depth[1, :, :4] = np.inf  # sky: no return
    intensity = rng.uniform(0.3, 1.0, depth.shape).astype(np.float32)
    cfg = tiny_train_cfg(batch_size=3, snr_range=(50.0, 50.0), mean_signal_range=(500.0, 500.0))
    make_batch = jax.jit(sequence_batches(depth, intensity, 2, cfg, sensor=sensor))
    windows, gt = make_batch(jax.random.key(0))
    assert windows.shape == (3, 5, 4, 8) and gt.shape == (3, 16, 32)
    g = np.asarray(gt).ravel()
    assert np.all(np.min(np.abs(g[:, None] - np.array([10 / 35, 20 / 35, 1.0])), axis=1) < 1e-6)
    # plenty of photons: centre of mass within half a bin (1/32) of the truth away from the edge column
    w = np.asarray(windows)
    np.testing.assert_allclose(w[:, :, 1:, :3], 10 / 35, atol=1 / 32)
    np.testing.assert_allclose(w[:, :, 1:, 5:], 20 / 35, atol=1 / 32)
    with pytest.raises(ValueError, match="fewer than the window"):
        sequence_batches(depth[:, :3], intensity[:, :3], 2, cfg, sensor=sensor)
    with pytest.raises(ValueError, match="equal shape"):
        sequence_batches(depth, intensity[..., :16], 2, cfg, sensor=sensor)


@pytest.mark.slow  # renders the validation sequences (16 s)
def test_validation_set_from_the_named_sequences():
    """The default validation data: the first frames of the scenes module's named validation sequences."""
    cfg = dataclasses.replace(PRESETS["cpu"], val_frames=2)
    sensor = Sensor()
    val = validation_set(jax.random.key(0), 1, cfg)
    n = 2 * len(cfg.val_sequences)
    assert (val["windows"].shape == (n, 3, 32, 64) and val["gt"].shape == (n, 128, 256)
            and val["lr"].shape == (n, 32, 64))
    assert val["names"] == list(cfg.val_sequences)
    # GT: each named sequence's first val_frames frames, normalised, in the order of val_sequences
    seqs = test_sequences(n_frames=2, names=cfg.val_sequences, sensor=sensor)
    expect = np.concatenate([np.asarray(normalise_depth(seqs[name].depth[:2], sensor)) for name in val["names"]])
    np.testing.assert_array_equal(val["gt"], expect)
    # windows: centred on the LR frames, edge-replicated within each sequence (no frame of a neighbour)
    w, lr = np.asarray(val["windows"]), np.asarray(val["lr"])
    np.testing.assert_array_equal(w[:, 1], lr)
    np.testing.assert_array_equal(w[0::2, 0], lr[0::2])  # first frame of each sequence: its own frame before
    np.testing.assert_array_equal(w[1::2, 2], lr[1::2])  # last frame: its own frame after
    np.testing.assert_array_equal(w[0::2, 2], lr[1::2])


@pytest.mark.slow  # simulates a validation set at two SNRs (10 s)
def test_validation_set_simulates_each_sequence_at_its_own_snr():
    """The same flat wall at SNR 1000 and 0.01: centre of mass finds it in the first; in the second the ambient
    light often hides the peak (errors of a tenth of the range). Sequences may be dicts or objects with fields."""
    sensor = Sensor(optics=Optics.of_hr((16, 32)))
    depth = np.full((3, 16, 32), 10.0, np.float32)
    intensity = np.full_like(depth, 0.8)
    seqs = {"clear": {"depth": depth, "intensity": intensity, "snr": 1000.0},
            "murky": SimpleNamespace(depth=depth, intensity=intensity, snr=0.01)}
    cfg = dataclasses.replace(PRESETS["cpu"], val_frames=2, val_sequences=("murky", "clear"), val_mean_signal=50.0)
    val = validation_set(jax.random.key(0), 0, cfg, sensor=sensor, sequences=seqs)
    assert val["names"] == ["murky", "clear"] and val["lr"].shape == (4, 4, 8)
    np.testing.assert_allclose(val["gt"], 10 / 35, rtol=1e-6)
    err = np.abs(np.asarray(val["lr"]) - 10 / 35)
    assert err[2:].max() < 1 / 32, err[2:].max()  # within half a bin (1/16 of the range)
    assert err[:2].mean() > 10 * err[2:].mean(), (err[:2].mean(), err[2:].mean())


@pytest.mark.slow
def test_train_command_end_to_end(tmp_path):
    """`jaxsr train` with the default scene data for one epoch of the cpu preset, then resume to epoch 2."""
    from jaxsr.cli import main

    out = tmp_path / "tr0"
    assert main(["train", "--tr", "0", "--preset", "cpu", "--epochs", "1", "--output", str(out), "--no-progress"]) == 0
    assert (out / "best.npz").exists() and (out / "last.npz").exists()
    assert main(["train", "--tr", "0", "--preset", "cpu", "--epochs", "2", "--output", str(out), "--no-progress",
                 "--resume"]) == 0
    lines = (out / "metrics.jsonl").read_text().splitlines()
    assert len(lines) == 2


def test_a_run_resumes_with_the_validation_it_started_with(tmp_path):
    # runs begun before the presets' validation changed keep theirs (fit refuses other settings); new runs get
    # today's
    cfg = PRESETS["paper"]
    assert resume_config(tmp_path, cfg) is cfg
    old = ["val1_street", "val2_road", "val3_courtyard"]
    save_tree(tmp_path / "last.npz", {"x": np.zeros(1)},
              {"kind": "train_state", "train_config": {"val_sequences": old}})
    resumed = resume_config(tmp_path, cfg)
    assert resumed.val_sequences == tuple(old) and dataclasses.replace(resumed, val_sequences=cfg.val_sequences) == cfg


def test_a_run_saved_before_a_train_setting_existed_resumes_with_its_default(tmp_path):
    """A train state written before `TrainConfig.precision` existed (its train_config lacks the field) matches a
    resume at the field's default; a real difference is still named."""
    from jaxsr.training.run_state import _check_resumable, _settings

    cfg, train_cfg = ModelConfig(tr=0), TrainConfig()
    settings = _settings(cfg, train_cfg, 0)
    old = {k: v for k, v in settings["train_config"].items() if k != "precision"}
    meta = {"kind": "train_state", "architecture": "duf", "config": settings["config"], "train_config": old}
    _check_resumable(tmp_path / "last.npz", meta, settings)
    with pytest.raises(ValueError, match="train.precision"):
        _check_resumable(tmp_path / "last.npz", meta,
                         _settings(cfg, dataclasses.replace(train_cfg, precision="bfloat16"), 0))
