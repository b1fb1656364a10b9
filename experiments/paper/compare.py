"""Comparison with other methods (the paper's Table 3, Figs. 8-9): bicubic, Lanczos, maximum-likelihood depth +
bicubic, a TV-regularised multi-frame reconstruction (optimistix), the learned baselines HistNet and iSeeBetter
retrained on our data, ours at TR1 and TR4 (the bundle), and ours at each baseline's training budget.

    python experiments/paper/compare.py [--frames 100] [--weights DIR] [--baselines histnet iseebetter]
                                  [--baseline-weights DIR] [--budget-weights DIR|none]

PSNR and SSIM per test scene (means over --frames frames spread evenly over its 500, as in sweep_tr.py),
end-to-end frames/s on this machine (histograms in, HR depth out), parameter counts, a figure of example frames
(LR input, every method, ground truth) and one of |SR - GT| error maps.
HistNet and iSeeBetter come from `experiments/paper/train_baselines.py` (bundled jaxsr/weights/histnet.npz,
iseebetter.npz, or --baseline-weights); a baseline without weights is skipped with a message. The paper's rows
for them are kept, marked as the paper's. Each baseline's budget is the steps of the TR model of comparable cost
bundled when it was planned, times their step-time ratio (its card); the bundle has since trained far longer, so
experiments/budget_weights keeps those TR models, scored as "ours TRk, <baseline>'s budget": the rows at equal
compute.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _baselines import (
    add_baseline_args,
    BUDGET_WEIGHTS,
    baseline_source,
    budget_source,
    load_baselines,
    load_budget_models,
    run_baseline,
)

import jaxsr
from jaxsr.nn import count_params
from jaxsr.baselines.tv import tv_super_resolve
from jaxsr.runtime import enable_compilation_cache

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import (  # noqa: E402
    FPS_NOTE,
    PAPER_BICUBIC,
    PAPER_TABLE1,
    SCENE_LABELS,
    SEQUENCE_FRAMES,
    TEST_SCENES,
    add_model_args,
    frames_per_second,
    load_tr,
    score,
    super_resolve_frames,
    test_clips,
    weights_source,
)
from harness.reports import header, markdown_table, write_atomic  # noqa: E402

PAPER_OTHERS = {
    "iSeeBetter (paper)": ((20.47, 0.784), (21.96, 0.837), (28.74, 0.843), 33.0),
    "HistNet (paper)": ((19.14, 0.812), (20.14, 0.858), (27.18, 0.881), 0.25),
}
SENSOR = jaxsr.Sensor()


@jax.jit
def _com_then(counts):
    return jaxsr.centre_of_mass(counts, SENSOR)


def per_frame(fn):
    """A method that upscales each frame on its own: run on the scored frames only."""
    return lambda clip: fn(clip.at(clip.scored))


def over_sequence(fn):
    """A method that reads neighbouring frames: run on the whole sequence, keep the scored frames."""
    return lambda clip: fn(clip) if clip.scored is None else fn(clip)[clip.scored]


def over_windows(fn, radius: int):
    """A method whose frame t reads only frames t - radius .. t + radius (edge-replicated at the ends): run on the
    scored frames' windows laid end to end, and keep each window's centre (it reads exactly its own window)."""

    def run(clip):
        if clip.scored is None:
            return fn(clip)
        frames = np.clip(clip.scored[:, None] + np.arange(-radius, radius + 1), 0, len(clip.gt) - 1)
        return fn(clip.at(frames.reshape(-1)))[radius :: 2 * radius + 1]

    return run


def methods(models, baselines=None, budget=None):
    """name -> function (clip) -> HR (S, H, W) normalised, the clip's S scored frames (`Clip.scored`; None: all
    its frames); clip: a `harness.scoring.Clip` (counts (T, h, w, K), centre-of-mass depth lr (T, h, w), HR intensity
    (T, H, W)). models: {tr: Model}; baselines: {label: Model}; budget: {label: Model}, ours at the
    baselines' budgets."""
    up = jax.jit(lambda x: jaxsr.bicubic(x, scale=4))
    lanczos = jax.jit(lambda x: jaxsr.lanczos(x, scale=4))
    ml = jax.jit(lambda c: jaxsr.bicubic(jaxsr.maximum_likelihood_depth(c, SENSOR), scale=4))
    out = {
        "bicubic": per_frame(lambda clip: np.asarray(up(clip.lr))),
        "Lanczos": per_frame(lambda clip: np.asarray(lanczos(clip.lr))),
        "ML + bicubic": per_frame(lambda clip: np.asarray(ml(clip.counts))),
        "TV multi-frame (TR1)": over_windows(lambda clip: np.asarray(tv_super_resolve(clip.lr, scale=4, tr=1)), 1),
    }
    for label, model in (baselines or {}).items():  # HistNet upscales frame by frame, iSeeBetter reads neighbours
        wrap = per_frame if model.kind == "histnet" else over_sequence
        out[label] = wrap(lambda clip, model=model: run_baseline(model, clip))
    ours = {**(budget or {}), **{f"ours TR{tr}": model for tr, model in models.items()}}
    for label, model in ours.items():
        out[label] = lambda clip, model=model: super_resolve_frames(model, clip.lr, clip.scored)
    return out


def end_to_end_fps(fn, clip, *, frames: int = 16, min_time):
    """Frames/s from histograms (centre of mass included in every call), the first `frames` frames of the clip
    per call (HistNet also reads their HR intensity)."""
    counts = jnp.asarray(clip.counts[:frames])

    def call():
        lr = np.asarray(_com_then(counts))
        return fn(dataclasses.replace(clip, counts=counts, lr=lr, intensity=clip.intensity[:frames], scored=None))

    return frames_per_second(call, frames, min_time=min_time)


def figures(path_frames, path_errors, clips, outputs, pos):
    """Example frames (paper Fig. 8) and |SR - GT| error maps (Fig. 9), one row per scene: the scored frame at
    position `pos` of the outputs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(next(iter(outputs.values())))
    for path, errors in ((path_frames, False), (path_errors, True)):
        cols = (["LR (centre of mass)"] if not errors else []) + names + ([] if errors else ["ground truth"])
        fig, axes = plt.subplots(len(clips), len(cols), figsize=(2.3 * len(cols), 1.35 * len(clips)), squeeze=False)
        for row, (scene, clip) in enumerate(clips.items()):
            shown = clip.at(clip.scored)
            frame = pos if clip.scored is None else int(clip.scored[pos])
            gt = shown.gt[pos]
            panels = [] if errors else [np.repeat(np.repeat(shown.lr[pos], 4, 0), 4, 1)]
            for m in names:
                sr = np.clip(outputs[scene][m][pos], 0, 1)
                panels.append(np.abs(sr - gt) if errors else sr)
            if not errors:
                panels.append(gt)
            for ax, img, title in zip(axes[row], panels, cols):
                ax.imshow(img, cmap="magma" if errors else "turbo_r", vmin=0, vmax=0.5 if errors else 1,
                          interpolation="nearest")
                ax.set_xticks([])
                ax.set_yticks([])
                if row == 0:
                    ax.set_title(title, fontsize=7)
            axes[row][0].set_ylabel(SCENE_LABELS[scene], fontsize=7)
        fig.suptitle(("|SR - GT| (normalised depth, 0-0.5)" if errors else "normalised depth (near = red)")
                     + f", frame {frame}", fontsize=8)
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100,
                        help=f"frames scored per test scene, spread evenly over its {SEQUENCE_FRAMES} (default 100; "
                        f"{SEQUENCE_FRAMES}: all)")
    add_model_args(parser, trs=(1, 4))
    add_baseline_args(parser)
    parser.add_argument("--budget-weights", default=None,
                        help="folder of tr<N>.npz: ours at each baseline's training budget (default "
                             "experiments/budget_weights; 'none' leaves those rows out)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--figure-frame", type=int, default=None,
                        help="frame shown in the figures: the scored frame nearest to it (default: the middle one)")
    parser.add_argument("--out", default="experiments/results/compare")
    args = parser.parse_args()
    started = time.time()
    enable_compilation_cache()
    clips = test_clips(args.frames, seed=args.seed, spread=True)
    ours = {tr: load_tr(tr, args.weights) for tr in args.trs}
    baselines, cards, skipped = load_baselines(args.baselines, args.baseline_weights)
    budget_folder = args.budget_weights or BUDGET_WEIGHTS
    budget, budget_skipped = ({}, []) if budget_folder == "none" else load_budget_models(cards, budget_folder)
    fns = methods(ours, baselines, budget)
    params = {**{f"ours TR{tr}": count_params(m.params) for tr, m in ours.items()},
              **{label: count_params(m.params) for label, m in {**baselines, **budget}.items()}}
    outputs = {scene: {} for scene in clips}
    scores = {m: {} for m in fns}
    for m, fn in fns.items():
        for scene, clip in clips.items():
            outputs[scene][m] = fn(clip)
            scores[m][scene] = score(outputs[scene][m], clip.at(clip.scored).gt)
        print(m, ", ".join(f"{SCENE_LABELS[s]} {p:.2f}/{q:.3f}" for s, (p, q) in scores[m].items()), flush=True)
    speed = {m: end_to_end_fps(fn, clips[TEST_SCENES[0]], min_time=2.0) for m, fn in fns.items()}

    fmt = lambda sc: [f"{sc[s][i]:.{2 if i == 0 else 3}f}" for s in TEST_SCENES for i in (0, 1)]
    mparams = lambda m: f"{params[m] / 1e6:.2f} M" if m in params else "-"
    rows = [[m] + fmt(scores[m]) + [f"{speed[m]:.1f}", mparams(m)] for m in fns]
    quoted = {"bicubic (paper)": PAPER_BICUBIC, **PAPER_OTHERS,
              **{f"ours TR{tr} (paper)": PAPER_TABLE1[tr] for tr in args.trs}}
    rows += [[m] + [f"{v:.{2 if i == 0 else 3}f}" for sc in vals[:3] for i, v in enumerate(sc)] + [f"{vals[3]:g}", ""]
             for m, vals in quoted.items()]
    columns = (["method"] + [f"{SCENE_LABELS[s]} {k}" for s in TEST_SCENES for k in ("PSNR", "SSIM")]
               + ["frames/s", "parameters"])
    scored = clips[TEST_SCENES[0]].scored  # the same frames in every scene
    pos = len(scored) // 2 if args.figure_frame is None else int(np.argmin(np.abs(scored - args.figure_frame)))
    frame = int(scored[pos])
    text = header("Comparison with other methods (paper Table 3, Figs. 8-9)", started)
    spread = "all" if len(scored) == SEQUENCE_FRAMES else f"{len(scored)} frames spread evenly over the"
    text += (f"{spread.capitalize()} {SEQUENCE_FRAMES} frames of each test scene (scenes 1-2 at SNR 1.3, scene 3 "
             "at SNR 3, "
             f"{jaxsr.config.DEFAULT_MEAN_SIGNAL:g} signal photons per LR pixel, noise seed {args.seed}); "
             "PSNR (dB) and "
             f"SSIM of the clipped output against the normalised ground truth. Ours: {weights_source(args.weights)}. "
             "frames/s: end to end on this machine (16 frames of histograms -> centre of mass or ML fit -> "
             f"upscaling; ours with the {FPS_NOTE}); the paper's are on an RTX 2070. "
             "TV multi-frame: `jaxsr.baselines.tv.tv_super_resolve` "
             "(robust data term over 3 frames + smoothed TV, L-BFGS), defaults chosen on a validation sequence. "
             + baseline_source(baselines, cards, skipped, args.baseline_weights)
             + budget_source(budget, budget_skipped, budget_folder)
             + "Rows marked (paper) are quoted from the paper (its own data and GPU).\n\n")
    text += markdown_table(columns, rows)
    text += (f"\nFigures: `compare_frames.png` (frame {frame} of each scene, every method) and "
             f"`compare_errors.png` (|SR - GT| of the same frames).\n")
    write_atomic(f"{args.out}.md", text)
    figures(f"{args.out}_frames.png", f"{args.out}_errors.png", clips, outputs, pos)
    print(f"wrote {args.out}.md, _frames.png, _errors.png ({time.time() - started:.0f} s)")


if __name__ == "__main__":
    main()
