"""The learned baselines of the paper's Table 3 (HistNet, iSeeBetter) for the paper's scripts: loading their trained
weights, running them on a test clip, our models at their training budgets (experiments/budget_weights), and the
sentences that say where each came from."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

import jaxsr

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import Clip  # noqa: E402

# The learned baselines of the paper's Table 3, retrained on our data (experiments/paper/train_baselines.py).
BASELINE_LABELS = {"histnet": "HistNet (retrained here)", "iseebetter": "iSeeBetter (retrained here)"}


def add_baseline_args(parser) -> None:
    """--baselines and --baseline-weights, for the scripts that score the learned baselines (see `load_baselines`)."""
    parser.add_argument("--baselines", nargs="*", default=list(BASELINE_LABELS), choices=list(BASELINE_LABELS),
                        help="learned baselines to score (default both; none: --baselines with no name)")
    parser.add_argument("--baseline-weights", default=None,
                        help="folder holding <name>.npz or <name>/best.npz (e.g. runs/baselines; default: the "
                             "bundled jaxsr/weights/<name>.npz)")


def load_baselines(names, weights=None) -> tuple[dict, dict, list[str]]:
    """The trained baselines that exist: ({label: Model}, {label: training card}, [a sentence for each one
    skipped]). Absent weights skip the baseline with a message (printed too) instead of failing the experiment."""
    models, cards, skipped = {}, {}, []
    for name in names:
        label = BASELINE_LABELS[name]
        candidates = [name] if weights is None else [Path(weights) / f"{name}.npz", Path(weights) / name / "best.npz"]
        path = next((c for c in candidates if weights is None or Path(c).is_file()), None)
        try:
            if path is None:
                raise FileNotFoundError(f"no {name}.npz or {name}/best.npz in {weights}")
            path = jaxsr.io.resolve_model_path(path)
            models[label] = jaxsr.load_model(path)
            cards[label] = jaxsr.read_metadata(path).get("card", {})
        except FileNotFoundError as e:
            skipped.append(f"{label}: skipped, no trained weights ({e})")
            print(skipped[-1], flush=True)
    return models, cards, skipped


# Ours at the learned baselines' budgets: the TR model whose training steps set each baseline's budget
# (`train_baselines.py`'s plan), as it was bundled then (the same files as jaxsr/weights at 43a44b3 and 090f946,
# so git stores them once). Since 2026-11-24 the bundle has been trained far longer (on a GPU), so the bundled rows
# no longer compare at equal compute; these rows do.
BUDGET_WEIGHTS = Path(__file__).resolve().parents[1] / "budget_weights"


def load_budget_models(cards: dict, folder=BUDGET_WEIGHTS) -> tuple[dict, list[str]]:
    """Our TR model at each baseline's training budget: ({label: Model}, [a sentence for each one skipped]).

    cards: {baseline label: training card} (`load_baselines`); a card's `plan` names the TR and its steps that set
    the baseline's budget. folder/tr<N>.npz must hold that TR trained for exactly those steps (its own card says):
    another checkpoint would compare at another budget, so it is refused. A missing file skips the row."""
    models, skipped = {}, []
    for base_label, card in cards.items():
        plan = card.get("plan")
        if not plan:
            continue
        tr, steps, name = plan["comparable_tr"], plan["tr_steps"], base_label.split(" (")[0]
        label, path = f"ours TR{tr}, {name}'s budget ({steps} steps)", Path(folder) / f"tr{tr}.npz"
        if not path.is_file():
            skipped.append(f"{label}: skipped, no {path}")
            print(skipped[-1], flush=True)
            continue
        got = jaxsr.read_metadata(path).get("card", {}).get("steps")
        if got != steps:
            raise SystemExit(f"{path}: a TR{tr} model trained for {got} steps, but {name}'s budget was set by TR{tr} "
                             f"at {steps} steps; put that model there (or point --budget-weights elsewhere)")
        models[label] = jaxsr.load_model(path)
    return models, skipped


def budget_source(models: dict, skipped, folder) -> str:
    """Sentences on the rows of ours at the baselines' budgets: where from, and which were skipped."""
    text = ""
    if models:
        text += ("Rows \"ours TRk, <baseline>'s budget\": the TR model whose training steps set that baseline's "
                 f"budget, as bundled then ({os.path.relpath(folder)}; each file's card, `jaxsr info FILE`, says "
                 "how it trained). ")
    return text + "".join(s + ". " for s in skipped)


def run_baseline(model, clip: Clip) -> np.ndarray:
    """A trained baseline on a clip: HistNet from its histograms and HR intensity, iSeeBetter from its
    centre-of-mass frames. Returns (T, H, W) normalised depth, not clipped."""
    if model.architecture.inputs == "histograms":
        return jaxsr.super_resolve_histograms(model, clip.counts, intensity=clip.intensity, batch_size=4)
    return jaxsr.super_resolve(model, clip.lr, batch_size=4)


def baseline_source(models: dict, cards: dict, skipped, weights) -> str:
    """Sentences on the baselines: where their weights came from, their size and training (from their cards),
    and which were skipped."""
    text = ""
    if models:
        where = "the bundled weights (jaxsr/weights)" if weights is None else f"the weights in {weights}"
        parts = []
        for label, m in models.items():
            card = cards.get(label, {})
            plan = card.get("plan", {})
            budget = ""
            if plan:
                total = plan["steps_per_epoch"] * plan["epochs"]
                kept = "" if card.get("steps") == total else " (the epoch early stopping kept)"
                budget = (f", {card.get('steps')} steps of batch 4{kept} of a budget of {total}, that of "
                          f"TR{plan['comparable_tr']}: {plan['tr_steps']} x its step time / this step time")
            parts.append(f"{label}: {describe_baseline(m)}{budget}")
        text += (f"Learned baselines from {where}, trained by `experiments/paper/train_baselines.py` on our data "
                 "(the VGG perceptual term of iSeeBetter's loss left out): " + "; ".join(parts) + ". ")
    if skipped:
        text += " ".join(s + "." for s in skipped) + " "
    return text


def describe_baseline(model) -> str:
    """Architecture in a few words: configuration and parameter count."""
    from jaxsr.nn import count_params

    c = model.config
    n = count_params(model.params) / 1e6
    if model.kind == "histnet":
        return f"width {c.width}, {n:.2f} M parameters"
    return (f"RBPN {c.frames} frames, base_filter {c.base_filter}, feat {c.feat}, {c.n_resblock} residual blocks, "
            f"{n:.2f} M parameters")


