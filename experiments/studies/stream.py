"""Sequence-form models beside the windowed ones of the same TR, at equal training time: the three test scenes, the
frame-rate study, temporal coherence, frames/s and FLOPs per frame, and the speed-accuracy plot.

    python experiments/studies/stream.py [--trs 1 2 3 4] [--frames 100] [--fps-frames 48]

Three models per TR: the bundled windowed model (trN, the paper's form), the same weights run in the sequence
form (trN in sequence form: no training, 2R frames of context more, edge padding at the sequence ends), and the
bundled sequence-form model (trN-seq, trained in that form for as long as trN was; its card and
results/weights_sequence.md say how long). A TR without trN-seq.npz is skipped. Everything is measured in one run
on this machine: frames/s end to end from photon histograms, PSNR / SSIM on the test scenes' first --frames
frames and the frame-rate study's walkers at 1-100 FPS on their first --fps-frames (sweep_tr.py and fps_study.py
spread theirs over 500 frames), and Tc at eps 0.01 as in `coherence.py` (walkers at 25 FPS).
Writes experiments/results/stream.md and stream.png (PSNR against frames/s, with the windowed TR0).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import jaxsr
from jaxsr.nn import flops_per_frame
from jaxsr.runtime import enable_compilation_cache

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import (  # noqa: E402
    FPS_NOTE,
    SCENE_LABELS,
    TEST_SCENES,
    bundled,
    model_fps,
    score,
    test_clips,
    walkers_at,
    walkers_clip,
)
from harness.scoring import FRAME_RATES as RATES  # noqa: E402
from harness.reports import hand_written_tail, header, markdown_table, save_figure, write_atomic  # noqa: E402

KINDS = ("window", "window weights, sequence form", "sequence-trained")
HAND_WRITTEN = "## Reading"  # the hand-written section at the end of the results file, kept on re-runs


def models_of(tr: int) -> dict | None:
    """The three models of one TR (see the module docstring), or None where trN-seq is not bundled."""
    if bundled(f"tr{tr}-seq") is None:
        return None
    return dict(zip(KINDS, (jaxsr.load_model(f"tr{tr}"), jaxsr.load_model(f"tr{tr}", temporal="sequence"),
                            jaxsr.load_model(f"tr{tr}-seq"))))


def tc(sr, gt) -> float:
    return float(jaxsr.temporal_coherence(jnp.asarray(sr), jnp.asarray(gt), eps=0.01).mean)


def plot(path, points):
    """PSNR (mean over the scenes) against frames/s, one marker per form."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.8))
    for kind, marker in zip(KINDS, ("o", "s", "^")):
        pts = [(f, p, lab) for k, f, p, lab in points if k == kind]
        if pts:
            ax.plot([f for f, _, _ in pts], [p for _, p, _ in pts], marker, label=kind)
            for f, p, lab in pts:
                ax.annotate(lab, (f, p), textcoords="offset points", xytext=(4, 3), fontsize=7)
    ax.set_xscale("log")
    ax.set_xlabel("frames/s on this machine (end to end)")
    ax.set_ylabel("mean PSNR over the 3 test scenes (dB)")
    ax.legend(fontsize=7)
    save_figure(fig, path)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trs", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--frames", type=int, default=100, help="frames scored per test scene (default 100)")
    parser.add_argument("--fps-frames", type=int, default=48, help="frames per rate in the frame-rate study")
    parser.add_argument("--out", default="experiments/results/stream")
    args = parser.parse_args()
    started = time.time()
    enable_compilation_cache()
    sensor = jaxsr.Sensor()
    clips = test_clips(args.frames)
    clip0 = clips[TEST_SCENES[0]]
    walkers = {fps: walkers_clip(fps, args.fps_frames, t0=0.0, seed=0, sensor=sensor)[0] for fps in RATES}
    still, _ = walkers_at(25.0, 100)

    rows, rate_rows, points = [], [], []
    tr0 = jaxsr.load_model("tr0")
    tr0_psnr = np.mean([score(jaxsr.super_resolve(tr0, c.lr, form="model"), c.gt)[0] for c in clips.values()])
    points.append(("window", model_fps(tr0, clip0), tr0_psnr, "TR0"))
    for tr in args.trs:
        models = models_of(tr)
        if models is None:
            print(f"TR{tr}: no bundled tr{tr}-seq, skipped", flush=True)
            continue
        for kind, model in models.items():
            scores = {n: score(jaxsr.super_resolve(model, c.lr, form="model"), c.gt) for n, c in clips.items()}
            fps = model_fps(model, clip0)
            flops = flops_per_frame(model.config) / 1e9
            rates = [score(jaxsr.super_resolve(model, walkers[r].lr, form="model"), walkers[r].gt)[0] for r in RATES]
            coherence = tc(jaxsr.super_resolve(model, still.lr, form="model"), still.gt)
            card = jaxsr.read_metadata(bundled(f"tr{tr}-seq" if kind == KINDS[2] else f"tr{tr}"))["card"]
            mean = float(np.mean([s[0] for s in scores.values()]))
            rows.append([f"TR{tr}", kind] + [f"{scores[n][0]:.2f} / {scores[n][1]:.3f}" for n in TEST_SCENES]
                        + [f"{mean:.2f}", f"{coherence:.0f}", f"{fps:.1f}", f"{flops:.1f}",
                           f"{card['steps']} / {card['wall_time_s'] / 60:.0f}"])
            rate_rows.append([f"TR{tr}", kind] + [f"{p:.2f}" for p in rates])
            points.append((kind, fps, mean, f"TR{tr}"))
            print(*rows[-1], "|", *rate_rows[-1][2:], flush=True)

    text = header("Sequence form and streaming: sequence-trained models beside the windowed ones", started)
    text += (f"Models per TR: `trN` (window form, bundled), the same weights in the sequence form "
             "(`load_model('trN', temporal='sequence')`, not retrained) and `trN-seq` (trained in the sequence "
             "form for at least trN's training time: experiments/studies/train_sequence_bundle.py, "
             "results/weights_sequence.md). "
             f"Test scenes: their first {args.frames} frames (sweep_tr.py spreads its frames over the whole sequence, "
             "so the numbers differ from Table 1's), cells PSNR (dB) / SSIM of the clipped output. "
             "Tc: mean flickering static pixels per frame pair at eps 0.01, walkers at 25 FPS, its first 100 "
             f"frames (coherence.py scores all 125; lower is steadier). frames/s: end to end from histograms, "
             f"{FPS_NOTE}; the sequence form "
             "runs chunks of 32 frames with 2R frames of overlap. GFLOP per output frame: `flops_per_frame` in the "
             "model's form. Training: steps / minutes from the card (the windowed cards were written on another "
             "machine: results/weights.md).\n\n")
    text += markdown_table(["TR", "model"] + [SCENE_LABELS[n] for n in TEST_SCENES]
                           + ["mean PSNR", "Tc", "frames/s", "GFLOP", "train steps / min"], rows)
    text += (f"\nWindowed TR0 for reference: mean PSNR {tr0_psnr:.2f} dB, "
             f"{points[0][1]:.1f} frames/s.\n\n"
             f"## Frame-rate study (walkers, {args.fps_frames} frames per rate, PSNR dB)\n\n")
    text += markdown_table(["TR", "model"] + [f"{r:g} FPS" for r in RATES], rate_rows)
    text += f"\nPlot: `{args.out.split('/')[-1]}.png` (mean PSNR against frames/s).\n"
    text += hand_written_tail(f"{args.out}.md", HAND_WRITTEN)
    write_atomic(f"{args.out}.md", text)
    plot(f"{args.out}.png", points)
    print(f"wrote {args.out}.md, .png ({time.time() - started:.0f} s)")


if __name__ == "__main__":
    main()
