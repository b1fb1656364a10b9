"""SNR robustness (the paper's SNR study): PSNR and SSIM of bicubic, TR0, TR4 and the learned baselines (HistNet,
iSeeBetter, retrained on our data; the paper compares with iSeeBetter from SNR 0.25 to 10) against the frame SNR,
on the three test scenes, plus the extremes (1e-3 and 1e4) where the outputs must stay finite.

    python experiments/paper/snr_sweep.py [--frames 50] [--snrs 0.001 0.25 ... 10000] [--weights DIR]
                                    [--baselines histnet iseebetter] [--baseline-weights DIR]

Every scene is simulated at every SNR with the same photon level (`DEFAULT_MEAN_SIGNAL` signal photons per LR
pixel; the ambient level follows from the SNR). Models are trained on SNR 0.5-8 (`TrainConfig.snr_range`):
0.25, 0.34 and 1e4 lie outside it (the baselines were trained on the same range). A baseline without trained
weights is skipped with a message.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import numpy as np
from _baselines import add_baseline_args, baseline_source, load_baselines, run_baseline

import jaxsr
from jaxsr import scenes
from jaxsr.runtime import enable_compilation_cache

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import TEST_SCENES, add_model_args, load_tr, score, simulate_clip, weights_source  # noqa: E402
from harness.reports import header, markdown_table, write_atomic  # noqa: E402

SNRS = (0.001, 0.25, 0.34, 0.5, 0.75, 1.0, 10.0, 10000.0)


def plot(path, snrs, results):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for method, values in results.items():
        for ax, i in zip(axes, (0, 1)):
            ax.plot(snrs, [values[s][i] for s in snrs], "o-", label=method)
    for ax, label in zip(axes, ("PSNR (dB)", "SSIM")):
        ax.set_xscale("log")
        ax.set_xlabel("frame SNR (signal / background photons)")
        ax.set_ylabel(label + ", mean of the 3 test scenes")
        ax.axvspan(0.5, 8.0, color="0.9", zorder=0)
    axes[0].legend(fontsize=8, title="grey: training SNR range", title_fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=50, help="frames per scene (default 50)")
    parser.add_argument("--snrs", type=float, nargs="+", default=list(SNRS))
    add_model_args(parser, trs=(0, 4))
    add_baseline_args(parser)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="experiments/results/snr_sweep")
    args = parser.parse_args()
    started = time.time()
    enable_compilation_cache()
    sensor = jaxsr.Sensor()
    seqs = scenes.test_sequences(n_frames=args.frames, names=TEST_SCENES)
    models = {f"TR{tr}": load_tr(tr, args.weights) for tr in args.trs}
    baselines, cards, skipped = load_baselines(args.baselines, args.baseline_weights)
    methods = ["bicubic", *models, *baselines]
    per_scene = {m: {} for m in methods}  # method -> snr -> [(psnr, ssim) per scene]
    finite = {m: True for m in methods}
    for snr in args.snrs:
        for m in methods:
            per_scene[m][snr] = []
        for i, name in enumerate(TEST_SCENES):
            clip = simulate_clip(jax.random.key(args.seed * 1000 + i), seqs[name], sensor=sensor, snr=snr)
            outputs = {"bicubic": np.asarray(jaxsr.bicubic(clip.lr, scale=sensor.scale))}
            outputs.update({m: jaxsr.super_resolve(model, clip.lr, form="model") for m, model in models.items()})
            outputs.update({m: run_baseline(model, clip) for m, model in baselines.items()})
            for m, sr in outputs.items():
                finite[m] &= bool(np.all(np.isfinite(sr)))
                per_scene[m][snr].append(score(sr, clip.gt))
        print(f"SNR {snr:g}: " + ", ".join(f"{m} {np.mean([v[0] for v in per_scene[m][snr]]):.2f} dB"
                                            for m in methods), flush=True)
    mean = {m: {s: tuple(np.mean(per_scene[m][s], axis=0)) for s in args.snrs} for m in methods}
    rows = [[f"{s:g}"] + [f"{mean[m][s][0]:.2f} / {mean[m][s][1]:.3f}" for m in methods] for s in args.snrs]
    scene_rows = [[f"{s:g}", m] + [f"{p:.2f} / {q:.3f}" for p, q in per_scene[m][s]] for s in args.snrs
                  for m in methods]
    text = header("SNR robustness: bicubic, our models and the learned baselines against the frame SNR", started)
    text += (f"The three test scenes, first {args.frames} frames each, simulated at each SNR "
             f"({jaxsr.config.DEFAULT_MEAN_SIGNAL:g} signal photons per LR pixel), "
             f"models: {weights_source(args.weights)}. "
             "Cells: PSNR (dB) / SSIM, mean over the three scenes. Training covered SNR 0.5-8. "
             + baseline_source(baselines, cards, skipped, args.baseline_weights) + "\n\n")
    text += markdown_table(["SNR", *methods], rows)
    text += "\nPer scene (Scene 1 | Scene 2 | Scene 3):\n\n"
    text += markdown_table(["SNR", "method", "Scene 1", "Scene 2", "Scene 3"], scene_rows)
    text += ("\nAll outputs finite at every SNR: "
             + ", ".join(f"{m} {'yes' if ok else 'NO'}" for m, ok in finite.items()) + "\n")
    write_atomic(f"{args.out}.md", text)
    plot(f"{args.out}.png", list(args.snrs), mean)
    print(f"wrote {args.out}.md, .png ({time.time() - started:.0f} s)")


if __name__ == "__main__":
    main()
