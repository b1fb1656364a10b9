"""Stacked runs (`fit(seeds=...)`, `jaxsr train --seeds`): several seeds of one network in one vmapped step, seed k
equal to the run of seed k alone, each in its own run folder with its own card, resume and early stopping."""

import contextlib
import dataclasses
import json
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))  # the tiny network and toy data of test_train
from test_train import TINY, Killed, tiny_train_cfg, toy_batches, toy_validation  # noqa: E402

import jaxsr.training.recipes as recipes  # noqa: E402
from jaxsr import cli  # noqa: E402
from jaxsr.io.checkpoint import read_metadata  # noqa: E402
from jaxsr.training import fit, seed_folder  # noqa: E402

# 3 steps an epoch, the rate cut after each, so that the schedule crosses the epochs; validation built from each
# seed's own key (validation=None), as a real run's
CFG = tiny_train_cfg(examples_per_epoch=12, epochs=2, decay_epochs=1, val_frames=2)
MAKE_BATCH = toy_batches(TINY.tr, 4)
SEEDS = [0, 1]
RUN = ["best.npz", "last.npz", "metrics.jsonl"]


def leaves(model):
    return [np.asarray(a) for a in jax.tree_util.tree_leaves((model.params, model.state))]


def strip(history):
    """A history without its timings (which differ from run to run)."""
    return [{k: v for k, v in r.items() if "time" not in k and "per_s" not in k} for r in history]


@pytest.fixture(scope="module")
def stacked(tmp_path_factory):
    """A stacked run of seeds 0 and 1, uninterrupted: (its folder, fit's result, the records its callback got)."""
    out = tmp_path_factory.mktemp("stacked") / "runs"
    told = []
    on_cpu = jax.default_backend() == "cpu"
    with pytest.warns(UserWarning, match="stacked on CPU train slower") if on_cpu else contextlib.nullcontext():
        result = fit(TINY, CFG, out=out, seeds=SEEDS, make_batch=MAKE_BATCH, progress=False, callback=told.append)
    return out, result, told


@pytest.mark.slow  # the stacked fixture trains 2 seeds twice (18 s)
def test_each_seed_of_a_stacked_run_equals_its_run_alone(stacked, tmp_path):
    out, result, told = stacked
    assert sorted(result) == SEEDS
    for seed in SEEDS:
        alone, history = fit(TINY, dataclasses.replace(CFG, seed=seed), out=tmp_path / f"alone{seed}",
                             make_batch=MAKE_BATCH, progress=False)
        model, stacked_history = result[seed]
        for a, b in zip(leaves(model), leaves(alone)):
            np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
        for got, want in zip(strip(stacked_history), strip(history), strict=True):
            assert got.keys() == want.keys()
            assert got == pytest.approx(want, rel=1e-4, abs=1e-6)
    # the seeds differ from each other: their own initial weights and data
    assert not np.allclose(leaves(result[0][0])[0], leaves(result[1][0])[0])
    assert [(r["seed"], r["epoch"]) for r in told] == [(0, 1), (1, 1), (0, 2), (1, 2)]


@pytest.mark.slow  # the stacked fixture (18 s)
def test_each_seed_has_its_own_run_folder_and_card(stacked):
    out, result, _ = stacked
    assert sorted(p.name for p in out.iterdir()) == ["seed0", "seed1"]
    for seed in SEEDS:
        folder = seed_folder(out, seed)
        assert folder == out / f"seed{seed}"
        assert sorted(p.name for p in folder.iterdir()) == RUN  # the lock released
        card = read_metadata(folder / "last.npz")["card"]
        assert card["seed"] == seed and card["stacked_seeds"] == SEEDS and card["steps"] == 2 * CFG.steps_per_epoch
        assert card["train_config"]["seed"] == seed
        lines = [json.loads(line) for line in (folder / "metrics.jsonl").read_text().splitlines()]
        assert strip(lines) == strip(result[seed][1])
    # a seed's folder is a run folder: resumable alone (nothing left to train), and refused as a new run
    with pytest.warns(UserWarning, match="already has 2 epochs"):
        fit(TINY, dataclasses.replace(CFG, seed=1), out=seed_folder(out, 1), make_batch=MAKE_BATCH, progress=False,
            resume=True)
    with pytest.raises(FileExistsError, match=r"seed1 holds a training run"):
        fit(TINY, CFG, out=out, seeds=[1, 2], make_batch=MAKE_BATCH, progress=False)
    assert not (out / "seed2").exists() or not any((out / "seed2").iterdir())
    with pytest.raises(FileExistsError, match="a stacked run trains each seed in a folder inside out"):
        fit(TINY, CFG, out=seed_folder(out, 0), seeds=[5], make_batch=MAKE_BATCH, progress=False)


@pytest.mark.slow  # 10-18 s: keeps the default suite under 8 minutes on 2 cores
def test_one_seed_trains_unstacked_in_its_folder(tmp_path, recwarn):
    told = []
    result = fit(TINY, dataclasses.replace(CFG, epochs=1), out=tmp_path, seeds=[5], make_batch=MAKE_BATCH,
                 validation=toy_validation(TINY.tr, n=2), progress=False, callback=told.append)
    assert list(result) == [5] and [r["seed"] for r in told] == [5]
    assert read_metadata(seed_folder(tmp_path, 5) / "last.npz")["card"]["stacked_seeds"] == [5]
    assert not [w for w in recwarn if "stacked on CPU" in str(w.message)]


@pytest.mark.parametrize("seeds,message", [
    ([], "at least one"), ([0, 0], "0 more than once"), ([-1], "integers 0..2"), ("0,1", "a list of integers"),
    ([1.5], "integers 0..2"),
])
def test_bad_seeds_are_refused(tmp_path, seeds, message):
    with pytest.raises(ValueError, match=message):
        fit(TINY, CFG, out=tmp_path / "x", seeds=seeds, make_batch=MAKE_BATCH, progress=False)
    assert not (tmp_path / "x").exists()


@pytest.mark.slow  # the stacked fixture and 2 runs
def test_a_stacked_run_killed_between_its_seeds_resumes_to_the_uninterrupted_one(stacked, tmp_path):
    """Killed after seed 0 saved epoch 2, before seed 1 did: seed 1 resumes from epoch 1 and trains epoch 2 alone
    (seed 0 masked: it waits), and both end as the uninterrupted stacked run."""
    _, want, _ = stacked

    def kill(record):
        if record["seed"] == 0 and record["epoch"] == 2:
            raise Killed

    with pytest.raises(Killed):
        fit(TINY, CFG, out=tmp_path, seeds=SEEDS, make_batch=MAKE_BATCH, progress=False, callback=kill)
    assert [read_metadata(seed_folder(tmp_path, s) / "last.npz")["run"]["epoch"] for s in SEEDS] == [2, 1]
    got = fit(TINY, CFG, out=tmp_path, seeds=SEEDS, make_batch=MAKE_BATCH, progress=False, resume=True)
    for seed in SEEDS:
        for a, b in zip(leaves(got[seed][0]), leaves(want[seed][0])):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
        for got_record, want_record in zip(strip(got[seed][1]), strip(want[seed][1]), strict=True):
            assert got_record == pytest.approx(want_record, rel=1e-5)
        last = read_metadata(seed_folder(tmp_path, seed) / "last.npz")["run"]
        assert last["epoch"] == 2 and last["step"] == 2 * CFG.steps_per_epoch


def _worse_for_seed_0(real: recipes.Recipe, stop_seed_1_at: int) -> recipes.Recipe:
    """The DUF recipe with a stand-in validation set that knows its seed (by its key) and a score by seed:
    seed 0's loss rises from its first epoch on, seed 1's falls until epoch `stop_seed_1_at`, then rises."""
    scored = {0: 0, 1: 0}
    val_key = {seed: np.asarray(jax.random.key_data(jax.random.fold_in(jax.random.key(seed), 2))) for seed in SEEDS}

    def validation(key, *args):
        seed = next(s for s, k in val_key.items() if np.array_equal(k, jax.random.key_data(key)))
        return {"gt": np.zeros((1, 4, 4)), "names": ["none"], "seed": seed}

    def evaluate(model, validation, *args, **kw):
        seed = validation["seed"]
        scored[seed] += 1
        epoch = scored[seed]
        loss = float(epoch) if seed == 0 else (1.0 / epoch if epoch < stop_seed_1_at else float(epoch))
        return {"loss": loss, "psnr": 20.0}

    return real._replace(validation=validation, evaluate=evaluate)


@pytest.mark.slow  # a stacked run of 2 seeds (10 s)
def test_a_seed_that_stops_early_stops_while_the_others_train_on(tmp_path, monkeypatch):
    """Patience 1: seed 0 stops after epoch 2 (no progress after its first), seed 1 after epoch 3; the stacked run
    ends then, short of its 5 epochs, and seed 0's folder is not written after it stopped."""
    monkeypatch.setitem(recipes._RECIPES, "duf", _worse_for_seed_0(recipes.recipe("duf"), stop_seed_1_at=3))
    cfg = dataclasses.replace(CFG, epochs=5, patience=1)
    seen = {}

    def remember(record):
        if record["seed"] == 0 and record["epoch"] == 2:
            seen["last"] = (seed_folder(tmp_path, 0) / "last.npz").read_bytes()

    result = fit(TINY, cfg, out=tmp_path, seeds=SEEDS, make_batch=MAKE_BATCH, progress=False, callback=remember)
    assert [len(result[s][1]) for s in SEEDS] == [2, 3]
    assert (seed_folder(tmp_path, 0) / "last.npz").read_bytes() == seen["last"]
    run0, run1 = (read_metadata(seed_folder(tmp_path, s) / "last.npz")["run"] for s in SEEDS)
    assert (run0["epoch"], run0["step"], run0["finished"], run0["best_epoch"]) == (2, 2 * cfg.steps_per_epoch, True, 0)
    assert (run1["epoch"], run1["finished"], run1["best_epoch"]) == (3, True, 1)
    # resumed with more epochs: both stopped early, so nothing trains
    with pytest.warns(UserWarning, match="stopped early"):
        again = fit(TINY, dataclasses.replace(cfg, epochs=8), out=tmp_path, seeds=SEEDS, make_batch=MAKE_BATCH,
                    progress=False, resume=True)
    assert [len(again[s][1]) for s in SEEDS] == [2, 3]


# --- the command line -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("args,message", [
    (["--seeds", ""], "argument --seeds: expected seeds separated by commas, such as 0,1,2, got ''"),
    (["--seeds", "0,,1"], "argument --seeds: expected seeds separated by commas"),
    (["--seeds", "1,2,1"], "argument --seeds: each seed once, got 1 more than once in '1,2,1'"),
    (["--seeds", "-1"], "argument --seeds: expected an integer from 0 to 4294967295, got -1"),
    (["--seeds", "0,-3"], "argument --seeds: expected an integer from 0 to 4294967295, got -3"),
    (["--seeds", "0,x"], "argument --seeds: expected an integer, got 'x'"),
    (["--seed", "1", "--seeds", "0,1"], "argument --seeds: not allowed with argument --seed"),
    (["--seeds", "0,1", "--seed", "1"], "argument --seed: not allowed with argument --seeds"),
])
def test_train_refuses_bad_seeds_in_one_line(tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as e:
        cli.main(["train", "--tr", "0", "--output", str(tmp_path / "run"), *args])
    err = capsys.readouterr().err
    assert e.value.code == 2 and message in err, err
    assert err.count("\n") == 1 and err.startswith("jaxsr train: error: "), err
    assert not (tmp_path / "run").exists()


def test_train_seeds_reach_fit_and_each_seed_is_reported(tmp_path, monkeypatch, capsys):
    import jaxsr.training.presets as presets

    got = {}
    record = {"epoch": 1, "val_loss": 0.5, "val_psnr": 30.0}

    def fake_fit(cfg, train_cfg, **kw):
        got.update(kw, train_cfg=train_cfg)
        return {s: (None, [record]) for s in kw["seeds"]}

    monkeypatch.setattr(presets, "fit", fake_fit)
    out = tmp_path / "runs"
    assert cli.main(["train", "--tr", "0", "--output", str(out), "--seeds", "2,0", "--no-progress"]) == 0
    assert got["seeds"] == (2, 0) and got["out"] == str(out)
    assert capsys.readouterr().out.splitlines() == [
        f"seed {s}: best epoch 1: val loss 5.000e-01, val PSNR 30.00 dB -> {out / f'seed{s}' / 'best.npz'}"
        for s in (2, 0)]
    # --resume needs a run in one of the seeds' folders; the folder itself must not hold a run
    assert cli.main(["train", "--tr", "0", "--output", str(tmp_path / "none"), "--seeds", "0,1", "--resume"]) == 2
    assert "no seed folder of" in capsys.readouterr().err
    (tmp_path / "one").mkdir()
    (tmp_path / "one" / "last.npz").write_bytes(b"")
    assert cli.main(["train", "--tr", "0", "--output", str(tmp_path / "one"), "--seeds", "0,1"]) == 2
    assert "a stacked run trains each seed in a folder inside out" in capsys.readouterr().err
    with pytest.raises(ValueError, match="seed and seeds exclude each other"):
        presets.train(tmp_path / "x", tr=0, seed=1, seeds=[0, 1])


@pytest.mark.slow  # 2 stacked runs (8 s)
def test_a_stacked_run_killed_inside_an_epoch_between_its_seeds_saves_resumes_to_the_uninterrupted_one(
        stacked, tmp_path, monkeypatch):
    """Saving after every step (checkpoint_every_s=0), killed inside epoch 2 after seed 0 saved step spe + 1 and
    before seed 1 did: the seeds resume in the same epoch at different steps (seed 1 trains its step alone, seed 0
    masked) and both end as the uninterrupted stacked run."""
    import jaxsr.training.run_state as run_state

    _, want, _ = stacked
    spe = CFG.steps_per_epoch
    real_save = run_state._save_state

    def save_then_kill(path, ts, run, *args, **kwargs):
        real_save(path, ts, run, *args, **kwargs)
        if path.parent.name == "seed0" and path.name == "resume.npz" and run.step == spe + 1:
            raise Killed

    monkeypatch.setattr(run_state, "_save_state", save_then_kill)
    with pytest.raises(Killed):
        fit(TINY, CFG, out=tmp_path, seeds=SEEDS, make_batch=MAKE_BATCH, progress=False, checkpoint_every_s=0)
    monkeypatch.setattr(run_state, "_save_state", real_save)
    steps = {s: read_metadata(seed_folder(tmp_path, s) / name)["run"]["step"]
             for s, name in ((0, "resume.npz"), (1, "last.npz"))}
    assert steps == {0: spe + 1, 1: spe} and not (seed_folder(tmp_path, 1) / "resume.npz").exists()
    got = fit(TINY, CFG, out=tmp_path, seeds=SEEDS, make_batch=MAKE_BATCH, progress=False, resume=True)
    for seed in SEEDS:
        for a, b in zip(leaves(got[seed][0]), leaves(want[seed][0])):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
        last = read_metadata(seed_folder(tmp_path, seed) / "last.npz")["run"]
        assert last["epoch"] == 2 and last["step"] == 2 * CFG.steps_per_epoch
