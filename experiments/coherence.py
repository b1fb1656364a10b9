"""Temporal coherence (the paper's Tc, Eq. 2): flicker of TR0 against TR4 (and of the learned baselines HistNet and
iSeeBetter, retrained on our data) on a static-camera sequence of people.

    python experiments/coherence.py [--frames 125] [--fps 25] [--weights DIR] [--baselines histnet iseebetter]
                                    [--baseline-weights DIR] [--seed-runs CHECKPOINT ...]

Tc_t counts pixels that are static in the ground truth (|GT_t+1 - GT_t| <= 1e-6) but change in the output by more
than eps; the paper reports TR0 with about twice TR4's count. Since outputs are real numbers, the count depends on
eps: it is reported at eps = 1/255, 0.01 and 0.05 of the depth range (`jaxsr.temporal_coherence`), for bicubic and
the baselines (skipped with a message where they have no trained weights) too. Sequence: `walkers_100fps` (static
camera, a stream of people walking at 4.3 km/h in four lanes 7.5-10.5 m away) sampled at --fps. The TR0 / TR4 ratio
comes with a paired block-bootstrap interval over frame pairs (`jaxsr.ratio_interval`); with `--seed-runs`
(other trainings of TR0 or TR4), for every pair of a TR0 run and a TR4 run.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
from _eval import (
    BLOCK,
    SEQUENCE_FRAMES,
    add_baseline_args,
    add_model_args,
    baseline_source,
    load_baselines,
    load_tr,
    run_baseline,
    score,
    simulate_clip,
    weights_source,
)
from _report import header, markdown_table, save_figure, write_atomic
from _seeds import add_seed_run_args, load_seed_runs, seed_summary

import jaxsr
from jaxsr.runtime import enable_compilation_cache
from jaxsr.scenes import test_sequence

EPS = (1 / 255, 0.01, 0.05)


def plot(path, counts):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.4))
    for method, c in counts.items():
        ax.plot(np.arange(1, len(c) + 1), c, label=method, lw=1)
    ax.set_xlabel("frame pair t, t + 1")
    ax.set_ylabel("Tc_t (flickering static pixels, eps = 0.01)")
    ax.legend(fontsize=8)
    save_figure(fig, path)


def ratio_intervals(sr_a, sr_b, gt, block: int) -> dict:
    """{eps: TR a's Tc over TR b's with its paired block-bootstrap interval over frame pairs} (`jaxsr.ratio_interval`)."""
    counts = [[jaxsr.temporal_coherence(jnp.asarray(sr), jnp.asarray(gt), eps=e).counts for e in EPS]
              for sr in (sr_a, sr_b)]
    return {e: jaxsr.ratio_interval(jax.random.key(0), counts[0][i], counts[1][i], block=block)
            for i, e in enumerate(EPS)}


def walkers_at(fps: float, frames: int, *, seed: int = 0):
    """The static-camera walkers sequence sampled at about `fps` (every round(100 / fps)-th frame of the 100 FPS
    sequence), simulated with noise seed `seed`: (Clip, the sampled sequence)."""
    step = round(100 / fps)
    seq = test_sequence("walkers_100fps", n_frames=frames * step)
    seq = seq._replace(depth=seq.depth[::step], intensity=seq.intensity[::step], fps=100.0 / step)
    return simulate_clip(jax.random.key(seed), seq), seq


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=None,
                        help=f"frames at --fps (default: the whole {SEQUENCE_FRAMES}-frame sequence, 125 at 25 FPS)")
    parser.add_argument("--fps", type=float, default=25.0, help="frame rate sampled from the 100 FPS sequence")
    add_model_args(parser, trs=(0, 4))
    add_baseline_args(parser)
    parser.add_argument("--seed", type=int, default=0)
    add_seed_run_args(parser)
    parser.add_argument("--out", default="experiments/results/coherence")
    args = parser.parse_args()
    started = time.time()
    enable_compilation_cache()
    args.frames = args.frames or SEQUENCE_FRAMES // round(100 / args.fps)
    clip, seq = walkers_at(args.fps, args.frames, seed=args.seed)
    outputs = {"bicubic": np.asarray(jaxsr.bicubic(clip.lr, scale=4))}
    outputs.update({f"TR{tr}": jaxsr.super_resolve(load_tr(tr, args.weights), clip.lr) for tr in args.trs})
    seed_runs = load_seed_runs(args.seed_runs)
    outputs.update({f"TR{m.config.tr} ({name})": jaxsr.super_resolve(m, clip.lr) for name, m in seed_runs.items()})
    baselines, cards, skipped = load_baselines(args.baselines, args.baseline_weights)
    outputs.update({label: run_baseline(model, clip) for label, model in baselines.items()})
    rows, counts = [], {}
    for method, sr in outputs.items():
        tcs = [jaxsr.temporal_coherence(jnp.asarray(sr), jnp.asarray(clip.gt), eps=e) for e in EPS]
        counts[method] = np.asarray(tcs[1].counts)
        p, s = score(sr, clip.gt)
        rows.append([method] + [f"{float(tc.mean):.0f} ({100 * float(tc.flicker_fraction):.2f} %)" for tc in tcs]
                    + [f"{p:.2f} / {s:.3f}"])
        print(method, rows[-1][1:], flush=True)
    block = min(BLOCK, args.frames - 1)
    runs = {tr: [m for m in outputs if m == f"TR{tr}" or m.startswith(f"TR{tr} (")] for tr in (0, 4)}
    # per frame pair, a TR0 run's count over a TR4 run's, resampled in blocks of pairs; every pair of runs
    ratios = {(a, b): ratio_intervals(outputs[a], outputs[b], clip.gt, block) for a in runs[0] for b in runs[4]}
    ratio = ratios.get(("TR0", "TR4"), {})
    text = header("Temporal coherence Tc: TR0 against TR4 (paper Eq. 2)", started)
    text += (f"Sequence `walkers_100fps` at {seq.fps:g} FPS (static camera), {args.frames} frames, SNR {clip.snr:g}; "
             f"models: {weights_source(args.weights)}. Cells: mean Tc_t over frame pairs (flickering static pixels "
             "per frame, of 128 x 256) and, in brackets, the share of static pixels that flicker; last column PSNR "
             "(dB) / SSIM. " + baseline_source(baselines, cards, skipped, args.baseline_weights) + "\n\n")
    text += markdown_table(["method"] + [f"Tc, eps = {e:.3g}" for e in EPS] + ["PSNR / SSIM"], rows)
    if ratio:
        iv = ratio[0.01]
        verdict = ("holds beyond the frame interval" if 1.5 <= iv.low and iv.high <= 3 else
                   "holds on the ratio only, not beyond the frame interval" if 1.5 <= iv.mean <= 3 else "does not hold")
        text += ("\nTR0 / TR4 Tc ratio with its 95 % interval (a paired bootstrap over blocks of "
                 f"{min(BLOCK, args.frames - 1)} frame pairs): "
                 + ", ".join(f"{float(r.mean):.2f} [{float(r.low):.2f}, {float(r.high):.2f}] at eps {e:.3g}"
                             for e, r in ratio.items())
                 + f". Paper: about 2 -> {verdict} at eps 0.01 (taken as 1.5-3).\n")
    if len(ratios) > 1:
        text += (f"\nAgainst retraining ({seed_summary(seed_runs)}): the ratio at eps 0.01 for every pair of a TR0 run "
                 "and a TR4 run, with its frame interval:\n\n")
        text += markdown_table(["TR0 run", "TR4 run", "TR0 / TR4 Tc at eps 0.01"],
                               [[a, b, f"{float(r[0.01].mean):.2f} [{float(r[0.01].low):.2f}, {float(r[0.01].high):.2f}]"]
                                for (a, b), r in ratios.items()])
        inside = [1.5 <= float(r[0.01].low) and float(r[0.01].high) <= 3 for r in ratios.values()]
        text += ("\n-> " + ("holds beyond the frame interval for every pair of runs" if all(inside) else
                            f"beyond the frame interval for {sum(inside)} of {len(inside)} pairs of runs") + ".\n")
    write_atomic(f"{args.out}.md", text)
    plot(f"{args.out}.png", counts)
    print(f"wrote {args.out}.md, .png ({time.time() - started:.0f} s)")


if __name__ == "__main__":
    main()
