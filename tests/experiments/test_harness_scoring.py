"""The experiments' frame selection (experiments/harness/scoring.py): scores spread over a whole test sequence, and the
windowed models computed on those frames only, equal to the whole sequence's output there."""

import dataclasses

import jax
import numpy as np
import pytest

import _baselines  # experiments/paper (pytest's pythonpath)

import jaxsr
from harness import scoring
from jaxsr.nn import Model, init_model

SMALL = {"base": 8, "growth": 4, "head": 16, "filter_hidden": 16}


def test_scored_frames_are_spread_evenly_over_the_whole_sequence():
    idx = scoring.scored_frames(100, 500)
    assert len(idx) == 100 and len(set(idx.tolist())) == 100
    np.testing.assert_array_equal(np.diff(idx), 5)
    assert idx[0] == 2 and idx[-1] == 497  # the middle of each share: both ends of the sequence are covered
    np.testing.assert_array_equal(scoring.scored_frames(500, 500), np.arange(500))
    np.testing.assert_array_equal(scoring.scored_frames(900, 500), np.arange(500))
    assert scoring.scored_frames(3, 10).tolist() == [1, 5, 8]
    with pytest.raises(ValueError, match="at least one frame"):
        scoring.scored_frames(0, 500)


@pytest.mark.parametrize("temporal", ["window", "sequence"])
def test_super_resolve_frames_equals_the_whole_sequence_at_those_frames(temporal):
    cfg = jaxsr.ModelConfig(tr=2, temporal=temporal, **SMALL)
    model = Model(*init_model(jax.random.key(0), cfg), cfg)
    lr = np.asarray(jax.random.uniform(jax.random.key(1), (13, 8, 12)), np.float32)
    frames = np.array([0, 1, 6, 11, 12])  # both ends, where the windows are edge-replicated, and the middle
    whole = jaxsr.super_resolve(model, lr)
    part = scoring.super_resolve_frames(model, lr, frames, batch=2)  # a last, padded batch too
    assert part.shape == (5, 32, 48)
    np.testing.assert_allclose(part, whole[frames], atol=1e-5)
    np.testing.assert_allclose(scoring.super_resolve_frames(model, lr), whole, atol=1e-6)


def test_clip_at_keeps_the_chosen_frames_of_every_field():
    t = 6
    lr, counts, gt = np.arange(t * 2.0).reshape(t, 1, 2), np.zeros((t, 1, 2, 3)), np.arange(t * 8.0).reshape(t, 2, 4)
    clip = scoring.Clip("x", lr, counts, gt, 10.0, 1.3, intensity=np.ones((t, 2, 4)), scored=np.array([1, 4]))
    part = clip.at(clip.scored)
    assert part.lr.shape == (2, 1, 2) and part.counts.shape == (2, 1, 2, 3) and part.intensity.shape == (2, 2, 4)
    np.testing.assert_array_equal(part.gt, clip.gt[[1, 4]])
    assert part.scored is None and clip.at(None) is clip
    assert dataclasses.replace(clip, intensity=None).at([0]).intensity is None


def test_scene_scores_are_the_per_frame_scores_of_the_scored_frames():
    cfg = jaxsr.ModelConfig(tr=1, **SMALL)
    model = Model(*init_model(jax.random.key(0), cfg), cfg)
    keys = jax.random.split(jax.random.key(2), 4)
    clips = {}
    for i, name in enumerate(("a", "b")):
        lr = np.asarray(jax.random.uniform(keys[2 * i], (10, 8, 12)), np.float32)
        gt = np.asarray(jax.random.uniform(keys[2 * i + 1], (10, 32, 48)), np.float32)
        clips[name] = scoring.Clip(name, lr, np.zeros((10, 8, 12, 2)), gt, 10.0, 1.3,
                                   scored=scoring.scored_frames(4, 10))
    means, frames = scoring.scene_scores(model, clips)
    assert frames.shape == (2, 4) and list(means) == ["a", "b"]
    for row, clip in zip(frames, clips.values(), strict=True):
        p, s = scoring.frame_scores(jaxsr.super_resolve(model, clip.lr)[clip.scored], clip.gt[clip.scored])
        np.testing.assert_allclose(row, p, atol=1e-3)
        assert means[clip.name] == pytest.approx((float(p.mean()), float(s.mean())), abs=1e-3)


def test_baseline_source_tells_kept_steps_from_the_budget():
    """The bundled baselines' sentence: the steps of the kept checkpoint, and the budget when early stopping kept
    fewer (it read as if the kept steps were the budget)."""
    models, cards, skipped = _baselines.load_baselines(["histnet"])
    label = _baselines.BASELINE_LABELS["histnet"]
    card = cards[label]
    plan = card["plan"]
    text = _baselines.baseline_source(models, cards, skipped, None)
    assert f"{card['steps']} steps of batch 4" in text
    assert f"a budget of {plan['steps_per_epoch'] * plan['epochs']}" in text
    kept = card["steps"] < plan["steps_per_epoch"] * plan["epochs"]
    assert ("early stopping kept" in text) == kept
    full = {label: {**card, "steps": plan["steps_per_epoch"] * plan["epochs"]}}
    assert "early stopping kept" not in _baselines.baseline_source(models, full, skipped, None)


def test_budget_models_match_the_bundled_baselines_plans():
    # each bundled baseline's budget was set from a TR model's steps: experiments/budget_weights holds exactly it
    _, cards, _ = _baselines.load_baselines(list(_baselines.BASELINE_LABELS))
    models, skipped = _baselines.load_budget_models(cards)
    assert not skipped and len(models) == len(cards)
    for label, card in cards.items():
        tr, steps = card["plan"]["comparable_tr"], card["plan"]["tr_steps"]
        assert models[f"ours TR{tr}, {label.split(' (')[0]}'s budget ({steps} steps)"].config.tr == tr


def test_budget_models_refuse_another_checkpoint_and_skip_a_missing_one(tmp_path):
    card = {"plan": {"comparable_tr": 0, "tr_steps": 999}}
    with pytest.raises(SystemExit, match="trained for 1280 steps, but HistNet's budget was set by TR0 at 999"):
        _baselines.load_budget_models({"HistNet (retrained here)": card})
    models, skipped = _baselines.load_budget_models({"HistNet (retrained here)": card}, tmp_path)
    assert models == {} and "skipped" in skipped[0]
    assert _baselines.load_budget_models({"HistNet (retrained here)": {}}) == ({}, [])  # no plan: no row



def test_a_clip_gives_each_network_the_channels_it_reads_by_name():
    """A clip's photon channels are named (`Clip.channels`); a model reading them in another order or a subset
    gets its own stack, one reading a channel the clip lacks is told which."""
    t, h, w = 2, 4, 6
    lr = np.full((t, h, w), 0.5, np.float32)
    photons = np.stack([np.full((t, h, w), v, np.float32) for v in (0.1, 0.2, 0.3)], axis=-1)
    clip = scoring.Clip("c", lr, np.zeros((t, 0), np.float32), lr, 25.0, 1.3, photons=photons,
                        channels=("signal", "background", "ambient"))
    assert clip.network_input() is lr
    x = clip.network_input(("depth", "ambient", "signal"))
    np.testing.assert_allclose(x[0, 0, 0], [0.5, 0.3, 0.1], rtol=1e-6)
    two = dataclasses.replace(clip, photons=photons[..., :2], channels=("signal", "background"))
    with pytest.raises(ValueError, match=r"without the channels \['ambient'\]"):
        two.network_input(("depth", "signal", "background", "ambient"))
    with pytest.raises(ValueError, match="hold 2 channels but channels names 3"):
        dataclasses.replace(clip, photons=photons[..., :2]).network_input(("depth", "signal"))
