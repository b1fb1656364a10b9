"""experiments/paper/bundle_weights.py --keep-better: a run's model replaces a bundled one only when it scores higher on
the validation frames, and a kept bundled file is left byte for byte (a session that trained less than the bundle
must not make the product worse); how a card's training schedule is described."""

import dataclasses
import shutil

import jax
import pytest

import bundle_weights  # experiments/paper (pytest's pythonpath)

import jaxsr
from jaxsr.io.checkpoint import resolve_model_path, save_model
from jaxsr.nn import Model

ARGS = ["--runs", "runs", "--trs", "0", "--frames", "2", "--trained-with", "a test"]


@pytest.fixture
def workspace(tmp_path, monkeypatch):
    """A run tr0 holding the bundled TR0 model (best and last), an empty weights folder, results written locally."""
    bundled = resolve_model_path("tr0")
    card = jaxsr.read_metadata(bundled)["card"]
    model = jaxsr.load_model(bundled)
    run = tmp_path / "runs" / "tr0"
    run.mkdir(parents=True)
    for name in ("best", "last"):
        save_model(run / f"{name}.npz", model, card=card)
    weights = tmp_path / "weights"
    weights.mkdir()
    (tmp_path / "experiments" / "results").mkdir(parents=True)
    monkeypatch.setattr(bundle_weights, "WEIGHTS", weights)
    monkeypatch.chdir(tmp_path)
    return tmp_path, bundled, card


def test_a_bundled_model_as_good_as_the_run_is_kept_untouched(workspace):
    tmp_path, bundled, _ = workspace
    target = tmp_path / "weights" / "tr0.npz"
    shutil.copy(bundled, target)
    before = target.read_bytes()
    with pytest.raises(SystemExit, match="--force"):
        bundle_weights.main(ARGS)
    bundle_weights.main([*ARGS, "--keep-better"])
    assert target.read_bytes() == before
    assert not (tmp_path / "experiments" / "results" / "weights.md").exists()


@pytest.mark.slow  # 10-18 s: keeps the default suite under 8 minutes on 2 cores
def test_a_worse_bundled_model_is_replaced_by_the_run(workspace):
    tmp_path, _, card = workspace
    target = tmp_path / "weights" / "tr0.npz"
    model = jaxsr.load_model("tr0")
    # weights perturbed well beyond training's scale (an untrained network is no good stand-in: its uniform
    # dynamic filters smooth noisy depth well, and it can beat a short training on a few frames)
    noisy = jax.tree_util.tree_map(lambda p: p + 0.3 * jax.random.normal(jax.random.key(1), p.shape), model.params)
    save_model(target, Model(noisy, model.state, model.config), card=card)
    bundle_weights.main([*ARGS, "--keep-better"])
    assert jaxsr.read_metadata(target)["card"]["trained_with"] == "a test"
    assert "| TR0 |" in (tmp_path / "experiments" / "results" / "weights.md").read_text()


def test_the_schedule_is_described_for_crops_and_whole_frames():
    for preset, crops in (("bundle", "16 x 32 LR crops"), ("paper", "whole LR frames")):
        text = bundle_weights.describe(dataclasses.asdict(jaxsr.PRESETS[preset]))
        assert text.startswith(f"batch 4, {crops} of freshly rendered") and "3 x " in text
