"""Model selection and retraining spread at the paper preset: does a validation set pick the checkpoint that scores
best on the test scenes, and how far apart are runs that differ only in their seed, at equal steps?

    python experiments/paper/selection.py runs/paper/s0/tr0/best.npz runs/paper/s1/tr0/epoch1.npz ... [--frames 100]

Every checkpoint (best.npz, last.npz or a copy of an epoch's last.npz) is scored, with the same noise, on
- the old validation: the first --val-frames frames of val1_street, val2_road, val3_courtyard (the presets' until
  2026-11-24; val1 and val3 move the camera out of the modelled scene within 500 frames),
- the new validation: the same of val4_street, val2_road, val5_courtyard (static cameras, as the test scenes),
- the test scenes: --frames frames spread evenly over each 500 (as sweep_tr.py).
Each validation's loss (the Huber loss `fit` selects on) picks one checkpoint among those of each TR; the report
says what that pick scores on the test scenes against the best there. Pairs of checkpoints of one TR at equal
steps and different seeds give the retraining spread, with the paired bootstrap interval over frames.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import sys
import time
from pathlib import Path

import numpy as np

import jaxsr
from jaxsr.config import PRESETS, TrainConfig
from jaxsr.training.data import run_keys, validation_set
from jaxsr.training import evaluate

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import SCENE_LABELS, TEST_SCENES, format_interval, interval, scene_scores, test_clips  # noqa: E402
from harness.reports import hand_written_tail, header, markdown_table, write_atomic  # noqa: E402

# A section written by hand at the end of the results file (e.g. the rows of runs whose checkpoints are gone): kept
HAND_WRITTEN = "## Earlier runs"
VALIDATIONS = {"old": ("val1_street", "val2_road", "val3_courtyard"),  # the presets' until 2026-11-24
               "new": TrainConfig().val_sequences}


def card_of(path: Path) -> dict:
    """seed, steps and epoch of a checkpoint: a model's card, or a train state's run record."""
    meta = jaxsr.read_metadata(path)
    card, run = meta.get("card", {}), meta.get("run")
    seed = card.get("seed", meta.get("train_config", {}).get("seed"))
    if run is not None:  # a train state: the epochs done so far (1-based, as metrics.jsonl counts them)
        return {"seed": seed, "steps": run.get("step"), "epoch": run.get("epoch")}
    best = card.get("best_epoch")  # a model's card counts its selected epoch from 0
    return {"seed": seed, "steps": card.get("steps"), "epoch": None if best is None else best + 1}


def validation_scores(model, val_frames: int, cache: dict) -> dict:
    """{validation name: (loss, PSNR)} of one model; the validation frames and noise are the same for every
    checkpoint (validation noise of seed 0), built once per TR."""
    out = {}
    for name, sequences in VALIDATIONS.items():
        key = (name, model.config.tr)
        if key not in cache:
            cfg = dataclasses.replace(PRESETS["paper"], val_frames=val_frames, val_sequences=sequences)
            cache[key] = validation_set(run_keys(0)[2], model.config.tr, cfg)
        val = cache[key]
        r = evaluate(model.params, model.state, val["windows"], val["gt"], model.config)
        out[name] = (r["loss"], r["psnr"])
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+", type=Path, help="model or train-state files (.npz)")
    parser.add_argument("--frames", type=int, default=100, help="test frames per scene, spread over its 500")
    parser.add_argument("--val-frames", type=int, default=500, help="frames per validation sequence (default 500)")
    parser.add_argument("--out", default="experiments/results/selection")
    args = parser.parse_args()
    missing = [str(p) for p in args.checkpoints if not p.is_file()]
    if missing:
        parser.error(f"no such checkpoint: {', '.join(missing)}")
    started = time.time()
    clips = test_clips(args.frames, spread=True)
    cache, rows, found = {}, [], []
    for path in args.checkpoints:
        model = jaxsr.load_model(path)
        if model.config.temporal != "window":
            parser.error(f"{path}: a {model.config.temporal}-form model; this script validates the window form")
        info = card_of(path)
        val = validation_scores(model, args.val_frames, cache)
        means, frames = scene_scores(model, clips)
        test = [means[n][0] for n in TEST_SCENES]
        found.append(dict(path=path, tr=model.config.tr, val=val, frames=frames, test=float(np.mean(test)), **info))
        rows.append([str(path), f"TR{model.config.tr}", str(info["seed"]), str(info["steps"]), str(info["epoch"]),
                     *(f"{val[v][0]:.6f} / {val[v][1]:.2f}" for v in VALIDATIONS),
                     *(f"{p:.2f}" for p in test), f"{np.mean(test):.2f}"])
        print(*rows[-1], flush=True)

    text = header("Model selection and retraining spread at the paper preset", started)
    text += (f"Validation: the first {args.val_frames} frames of each sequence, the paper preset's noise (validation "
             "key of seed 0, the same for every checkpoint); loss = the Huber loss `fit` selects on. Old: "
             f"{', '.join(VALIDATIONS['old'])} (moving cameras in val1 and val3); new: "
             f"{', '.join(VALIDATIONS['new'])} (static cameras). Test: {args.frames} frames spread evenly over "
             "each 500-frame test scene at its SNR, noise seed 0; PSNR (dB).\n\n")
    text += markdown_table(["checkpoint", "TR", "seed", "steps", "epoch",
                            *(f"{v} validation loss / PSNR" for v in VALIDATIONS),
                            *(SCENE_LABELS[n] for n in TEST_SCENES), "test mean"], rows)
    picks = []
    for tr, seed in sorted({(c["tr"], c["seed"]) for c in found}):  # one run: the choice fit makes
        group = [c for c in found if (c["tr"], c["seed"]) == (tr, seed)]
        if len(group) < 2:
            continue
        best = max(group, key=lambda c: c["test"])
        for v in VALIDATIONS:
            pick = min(group, key=lambda c: c["val"][v][0])
            picks.append([f"TR{tr} s{seed}", v, f"epoch {pick['epoch']}", f"{pick['test']:.2f}",
                          f"epoch {best['epoch']}", f"{pick['test'] - best['test']:+.2f}"])
    if picks:
        text += ("\nWhat each validation's lowest loss picks among the checkpoints of a run (TR and seed), and what "
                 "that pick loses on the test scenes against the run's best there (0: it picked the best):\n\n")
        text += markdown_table(["run", "validation", "picks", "its test mean", "test best", "pick - best"], picks)
    pairs = [[f"TR{a['tr']}", str(a["steps"]), f"s{a['seed']} - s{b['seed']}",
              format_interval(interval(a["frames"], b["frames"]))]
             for a, b in itertools.combinations(found, 2)
             if a["tr"] == b["tr"] and a["steps"] == b["steps"] and a["seed"] != b["seed"]]
    if pairs:
        text += ("\nRetraining spread: checkpoints of one TR at equal steps from different seeds, the difference of "
                 "their test-scene PSNR (mean over scenes and frames) with its 95 % paired bootstrap interval over "
                 "blocks of scored frames (what the choice of frames moves; the difference itself is what "
                 "retraining moves):\n\n")
        text += markdown_table(["TR", "steps", "seeds", "difference [frame interval]"], pairs)
    text += hand_written_tail(f"{args.out}.md", HAND_WRITTEN)
    write_atomic(f"{args.out}.md", text)
    print(text)


if __name__ == "__main__":
    main()
