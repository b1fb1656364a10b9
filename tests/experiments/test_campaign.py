"""The training campaign (experiments/paper/campaign.py): which run goes next, when one is finished, and the
convergence measure, on fabricated metrics files (no training); the TR differences' spread over runs and frame
interval, on synthetic scores; the per-frame score cache (experiments/harness/score_cache.py) and scoring with it, on
fake scores."""

import json

import jax
import numpy as np
import pytest

import campaign  # experiments/paper (pytest's pythonpath)

import jaxsr
from jaxsr.config import PRESETS
from harness import score_cache
from harness.scoring import Clip
from jaxsr.io.checkpoint import save_model

CFG = PRESETS[campaign.PRESET]


def _write(root, seed, tr, val_losses, val_psnr=None):
    run = campaign.run_dir(root, seed, tr)
    run.mkdir(parents=True, exist_ok=True)
    psnr = val_psnr or [20.0 + i for i in range(len(val_losses))]
    lines = [json.dumps({"epoch": i + 1, "step": 100 * (i + 1), "val_loss": v, "val_psnr": p})
             for i, (v, p) in enumerate(zip(val_losses, psnr, strict=True))]
    (run / "metrics.jsonl").write_text("".join(line + "\n" for line in lines))


def test_the_run_with_fewest_epochs_goes_next_in_priority_order(tmp_path):
    assert campaign.next_run(tmp_path, CFG, None) == campaign.RUNS[0]
    for seed, tr in campaign.RUNS[:3]:
        _write(tmp_path, seed, tr, [1.0])
    assert campaign.next_run(tmp_path, CFG, None) == campaign.RUNS[3]  # no epochs yet beats one
    assert campaign.next_run(tmp_path, CFG, {"s0/tr1", "s0/tr2"}) == (0, 1)
    assert campaign.next_run(tmp_path, CFG, {"s0/tr1", "s0/tr2"}, skip={(0, 1)}) == (0, 2)


def test_a_run_is_finished_by_its_epoch_budget_or_by_patience(tmp_path):
    assert not campaign.finished([], CFG)
    improving = [{"val_loss": 1.0 - 0.01 * i} for i in range(CFG.epochs - 1)]
    assert not campaign.finished(improving, CFG)
    assert campaign.finished(improving + [{"val_loss": 0.0}], CFG)
    stalled = [{"val_loss": 0.5}] + [{"val_loss": 0.5}] * CFG.patience  # ties do not count as lower, as in fit
    assert campaign.finished(stalled, CFG)
    assert not campaign.finished(stalled[:-1], CFG)
    _write(tmp_path, 0, 0, [r["val_loss"] for r in stalled])
    assert campaign.next_run(tmp_path, CFG, {"s0/tr0"}) is None


def test_gain_over_the_last_quarter():
    assert campaign.gain_last_quarter([{"val_psnr": 20.0}] * 3) is None
    # one epoch that loses PSNR at epoch 4 is noise, not convergence: no verdict before 8 epochs
    assert campaign.gain_last_quarter([{"val_psnr": p} for p in (20.0, 22.0, 24.0, 23.5)]) is None
    assert campaign.gain_last_quarter([{"val_psnr": p} for p in (20.0, 22.0, 24.0, 23.5, 25.0, 26.0, 27.0)]) is None
    records = [{"val_psnr": p} for p in (20.0, 22.0, 23.0, 23.1, 23.0, 23.3, 23.2, 23.4)]
    assert campaign.gain_last_quarter(records) == pytest.approx(23.4 - 23.3)  # last 2 of 8 against the best before


def test_tr_differences_give_the_spread_over_runs_and_the_frame_interval():
    """Synthetic per-frame scores with a known answer: TR1 is TR0 + 1 dB frame by frame, seed for seed, with seed
    offsets of 0, 0.1 and 0.2 dB; TR2 (two runs) sits at the middle seed's level; TR3 (one run) 1.5 dB above."""
    rng = np.random.default_rng(0)
    frames = 20.0 + rng.normal(0.0, 1.0, (3, 40))  # (scenes, frames): frame-to-frame variation, shared by all runs
    scores = {(s, 0): frames + 0.1 * s for s in range(3)}
    scores |= {(s, 1): frames + 0.1 * s + 1.0 for s in range(3)}
    scores[(0, 2)] = scores[(1, 2)] = frames + 0.1
    scores[(0, 3)] = frames + 1.5
    diffs = campaign.tr_differences(scores)
    assert sorted(diffs) == [1, 2, 3]
    one = diffs[1]
    assert one["mean"] == pytest.approx(1.0)
    assert one["runs"] == pytest.approx((0.8, 1.2))  # every pair of a TR1 run and a TR0 run
    # the seed-averaged difference is the same in every frame, so every resample gives it
    assert (float(one["frames"].low), float(one["frames"].high)) == pytest.approx((1.0, 1.0), abs=1e-4)
    assert one["beyond"]
    two = diffs[2]
    assert two["mean"] == pytest.approx(0.0, abs=1e-9) and two["runs"] == pytest.approx((-0.1, 0.1))
    assert two["beyond"] is False  # the pairs straddle 0
    # one TR3 run: every pair and the frame interval are above 0, but TR3's own retraining spread is unmeasured
    assert diffs[3]["runs"][0] > 0 and float(diffs[3]["frames"].low) > 0 and diffs[3]["beyond"] is None
    assert campaign.tr_differences({(0, 1): frames}) == {}  # no TR0: nothing to compare with
    # one run of each TR: the frame interval alone cannot say the difference survives retraining
    single = campaign.tr_differences({(0, 0): frames, (0, 1): frames + 1.0})[1]
    assert single["runs"] == pytest.approx((1.0, 1.0)) and single["beyond"] is None
    # step by step: TR2 (+0.1) lies 0.9-1.1 dB below the TR1 runs (+1.0 to +1.2), TR3 (one run) 1.4 dB above TR2
    steps = campaign.tr_differences(scores, against_previous=True)
    assert sorted(steps) == [1, 2, 3] and steps[1]["mean"] == pytest.approx(1.0)
    assert steps[2]["mean"] == pytest.approx(-1.0) and steps[2]["runs"] == pytest.approx((-1.1, -0.9))
    assert steps[2]["beyond"] and float(steps[2]["frames"].high) < 0
    assert steps[3]["mean"] == pytest.approx(1.4) and steps[3]["beyond"] is None
    assert 3 not in campaign.tr_differences({(0, 0): frames, (0, 3): frames}, against_previous=True)  # no TR2


def test_an_epoch_is_expected_to_last_as_the_runs_last_one_or_another_seeds_of_its_tr(tmp_path):
    def write_times(seed, tr, times):
        run = campaign.run_dir(tmp_path, seed, tr)
        run.mkdir(parents=True, exist_ok=True)
        (run / "metrics.jsonl").write_text("".join(json.dumps({"epoch": i + 1, "epoch_time_s": t}) + "\n"
                                                   for i, t in enumerate(times)))

    assert campaign.expected_epoch_s(tmp_path, 1, 0) == 0.0  # nothing trained yet
    write_times(0, 0, [140.0, 130.0])
    write_times(0, 1, [600.0])
    assert campaign.expected_epoch_s(tmp_path, 0, 0) == 130.0  # its own last epoch
    assert campaign.expected_epoch_s(tmp_path, 2, 0) == 130.0  # a first epoch: another seed of TR0
    write_times(2, 0, [150.0])
    assert campaign.expected_epoch_s(tmp_path, 2, 0) == 150.0


def test_the_report_describes_the_preset_and_how_the_runs_trained(tmp_path):
    run = campaign.run_dir(tmp_path, 0, 4)
    run.mkdir(parents=True)
    records = [{"epoch": e, "step": 3875 * e, "wall_time_s": 60.0 * e, "val_loss": 1.0 / e, "val_psnr": 20.0 + e,
                "val_bicubic_psnr": 13.0} for e in (1, 2)]
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    out = tmp_path / "paper_runs.md"
    campaign.report(tmp_path, str(out), preset="paper", title="The paper preset", how="on a lent device")
    text = out.read_text()
    assert text.startswith("# The paper preset: learning curves")
    assert "100 epochs x 3875 steps" in text and "3 x 500 frames" in text and "on a lent device" in text
    assert "| s0/tr4 | 7750 | 2 | 22.00 | 22.00 (epoch 2) | - | 13.00 | training | ? | ? |" in text
    assert (tmp_path / "paper_runs.png").exists()


def _select(run, steps, tr=0):
    """A run's best.npz: a small TR-`tr` model whose card says it was selected at `steps`, validated on val4, val2,
    val5."""
    cfg = jaxsr.ModelConfig(tr=tr, base=8, growth=4, head=8, filter_hidden=8)
    params, state = jaxsr.init_model(jax.random.key(steps), cfg)
    card = {"steps": steps, "best_epoch": 1, "validation": {"psnr": 27.5, "bicubic_psnr": 13.4},
            "train_config": {"val_sequences": ["val4_street", "val2_road", "val5_courtyard"]}}
    save_model(run / "best.npz", jaxsr.Model(params, state, cfg), card=card)


def test_keep_copies_the_selected_weights_as_float16_and_never_replaces_later_ones(tmp_path):
    root, dest = tmp_path / "runs", tmp_path / "kept"
    run, kept = campaign.run_dir(root, 2, 0), campaign.run_dir(dest, 2, 0)
    _write(root, 2, 0, [1.0, 0.5])
    _select(run, 200)
    assert campaign.keep(root, dest) == ["s2/tr0"]
    meta = jaxsr.read_metadata(kept / "best.npz")
    assert meta["storage_dtype"] == "float16" and meta["card"]["steps"] == 200
    assert meta["card"]["storage"]["kept_from"] == str(run)
    assert (kept / "metrics.jsonl").read_text() == (run / "metrics.jsonl").read_text()
    stored, copied = jaxsr.load_model(run / "best.npz"), jaxsr.load_model(kept / "best.npz")
    for a, b in zip(jax.tree.leaves(stored), jax.tree.leaves(copied), strict=True):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-3, atol=1e-4)
    assert campaign.keep(root, dest) == []  # nothing newer
    _write(root, 2, 0, [1.0, 0.5, 0.6])  # an epoch past the selected one: the curve is kept, the weights stay
    assert campaign.keep(root, dest) == [] and len(campaign.history(kept)) == 3
    _select(run, 100)  # the run trained again and selected earlier weights: the kept copy stays
    assert campaign.keep(root, dest) == [] and campaign.selected_steps(kept) == 200
    assert campaign.keep(root, dest, force=True) == ["s2/tr0"] and campaign.selected_steps(kept) == 100


def test_the_report_shows_a_run_kept_without_its_curve_from_its_card(tmp_path):
    run = campaign.run_dir(tmp_path, 0, 3)
    run.mkdir(parents=True)
    _select(run, 7750)
    out = tmp_path / "paper_runs.md"
    campaign.report(tmp_path, str(out), preset="paper", title="The paper preset", how="on a lent device")
    assert ("| s0/tr3 | 7750 | - | - | 27.50 (epoch 2) | - | 13.40 | weights kept, curve not | val4, val2, val5 | "
            in out.read_text())


def _fake_test_clips(monkeypatch):
    """Three 4-frame test clips for campaign.score, whose scores the tests fake."""
    clips = {n: Clip(n, np.zeros((4, 2, 2), np.float32), None, np.zeros((4, 8, 8), np.float32), 25.0, 1.3,
                     scored=np.arange(4)) for n in ("a", "b", "c")}
    monkeypatch.setattr(campaign, "test_clips", lambda frames, spread: clips)


def test_scoring_reuses_the_kept_per_frame_scores_and_scores_only_a_new_or_retrained_run(tmp_path, monkeypatch):
    scored = []

    def fake_scene_scores(model, clips):  # a TR-dependent score, so that the table tells runs apart
        scored.append(model.config.tr)
        return {}, np.full((3, 4), 25.0 + model.config.tr)

    _fake_test_clips(monkeypatch)
    monkeypatch.setattr(campaign, "scene_scores", fake_scene_scores)
    root, out = tmp_path / "runs", tmp_path / "scores.md"
    for seed, tr, steps in ((0, 0, 100), (0, 1, 100)):
        run = campaign.run_dir(root, seed, tr)
        run.mkdir(parents=True)
        _select(run, steps, tr=tr)
    campaign.score(root, 4, str(out))
    assert sorted(scored) == [0, 1] and "| s0/tr1 | 100 | 26.00 | 26.00 | 26.00 | 26.00 | now |" in out.read_text()
    campaign.score(root, 4, str(out))  # nothing changed: nothing scored, the table the same from the kept scores
    assert sorted(scored) == [0, 1] and "| s0/tr1 | 100 | 26.00 | 26.00 | 26.00 | 26.00 | 20" in out.read_text()
    _select(campaign.run_dir(root, 0, 1), 200, tr=1)  # retrained: its weights file changed
    run = campaign.run_dir(root, 1, 0)
    run.mkdir(parents=True)
    _select(run, 100)  # a new run
    campaign.score(root, 4, str(out))
    assert sorted(scored) == [0, 0, 1, 1]
    assert set(json.loads(out.with_suffix(".json").read_text())) == {"s0/tr0", "s0/tr1", "s1/tr0"}


def test_scoring_flags_runs_of_different_lengths_but_not_an_earlier_epoch_picked_by_validation(tmp_path,
                                                                                                  monkeypatch):
    _fake_test_clips(monkeypatch)
    monkeypatch.setattr(campaign, "scene_scores", lambda model, clips: ({}, np.full((3, 4), 25.0 + model.config.tr)))
    root, out = tmp_path / "runs", tmp_path / "scores.md"
    for seed, tr, val_losses in ((0, 0, [1.0, 0.5]), (0, 1, [1.0, 0.4, 0.6]), (1, 0, [1.0, 0.5]), (1, 1, [1.0, 0.5])):
        _write(root, seed, tr, val_losses)  # 100 steps an epoch
        _select(campaign.run_dir(root, seed, tr), 200, tr=tr)  # every run's weights from step 200
    campaign.score(root, 4, str(out))
    text = out.read_text()
    assert "differ in training length" in text  # s0/tr1 trained 300 steps, the others 200
    assert "earlier epoch's weights of s0/tr1 (200)" in text
    _write(root, 0, 1, [1.0, 0.4])  # now every run trained 200 steps (100 an epoch), selected at its last
    campaign.score(root, 4, str(out))
    assert "differ in training length" not in out.read_text() and "earlier epoch" not in out.read_text()
    for seed, tr in ((0, 0), (1, 0), (1, 1)):  # every run trained 300 steps; s0/tr1's validation picked step 200
        _write(root, seed, tr, [1.0, 0.5, 0.4])
        _select(campaign.run_dir(root, seed, tr), 300, tr=tr)
    _write(root, 0, 1, [1.0, 0.4, 0.6])
    campaign.score(root, 4, str(out))
    text = out.read_text()
    assert "differ in training length" not in text and "earlier epoch's weights of s0/tr1 (200)" in text


def test_a_cached_score_is_used_only_for_the_same_key_and_shape(tmp_path):
    key = {"weights": "w1", "data": "d1", "code": "c1"}
    calls = []

    def compute(value):
        return lambda: calls.append(value) or np.full((3, 4), value + 1e-6)

    cache = {}
    first, computed = score_cache.cached_frame_scores(cache, "s0/tr0", key, (3, 4), compute(25.0))
    assert computed and np.array_equal(first, np.full((3, 4), 25.0))  # rounded to 1e-4 dB, as stored
    cache = json.loads(json.dumps(cache))  # what the file holds
    again, computed = score_cache.cached_frame_scores(cache, "s0/tr0", key, (3, 4), compute(26.0))
    assert not computed and calls == [25.0] and np.array_equal(again, first)
    for changed, value in (({"weights": "w2"}, 26.0), ({"data": "d2"}, 27.0), ({"code": "c2"}, 28.0)):
        key = dict(key, **changed)
        assert score_cache.cached_frame_scores(cache, "s0/tr0", key, (3, 4), compute(value))[0][0, 0] == value
    assert calls == [25.0, 26.0, 27.0, 28.0]
    # scores kept for another frame count are not reused: computed again (here of the wrong shape: a loud error)
    with pytest.raises(ValueError, match=r"shape \(3, 5\)"):
        score_cache.cached_frame_scores(cache, "s0/tr0", key, (3, 5), compute(29.0))
    assert calls[-1] == 29.0


def test_an_unreadable_cache_is_ignored_with_a_warning(tmp_path, capsys):
    path = tmp_path / "scores.json"
    assert score_cache.read_cache(path) == {}
    path.write_text('{"s0/tr0": {"weights"')  # cut short
    assert score_cache.read_cache(path) == {} and "ignoring the unreadable score cache" in capsys.readouterr().out
    path.write_text('["not", "a", "cache"]')
    assert score_cache.read_cache(path) == {}
    score_cache.write_cache(path, {"s0/tr1": {"psnr": [[1.0]]}, "s0/tr0": {"psnr": [[2.0]]}})
    assert score_cache.read_cache(path) == {"s0/tr0": {"psnr": [[2.0]]}, "s0/tr1": {"psnr": [[1.0]]}}
    assert len(path.read_text().splitlines()) == 4  # one run a line


def test_the_data_digest_changes_with_the_scored_data_only():
    rng = np.random.default_rng(0)
    lr, gt = rng.random((6, 2, 2), np.float32), rng.random((6, 8, 8), np.float32)

    def digest(lr=lr, gt=gt, scored=(0, 3)):
        return score_cache.data_digest({"a": Clip("a", lr, None, gt, 25.0, 1.3, scored=np.array(scored))})

    base = digest()
    assert digest() == base
    assert digest(scored=(0, 4)) != base
    assert digest(lr=lr + 1e-3) != base
    assert digest(gt=np.where(np.arange(6)[:, None, None] == 3, gt + 1e-3, gt)) != base  # a scored frame's truth
    assert digest(gt=np.where(np.arange(6)[:, None, None] == 1, gt + 1e-3, gt)) == base  # an unscored one's
    assert score_cache.digest(b"ab", b"c") != score_cache.digest(b"a", b"bc")
