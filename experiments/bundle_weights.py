"""Package trained models as the bundled weights (jaxsr/weights/tr<N>.npz), stored as float16 when that costs
under 0.05 dB, each with its training card; writes experiments/results/weights.md.

    python experiments/bundle_weights.py --runs runs/bundle [--trs 0 1 2 3 4] [--force]

The models come from `jaxsr train --tr N --preset bundle --out runs/bundle/trN` (their best.npz). The float16
cost is measured on the three validation sequences (first --frames frames each, never the test scenes): the
mean PSNR of the float32 model minus that of the float16 one.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

import jaxsr
from jaxsr import scenes
from jaxsr.checkpoint import save_model

from _eval import score, simulate_clip
from _report import header, markdown_table, write_atomic

WEIGHTS = Path(jaxsr.__file__).parent / "weights"
VALIDATION = ("val1_street", "val2_road", "val3_courtyard")
MAX_COST_DB = 0.05


def mean_psnr(model, clips):
    return float(np.mean([score(jaxsr.super_resolve(model, c.lr), c.gt)[0] for c in clips]))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", default="runs/bundle", help="folder with tr<N>/best.npz")
    parser.add_argument("--trs", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--frames", type=int, default=32, help="validation frames per sequence")
    parser.add_argument("--force", action="store_true", help="replace existing bundled weights")
    args = parser.parse_args()
    started = time.time()
    seqs = scenes.test_sequences(n_frames=args.frames, names=VALIDATION)
    clips = [simulate_clip(jax.random.key(7000 + i), seqs[n]) for i, n in enumerate(VALIDATION)]
    rows = []
    for tr in args.trs:
        source = Path(args.runs) / f"tr{tr}" / "best.npz"
        target = WEIGHTS / f"tr{tr}.npz"
        if target.exists() and not args.force:
            raise SystemExit(f"{target} exists; pass --force to replace it")
        model = jaxsr.load_model(source)
        card = jaxsr.read_metadata(source)["card"]
        with tempfile.TemporaryDirectory() as tmp:
            half = jaxsr.load_model(save_model(Path(tmp) / "half.npz", model, storage_dtype="float16"))
            full, reduced = mean_psnr(model, clips), mean_psnr(half, clips)
        cost = full - reduced
        dtype = "float16" if cost < MAX_COST_DB else "float32"
        card = dict(card, trained_with=f"jaxsr train --tr {tr} --preset bundle --out {Path(args.runs) / f'tr{tr}'}",
                    storage={"dtype": dtype, "psnr_cost_db": round(cost, 4),
                             "measured_on": f"{', '.join(VALIDATION)}, first {args.frames} frames"})
        save_model(target, model, card=card, storage_dtype=dtype)
        size = target.stat().st_size / 2**20
        val = card.get("validation", {})
        rows.append([f"TR{tr}", card["steps"], card["examples"], f"{card['wall_time_s'] / 60:.0f}",
                     f"{val.get('psnr', float('nan')):.2f}", f"{val.get('bicubic_psnr', float('nan')):.2f}",
                     f"{full:.2f}", f"{cost:+.4f}", dtype, f"{size:.1f}"])
        print(*rows[-1], flush=True)
    total = sum((WEIGHTS / f"tr{tr}.npz").stat().st_size for tr in range(5) if (WEIGHTS / f"tr{tr}.npz").exists())
    text = header("Bundled weights (jaxsr/weights)", started)
    text += ("Each model trained with `jaxsr train --preset bundle` (batch 4, 16 x 32 LR crops of freshly rendered "
             "random scenes, SNR 0.5-8, 7-28 signal photons, Adam 1e-3 cut to 1e-4 for the last epoch; "
             "validation on 3 x 16 frames of the validation sequences). Training PSNR columns: the best epoch's "
             "validation PSNR and bicubic's on the same frames, from the card. 'val PSNR' and the float16 cost: "
             f"mean over {', '.join(VALIDATION)} ({args.frames} frames each), float32 minus float16.\n\n")
    text += markdown_table(["model", "steps", "examples", "train min", "card val PSNR", "card bicubic",
                            "val PSNR", "float16 cost dB", "stored", "MB"], rows)
    text += f"\nAll bundled weights together: {total / 2**20:.1f} MB.\n"
    write_atomic("experiments/results/weights.md", text)
    print(f"wrote experiments/results/weights.md ({time.time() - started:.0f} s)")


if __name__ == "__main__":
    main()
