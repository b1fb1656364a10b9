"""How much do models trained alike differ? Test-scene PSNR of several training runs (e.g. the same TR and
preset with different seeds) beside the bundled models, to tell a TR's effect from training-to-training spread.

    jaxsr train --tr 0 --preset bundle --seed 1 -o runs/seeds/tr0_s1      # and --seed 2 ...
    python experiments/paper/seed_spread.py runs/seeds/tr0_s1 runs/seeds/tr0_s2 [--frames 100]

Each run folder contributes its last.npz (the final epoch, as bundled for TR1-TR3) and best.npz.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jaxsr

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import SCENE_LABELS, TEST_SCENES, scene_scores, test_clips  # noqa: E402
from harness.reports import header, markdown_table, write_atomic  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="training run folders (with best.npz and last.npz)")
    parser.add_argument("--frames", type=int, default=100,
                        help="frames scored per test scene, spread over its 500 as in sweep_tr.py (default 100)")
    parser.add_argument("--out", default="experiments/results/seed_spread")
    args = parser.parse_args()
    started = time.time()
    clips = test_clips(args.frames, spread=True)
    models = {f"bundled tr{tr}": jaxsr.load_model(f"tr{tr}") for tr in range(5)}
    for run in map(Path, args.runs):
        for name in ("best", "last"):
            models[f"{run.name} {name}"] = jaxsr.load_model(run / f"{name}.npz")
    rows = []
    for label, model in models.items():
        scores = [scene_scores(model, clips)[0][n][0] for n in TEST_SCENES]
        card = jaxsr.read_metadata(model_path(label, args.runs)).get("card", {})
        rows.append([label, f"TR{model.config.tr}", card.get("seed", "?"), card.get("steps", "?"),
                     *(f"{p:.2f}" for p in scores), f"{sum(scores) / len(scores):.2f}"])
        print(*rows[-1], flush=True)
    text = header("Training-to-training spread (test-scene PSNR)", started)
    text += (f"{args.frames} frames spread evenly over the 500 of each test scene at its SNR, noise seed 0, as in "
             "sweep_tr.py; "
             "PSNR (dB) of the clipped output, mean over frames.\n\n")
    text += markdown_table(["model", "TR", "seed", "steps", *(SCENE_LABELS[n] for n in TEST_SCENES), "mean"], rows)
    write_atomic(f"{args.out}.md", text)
    print(f"wrote {args.out}.md ({time.time() - started:.0f} s)")


def model_path(label, runs):
    if label.startswith("bundled "):
        return Path(jaxsr.__file__).parent / "weights" / f"{label.split()[1]}.npz"
    name, which = label.rsplit(" ", 1)
    return next(Path(r) for r in runs if Path(r).name == name) / f"{which}.npz"


if __name__ == "__main__":
    main()
