"""experiments/studies/no_return_head.py: the decision's shares, the in-sample threshold, and the branch refit
learning from fixed features, the HR convolutions, the static benchmark's guard."""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import no_return_head as study  # experiments/studies (pytest's pythonpath)
import numpy as np
import pytest

from jaxsr.config import ModelConfig
from jaxsr.nn import init_model, no_return_logits


def test_shares_read_the_logit_and_the_depth_as_the_benchmark_does():
    gt = np.array([[1.0, 1.0, 0.5, 0.5]])
    depth = np.array([[0.3, 0.995, 0.4, np.nan]])  # sky as depth, sky read as none, a return, a NaN return
    logit = np.array([[-1.0, -1.0, -1.0, -1.0]])
    assert study.shares(depth, logit, gt, 0.0) == (50.0, 50.0)
    assert study.shares(depth, logit, gt, -2.0) == (0.0, 100.0)  # every logit above: all no return
    keep = np.array([[True, False, True, False]])
    assert study.shares(depth, logit, gt, 0.0, keep) == (100.0, 0.0)


def test_best_threshold_keeps_the_drops_within_the_goal():
    gt = np.where(np.arange(200) < 100, 1.0, 0.2)[None]
    logit = np.concatenate([np.linspace(0.0, 4.0, 100), np.linspace(-4.0, 1.0, 100)])[None]
    t = study.best_threshold(np.full_like(gt, 0.2), logit, gt)
    as_depth, dropped = study.shares(np.full_like(gt, 0.2), logit, gt, t)
    assert dropped <= study.GOAL_DROPPED
    # the next lower candidate threshold drops more than the goal allows
    lower = max(c for c in study.DEFAULT_THRESHOLDS if c < t)
    assert study.shares(np.full_like(gt, 0.2), logit, gt, lower)[1] > study.GOAL_DROPPED
    assert as_depth == pytest.approx(100.0 * np.mean(logit[0, :100] <= t))


def test_refit_learns_a_branch_from_fixed_features():
    cfg = ModelConfig(tr=0, base=8, growth=4, head=16, filter_hidden=16, same_blocks=1, inputs=("depth", "signal"),
                      no_return_head=True)
    branch = init_model(jax.random.key(0), cfg)[0]["no_return"]
    rng = np.random.default_rng(0)
    features = rng.uniform(size=(64, 4, 5, cfg.head)).astype(np.float16)
    # no return where feature 0 is high: one LR pixel's whole block
    truth = np.kron(features[..., 0] > 0.5, np.ones((cfg.scale, cfg.scale), bool))

    def error(b):
        logit = no_return_logits(b, jnp.asarray(features, jnp.float32)[:, None], cfg)[:, 0]
        return float(np.mean((np.asarray(logit) > 0) != truth))

    assert error(branch) == pytest.approx(np.mean(truth))  # the new branch says "return" everywhere
    refitted = study.refit_branch(branch, features, truth, cfg, steps=150, lr=1e-2, log=lambda _: None)
    assert error(refitted) < 0.05
    assert jax.tree_util.tree_structure(refitted) == jax.tree_util.tree_structure(branch)


def test_hr_inputs_put_each_lr_value_on_its_block():
    rng = np.random.default_rng(1)
    windows = rng.uniform(size=(2, 3, 2, 3, 4)).astype(np.float32)  # 3 frames of 2 x 3 LR pixels, 4 channels
    depth, logit = rng.uniform(size=(2, 8, 12)), np.full((2, 8, 12), 100.0)
    x = study.hr_inputs(windows, depth, logit, 4).astype(np.float32)
    assert x.shape == (2, 8, 12, 2 * 4 + 1)
    assert np.all(x[..., 0] == study.LOGIT_CLIP / study.LOGIT_UNIT)  # the logit clipped, in its unit
    np.testing.assert_allclose(x[..., 1], depth, atol=1e-3)  # float16
    np.testing.assert_allclose(x[:, 5, 9, 2:6], windows[:, 1, 1, 2], atol=1e-3)  # HR (5, 9) lies in LR (1, 2)
    np.testing.assert_allclose(x[:, 5, 9, 6:], windows[:, :, 1, 2, 1:].mean(axis=1), atol=1e-3)


def test_hr_convolutions_start_at_the_branch_and_learn_what_it_misses():
    rng = np.random.default_rng(2)
    x = rng.uniform(size=(64, 8, 8, 3)).astype(np.float16)
    branch = rng.uniform(-6.0, -2.0, size=(64, 8, 8))  # the branch says "return" everywhere, each pixel its own
    x[..., 0] = study.hr_inputs(np.zeros((64, 1, 2, 2, 2)), np.zeros((64, 8, 8)), branch, 4)[..., 0]
    truth = x[..., 2] > 0.5  # what only another input shows
    layers = study.init_hr(jax.random.key(0), 3)
    start = np.asarray(study.hr_logits(layers, jnp.asarray(x, jnp.float32)))
    np.testing.assert_allclose(start, branch, atol=5e-3)  # the branch's own logit, up to float16
    fitted = study.fit_on_fixed(layers, study.hr_logits, x, truth, steps=300, lr=1e-2, log=lambda _: None)
    error = np.mean((np.asarray(study.hr_logits(fitted, jnp.asarray(x, jnp.float32))) > 0) != truth)
    assert error < 0.05 < np.mean(truth)


def test_static_benchmark_refuses_windows_that_would_hold_two_scenes():
    model = SimpleNamespace(config=ModelConfig(tr=4))
    with pytest.raises(ValueError, match="too close"):
        study.benchmark_windows(model, [3.0], frames=study.SEQUENCE_FRAMES // 4, seed=0, static=True)


def test_the_report_says_what_was_fitted_and_on_what(tmp_path):
    args = study.argparse.Namespace(model="m", draws=8, steps=5, lr=1e-3, hr_steps=0, static_prob=0.3, static=True,
                                    calibration_draws=4, frames=2, seed=0)
    pick = {"no_return_logit": 1.0, "as_depth": 10.0, "dropped": 1.0}
    row = {"photons": 3.0, "branch": "bundled", "chosen": 1.0, "best": 0.5,
           **{k: (1.0, 1.0) for k in ("all", "interior", "edges", "all_best", "interior_best", "edges_best")}}
    study.write_report(tmp_path / "r.md", [row], {"bundled": pick, "refitted": pick}, args, 0.0)
    text = (tmp_path / "r.md").read_text()
    assert study.HR not in text and "30 % of the training and calibration clips static" in text
    assert "**static**" in text
    study.write_report(tmp_path / "s.md", [row], {"bundled": pick, study.HR: pick},
                       study.argparse.Namespace(**{**vars(args), "hr_steps": None, "static_prob": 0.0,
                                                   "static": False}), 0.0)
    text = (tmp_path / "s.md").read_text()
    assert study.HR in text and "clips static" not in text and "**static**" not in text
