"""Fine-tuning a windowed model into the sequence form against training the sequence form from scratch.

    python experiments/studies/finetune_sequence.py [--tr 1] [--runs runs/finetune-seq] [--frames 100]

Does a windowed checkpoint fine-tuned into the sequence form beat a sequence model trained from
scratch at equal CPU time? The budget T of TR`tr` is the windowed bundle's (1280 steps of the `bundle` preset);
the bundled `trN-seq` had the same T as sequence steps (experiments/studies/train_sequence_bundle.py: 1280 x window
step / sequence step, timed in one run; its plan.json). Arms, all run in the sequence form and scored alike:

- `scratch`: the bundled trN-seq (T in the sequence form, random start);
- `half + half`: a windowed model trained from random for half the windowed steps (640), then fine-tuned in the
  sequence form for half trN-seq's steps: T in all, by the same measured step ratio;
- `window as is`: the bundled windowed trN run in the sequence form without retraining (T, the windowed form);
- `window + fine-tune`: the bundled trN fine-tuned in the sequence form for trN-seq's steps (2T: what a further T
  buys a windowed model when spent in the sequence form).

Each training run has the `bundle` preset's shape (5 epochs, the rate cut for the last, batch 4, 16 x 32 LR
crops) and is resumable: run the same command again after an interruption. Writes
experiments/results/finetune_sequence.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

import jaxsr
from jaxsr.config import PRESETS
from jaxsr.training import fit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import SCENE_LABELS, TEST_SCENES, bundled, score, test_clips  # noqa: E402
from harness.reports import hand_written_tail, header, markdown_table, write_atomic  # noqa: E402

HAND_WRITTEN = "## Reading"
EPOCHS = 5


def _train(out: Path, model_cfg, steps: int, *, init=None):
    """A `bundle`-shaped run of `steps` steps (5 epochs) into `out`, resumed if interrupted, loaded if done."""
    if steps % EPOCHS:
        raise ValueError(f"{steps} steps do not split into {EPOCHS} epochs")
    train_cfg = dataclasses.replace(PRESETS["bundle"], examples_per_epoch=4 * steps // EPOCHS, epochs=EPOCHS)
    # resume=True starts afresh (from init) in an empty folder
    fit(model_cfg, train_cfg, out=out, resume=True, progress=False, init=init,
        callback=lambda r: print(out.name, json.dumps({k: r[k] for k in ("epoch", "val_psnr")}), flush=True))
    return out / "best.npz"


def _card(path) -> dict:
    card = jaxsr.read_metadata(path)["card"]
    return {"steps": card["steps"], "minutes": card["wall_time_s"] / 60, "val_psnr": card["validation"]["psnr"]}


ARMS = ("scratch", "half + half", "window as is", "window + fine-tune")


def arms(tr: int, runs: Path, names=ARMS) -> dict:
    """Each arm's sequence-form model and the training behind it: name -> (Model, [card per training stage]),
    for the arms in `names` (training only those)."""
    seq_cfg = jaxsr.ModelConfig(tr=tr, temporal="sequence")
    scratch, window = bundled(f"tr{tr}-seq"), bundled(f"tr{tr}")
    if scratch is None:
        raise SystemExit(f"no bundled tr{tr}-seq: train it first "
                         f"(experiments/studies/train_sequence_bundle.py --trs {tr})")
    seq_steps = jaxsr.read_metadata(scratch)["card"]["steps"]

    def half_and_half():
        window_steps = jaxsr.read_metadata(window)["card"]["steps"]
        half_window = _train(runs / "window-half", jaxsr.ModelConfig(tr=tr), window_steps // 2)
        half_seq = _train(runs / "sequence-half", seq_cfg, seq_steps // 2, init=half_window)
        return jaxsr.load_model(half_seq), [_card(half_window), _card(half_seq)]

    def fine_tuned():
        fine = _train(runs / "window-fine-tuned", seq_cfg, seq_steps, init=window)
        return jaxsr.load_model(fine), [_card(window), _card(fine)]

    build = {
        "scratch": lambda: (jaxsr.load_model(scratch), [_card(scratch)]),
        "half + half": half_and_half,
        "window as is": lambda: (jaxsr.load_model(f"tr{tr}", temporal="sequence"), [_card(window)]),
        "window + fine-tune": fine_tuned,
    }
    return {name: build[name]() for name in names}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tr", type=int, default=1)
    parser.add_argument("--runs", default="runs/finetune-seq")
    parser.add_argument("--frames", type=int, default=100, help="frames scored per test scene (default 100)")
    parser.add_argument("--arms", nargs="+", choices=ARMS, default=list(ARMS), help="the arms to run (default all)")
    parser.add_argument("--out", default="experiments/results/finetune_sequence.md")
    args = parser.parse_args()
    started = time.time()
    jaxsr.runtime.use_cpu_cores()
    models = arms(args.tr, Path(args.runs) / f"tr{args.tr}", args.arms)
    clips = test_clips(args.frames)
    rows = []
    for name, (model, cards) in models.items():
        scores = {n: score(jaxsr.super_resolve(model, c.lr, form="model"), c.gt) for n, c in clips.items()}
        mean = float(np.mean([s[0] for s in scores.values()]))
        stages = " + ".join(f"{c['steps']}" for c in cards)
        minutes = " + ".join(f"{c['minutes']:.0f}" for c in cards)
        rows.append([name, stages, minutes, f"{cards[-1]['val_psnr']:.2f}"]
                    + [f"{scores[n][0]:.2f} / {scores[n][1]:.3f}" for n in TEST_SCENES] + [f"{mean:.2f}"])
        print(*rows[-1], flush=True)

    text = header(f"Fine-tuning into the sequence form against training it from scratch (TR{args.tr})", started)
    text += (f"All the models run in the sequence form (TR{args.tr}, R = {3 + args.tr}); the arms are described in "
             "the script's docstring. Steps and minutes per training stage from the cards (windowed bundle cards "
             "were written on another machine, results/weights.md; minutes depend on the load, the equal-time rule "
             "uses step times measured in one run: experiments/studies/train_sequence_bundle.py). val PSNR: the "
             "selected checkpoint's validation PSNR in its last stage (3 x 16 frames; the windowed bundle's in the "
             "windowed form). Test scenes: first "
             f"{args.frames} frames, cells PSNR (dB) / SSIM of the clipped output.\n\n")
    text += markdown_table(["arm", "steps", "minutes", "val PSNR"] + [SCENE_LABELS[n] for n in TEST_SCENES]
                           + ["mean PSNR"], rows)
    text += hand_written_tail(args.out, HAND_WRITTEN)
    write_atomic(args.out, text)
    print(f"wrote {args.out} ({time.time() - started:.0f} s)")


if __name__ == "__main__":
    main()
