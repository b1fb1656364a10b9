"""Comparison with other methods (the paper's Table 3, Figs. 8-9): bicubic, Lanczos, maximum-likelihood depth +
bicubic, a TV-regularised multi-frame reconstruction (optimistix), and ours at TR1 and TR4.

    python experiments/compare.py [--frames 50] [--weights DIR]

PSNR and SSIM per test scene, end-to-end frames/s on this machine (histograms in, HR depth out), a figure of
example frames (LR input, every method, ground truth) and one of |SR - GT| error maps. iSeeBetter and HistNet,
the paper's other two rows, are not reimplemented here (a separately trained RGB video network and a
histogram network with an intensity guide); their rows are quoted from the paper only.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxsr
from jaxsr.runtime import enable_compilation_cache
from jaxsr.recon import tv_super_resolve

from _eval import (FPS_NOTE, PAPER_BICUBIC, PAPER_TABLE1, SCENE_LABELS, TEST_SCENES, add_model_args, frames_per_second,
                   load_tr, score, test_clips, weights_source)
from _report import header, markdown_table, write_atomic

PAPER_OTHERS = {
    "iSeeBetter (paper)": ((20.47, 0.784), (21.96, 0.837), (28.74, 0.843), 33.0),
    "HistNet (paper)": ((19.14, 0.812), (20.14, 0.858), (27.18, 0.881), 0.25),
}
SENSOR = jaxsr.SensorConfig()


@jax.jit
def _com_then(counts):
    return jaxsr.centre_of_mass(counts, SENSOR)


def methods(models):
    """name -> function (counts (T, h, w, K), centre-of-mass depth (T, h, w)) -> HR (T, H, W) normalised."""
    up = jax.jit(lambda x: jaxsr.bicubic(x, scale=4))
    lanczos = jax.jit(lambda x: jaxsr.lanczos(x, scale=4))
    ml = jax.jit(lambda c: jaxsr.bicubic(jaxsr.maximum_likelihood_depth(c, SENSOR), scale=4))
    out = {
        "bicubic": lambda counts, lr: np.asarray(up(lr)),
        "Lanczos": lambda counts, lr: np.asarray(lanczos(lr)),
        "ML + bicubic": lambda counts, lr: np.asarray(ml(counts)),
        "TV multi-frame (TR1)": lambda counts, lr: np.asarray(tv_super_resolve(lr, scale=4, tr=1)),
    }
    for tr, model in models.items():
        out[f"ours TR{tr}"] = lambda counts, lr, model=model: jaxsr.super_resolve(model, lr)
    return out


def end_to_end_fps(fn, counts, *, min_time):
    """Frames/s from histograms (centre of mass included), all frames of `counts` per call."""
    counts = jnp.asarray(counts)
    return frames_per_second(lambda: fn(counts, np.asarray(_com_then(counts))), counts.shape[0], min_time=min_time)


def figures(path_frames, path_errors, clips, outputs, frame):
    """Example frames (paper Fig. 8) and |SR - GT| error maps (Fig. 9), one row per scene."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(next(iter(outputs.values())))
    for path, errors in ((path_frames, False), (path_errors, True)):
        cols = (["LR (centre of mass)"] if not errors else []) + names + ([] if errors else ["ground truth"])
        fig, axes = plt.subplots(len(clips), len(cols), figsize=(2.3 * len(cols), 1.35 * len(clips)), squeeze=False)
        for row, (scene, clip) in enumerate(clips.items()):
            gt = clip.gt[frame]
            panels = [] if errors else [np.repeat(np.repeat(clip.lr[frame], 4, 0), 4, 1)]
            for m in names:
                sr = np.clip(outputs[scene][m][frame], 0, 1)
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
    parser.add_argument("--frames", type=int, default=50, help="frames per test scene (default 50)")
    add_model_args(parser, trs=(1, 4))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--figure-frame", type=int, default=None, help="frame shown in the figures (default middle)")
    parser.add_argument("--out", default="experiments/results/compare")
    args = parser.parse_args()
    started = time.time()
    enable_compilation_cache()
    clips = test_clips(args.frames, seed=args.seed)
    fns = methods({tr: load_tr(tr, args.weights) for tr in args.trs})
    outputs = {scene: {} for scene in clips}
    scores = {m: {} for m in fns}
    for m, fn in fns.items():
        for scene, clip in clips.items():
            outputs[scene][m] = fn(clip.counts, clip.lr)
            scores[m][scene] = score(outputs[scene][m], clip.gt)
        print(m, ", ".join(f"{SCENE_LABELS[s]} {p:.2f}/{q:.3f}" for s, (p, q) in scores[m].items()), flush=True)
    counts16 = clips[TEST_SCENES[0]].counts[:16]
    speed = {m: end_to_end_fps(fn, counts16, min_time=2.0) for m, fn in fns.items()}

    fmt = lambda sc: [f"{sc[s][i]:.{2 if i == 0 else 3}f}" for s in TEST_SCENES for i in (0, 1)]  # noqa: E731
    rows = [[m] + fmt(scores[m]) + [f"{speed[m]:.1f}"] for m in fns]
    quoted = {"bicubic (paper)": PAPER_BICUBIC, **PAPER_OTHERS,
              **{f"ours TR{tr} (paper)": PAPER_TABLE1[tr] for tr in args.trs}}
    rows += [[m] + [f"{v:.{2 if i == 0 else 3}f}" for sc in vals[:3] for i, v in enumerate(sc)] + [f"{vals[3]:g}"]
             for m, vals in quoted.items()]
    columns = ["method"] + [f"{SCENE_LABELS[s]} {k}" for s in TEST_SCENES for k in ("PSNR", "SSIM")] + ["frames/s"]
    frame = args.frames // 2 if args.figure_frame is None else args.figure_frame
    text = header("Comparison with other methods (paper Table 3, Figs. 8-9)", started)
    text += (f"The first {args.frames} frames of each test scene (scenes 1-2 at SNR 1.3, scene 3 at SNR 3, "
             f"{jaxsr.DEFAULT_MEAN_SIGNAL:g} signal photons per LR pixel, noise seed {args.seed}); PSNR (dB) and "
             f"SSIM of the clipped output against the normalised ground truth. Ours: {weights_source(args.weights)}. "
             "frames/s: end to end on this machine (16 frames of histograms -> centre of mass or ML fit -> "
             f"upscaling; ours with the {FPS_NOTE}); the paper's are on an RTX 2070. "
             "TV multi-frame: `jaxsr.recon.tv_super_resolve` "
             "(robust data term over 3 frames + smoothed TV, L-BFGS), defaults chosen on a validation sequence. "
             "iSeeBetter and HistNet are quoted from the paper, not run here.\n\n")
    text += markdown_table(columns, rows)
    text += (f"\nFigures: `compare_frames.png` (frame {frame} of each scene, every method) and "
             f"`compare_errors.png` (|SR - GT| of the same frames).\n")
    write_atomic(f"{args.out}.md", text)
    figures(f"{args.out}_frames.png", f"{args.out}_errors.png", clips, outputs, frame)
    print(f"wrote {args.out}.md, _frames.png, _errors.png ({time.time() - started:.0f} s)")


if __name__ == "__main__":
    main()
