"""Do the models use their neighbouring frames? A diagnostic for the frame-rate study's claims.

    python experiments/studies/temporal_use.py [--frames 48] [--weights DIR]

Each TR >= 1 runs twice on the same clips: on the true windows of 2 TR + 1 frames, and on "frozen" windows in
which every frame is the centre frame (a static scene as far as the network can tell). If the true windows
score no better than the frozen ones, the network ignores what its neighbours add and a TR's score reflects the
quality of that model alone, whatever the motion. Clips: the walkers scene at 1 and 100 FPS (as in
fps_study.py) and the three test scenes. Scores: PSNR over whole frames, and over the pixels that move (the
ground truth changes by more than 0.01 between frames t - 1 and t + 1), where the neighbours matter most.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxsr

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import SCENE_LABELS, add_model_args, load_tr, test_clips, walkers_clip, weights_source  # noqa: E402
from harness.reports import header, markdown_table, write_atomic  # noqa: E402


@jax.jit
def _run(model, windows):
    return model(windows)


def predict(model, lr, *, frozen: bool, chunk: int = 8):
    """(T, h, w) -> (T, H, W): the network on each frame's window, or on its centre frame repeated."""
    tr = model.config.tr
    out = []
    for i in range(0, lr.shape[0], chunk):
        w = jaxsr.windows(jnp.asarray(lr), tr)[i : i + chunk]
        if frozen:
            w = jnp.broadcast_to(w[:, tr : tr + 1], w.shape)
        out.append(np.asarray(_run(model, w)))
    return np.clip(np.concatenate(out), 0, 1)


def psnr_over(sr, gt, mask) -> float:
    """PSNR (dB, peak 1) of the pixels in mask, pooled over frames."""
    mse = np.mean((sr[mask] - gt[mask]) ** 2) if mask.any() else np.nan
    return float(10 * np.log10(1.0 / mse)) if mse > 0 else float("inf")


def moving_mask(gt, threshold: float = 0.01):
    """Pixels whose ground truth changes between the frames before and after (ends: one-sided)."""
    padded = np.concatenate([gt[:1], gt, gt[-1:]])
    return np.abs(padded[2:] - padded[:-2]) > threshold


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=48, help="frames per clip (default 48)")
    add_model_args(parser, trs=(1, 2, 3, 4))
    parser.add_argument("--out", default="experiments/results/temporal_use")
    args = parser.parse_args()
    started = time.time()
    sensor = jaxsr.Sensor()
    clips = {f"walkers {fps:g} FPS": walkers_clip(fps, args.frames, t0=0.0, seed=0, sensor=sensor)[0]
             for fps in (1.0, 100.0)}
    clips.update({SCENE_LABELS[n]: c for n, c in test_clips(args.frames).items()})
    masks = {name: moving_mask(c.gt) for name, c in clips.items()}
    rows = []
    for tr in args.trs:
        model = load_tr(tr, args.weights)
        for name, clip in clips.items():
            true, frozen = predict(model, clip.lr, frozen=False), predict(model, clip.lr, frozen=True)
            whole = np.ones_like(masks[name])
            gains = [psnr_over(true, clip.gt, m) - psnr_over(frozen, clip.gt, m) for m in (whole, masks[name])]
            rows.append([f"TR{tr}", name, f"{psnr_over(true, clip.gt, whole):.2f}", f"{gains[0]:+.2f}",
                         f"{100 * masks[name].mean():.1f}", f"{psnr_over(true, clip.gt, masks[name]):.2f}",
                         f"{gains[1]:+.2f}"])
            print(*rows[-1], flush=True)
    text = header("Do the models use their neighbouring frames? (true vs frozen windows)", started)
    text += (f"Models: {weights_source(args.weights)}. {args.frames} frames per clip (walkers: SNR 1.3 from "
             "t0 = 0 s, noise seed 0; test scenes: their first frames at their SNR). PSNR pooled over frames. "
             "'gain': PSNR on the true windows minus PSNR on frozen windows (every frame = the centre frame), "
             "over whole frames and over the moving pixels (ground truth changes by > 0.01 between t - 1 and "
             "t + 1; their share in %). "
             "A gain near 0 means the neighbours are not used.\n\n")
    text += markdown_table(["model", "clip", "PSNR", "gain", "moving %", "PSNR moving", "gain moving"], rows)
    write_atomic(f"{args.out}.md", text)
    print(f"wrote {args.out}.md ({time.time() - started:.0f} s)")


if __name__ == "__main__":
    main()
