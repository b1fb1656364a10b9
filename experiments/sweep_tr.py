"""Temporal-radius sweep (the paper's Table 1 and Fig. 5): score TR0-TR4 on the three test scenes, measure
frames/s on this machine, and plot the speed-accuracy trade.

    python experiments/sweep_tr.py                   # the bundled weights (a few minutes on 2 CPU cores)
    python experiments/sweep_tr.py --train cpu       # train first with the cpu preset (2 CPU cores: 20-40 min)
    python experiments/sweep_tr.py --train paper     # the paper's schedule (a GPU)
    python experiments/sweep_tr.py --quick           # smoke run of the training pipeline (under 3 min)
    python experiments/sweep_tr.py --train cpu --scale 8   # the supplement's x8 study (LR 16 x 32 -> 128 x 256)
    python experiments/sweep_tr.py --frames 500 --sequence-form   # every frame, and tr<N>-seq (results/sweep_tr.md)

Scores are means over --frames frames spread evenly over each 500-frame test sequence (100 by default), not
its first frames: the scenes change along it.

With the bundled weights and --sequence-form, the sequence-form models tr<N>-seq, where present, are scored
beside the windowed ones and drawn in the speed-accuracy plot (each frame of theirs is computed with the whole
sequence: about 1.5 minutes per model). Training runs go to runs/sweep_tr/<preset>/x<scale>/tr<N> and resume
where they stopped; a finished run is loaded, not retrained. Writes experiments/results/sweep_tr[_x8][_<preset>|
_quick].{md,csv,png} (the _pareto.png beside it: PSNR against frames/s; both with 95 % intervals) and .mp4 (a
short comparison video: bicubic | TR0 | TR4 | truth), and prints where they are.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import numpy as np

import jaxsr
from jaxsr.config import PRESETS, ModelConfig, Optics, Sensor
from jaxsr.nn import Model, init_model
from jaxsr.runtime import enable_compilation_cache

from harness.scoring import (
    BLOCK,
    FPS_NOTE,
    PAPER_BICUBIC,
    PAPER_TABLE1,
    SCENE_LABELS,
    TEST_SCENES,
    Scores,
    bicubic_fps,
    bundled,
    SEQUENCE_FRAMES,
    format_interval,
    get_model,
    interval,
    model_fps,
    scene_metrics,
    frame_metrics,
    test_clips,
)
from harness.reports import header, markdown_table, save_figure, write_atomic

# Table 1's columns per scene: the paper's Eq. 2 SSIM heads, the windowed one beside it
METRIC_LABELS = ("PSNR", "SSIM Eq. 2", "SSIM 11x11")

VIDEO_FRAMES = 32  # consecutive frames of the first test scene in the comparison video


def bicubic_row(clips, scale) -> tuple[dict, np.ndarray]:
    """Bicubic's mean `Scores` (PSNR, SSIM Eq. 2, windowed SSIM) per scene, and its per-frame PSNR (scenes,
    frames)."""
    scored = {name: c.at(c.scored) for name, c in clips.items()}
    means, frames = {}, []
    for name, c in scored.items():
        scores = frame_metrics(np.asarray(jaxsr.bicubic(c.lr, scale=scale)), c.gt)
        means[name] = scores.mean()
        frames.append(scores.psnr)
    return means, np.stack(frames)


def mean_interval(frames):
    """(mean, low, high) of the mean PSNR over frames (scenes, T) or (T,), 95 % block bootstrap (`interval`)."""
    iv = interval(frames, np.zeros_like(frames))
    return float(iv.mean), float(iv.low), float(iv.high)


def error_bar(ivs):
    """matplotlib's yerr (2, n) from (mean, low, high) triples."""
    return np.array([[m - lo for m, lo, _ in ivs], [hi - m for m, _, hi in ivs]])


def comparison_video(path, clip, models, scale, *, frames=32, fps=8.0, sensor=Sensor()):
    """A short video of the clip's first `frames` consecutive frames: bicubic | each model | truth, in metres on
    one colour scale (`jaxsr.io.DepthVideoWriter`). models: {label: Model}. Returns the frames written."""
    from jaxsr.io import DepthVideoWriter

    n = min(frames, len(clip.lr))
    lr, gt = np.asarray(clip.lr[:n]), np.asarray(clip.gt[:n])
    outs = [np.asarray(jaxsr.bicubic(lr, scale=scale))] + [np.asarray(jaxsr.super_resolve(m, lr, form="model"))
                                                           for m in models.values()]
    metres = lambda a: np.asarray(jaxsr.denormalise_depth(np.clip(a, 0, 1), sensor))  # noqa: E731
    panels = [metres(a) for a in (*outs, gt)]
    labels = ("bicubic", *models, "truth")
    with DepthVideoWriter(path, gt.shape[1:], labels=labels, fps=fps, d_max=float(sensor.d_max), frames=n,
                          overwrite=True) as video:
        for t in range(n):
            video.write(*(p[t] for p in panels))
    return video.frames_written


def untrained(scale: int) -> Model:
    """TR0 with its initial weights: Glorot-small filter logits make every dynamic filter a near-uniform 5 x 5
    average, so it upsamples a box-smoothed LR depth. The floor that training starts from."""
    cfg = ModelConfig(tr=0, scale=scale)
    return Model(*init_model(jax.random.key(0), cfg), cfg)


def pareto(points):
    """Indices of the points not beaten in both frames/s and PSNR by another point."""
    return [i for i, (f, p) in enumerate(points)
            if not any(f2 >= f and p2 >= p and (f2, p2) != (f, p) for f2, p2 in points)]


def plot(path, rows, bicubic, fps_bicubic, seq_rows=None, bicubic_frames=None):
    """PSNR and SSIM against TR per scene (paper Fig. 5), and PSNR against frames/s with the Pareto front; PSNR
    with its 95 % interval over frames (block bootstrap, `interval`) where per-frame scores are at hand."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    trs = sorted(rows)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for k, name in enumerate(TEST_SCENES):
        for ax, i in zip(axes, (0, 1)):
            ys = [rows[tr]["scores"][name][i] for tr in trs]
            if i == 0 and all("frames" in rows[tr] for tr in trs):
                ax.errorbar(trs, ys, yerr=error_bar([mean_interval(rows[tr]["frames"][k]) for tr in trs]),
                            fmt="o-", capsize=3, label=SCENE_LABELS[name])
            else:
                ax.plot(trs, ys, "o-", label=SCENE_LABELS[name])
            colour = ax.lines[-1].get_color()
            ax.axhline(bicubic[name][i], ls=":", lw=0.8, color=colour)
            if i == 1:  # the windowed SSIM beside the paper's Eq. 2
                ax.plot(trs, [rows[tr]["scores"][name].ssim_window for tr in trs], "s--", ms=3, lw=0.8, color=colour)
    for ax, label in zip(axes, ("PSNR (dB)", "SSIM (solid: Eq. 2, whole frame; dashed: 11 x 11 window)")):
        ax.set_xlabel("temporal radius TR")
        ax.set_ylabel(label, fontsize=8 if ax is axes[1] else None)
        ax.set_xticks(trs)
    axes[0].legend(fontsize=8, title="dotted: bicubic; bars: 95 % intervals", title_fontsize=7)
    save_figure(fig, path)

    fig, ax = plt.subplots(figsize=(5, 3.6))
    pts = [(rows[tr]["fps"], np.mean([rows[tr]["scores"][n][0] for n in TEST_SCENES])) for tr in trs]
    pts.append((fps_bicubic, np.mean([bicubic[n][0] for n in TEST_SCENES])))
    labels = [f"TR{tr}" for tr in trs] + ["bicubic"]
    per_frame = [rows[tr].get("frames") for tr in trs] + [bicubic_frames]
    for tr, r in (seq_rows or {}).items():
        pts.append((r["fps"], np.mean([r["scores"][n][0] for n in TEST_SCENES])))
        labels.append(f"TR{tr}-seq")
        per_frame.append(r.get("frames"))
    front = sorted(pareto(pts), key=lambda i: pts[i][0])
    ax.plot([pts[i][0] for i in front], [pts[i][1] for i in front], "-", color="0.6", label="Pareto front")
    for (f, p), lab, fr in zip(pts, labels, per_frame):
        if fr is None:
            ax.plot(f, p, "^" if lab.endswith("-seq") else "o")
        else:
            ax.errorbar([f], [p], yerr=error_bar([mean_interval(fr)]), fmt="^" if lab.endswith("-seq") else "o",
                        capsize=3)
        ax.annotate(lab, (f, p), textcoords="offset points", xytext=(4, 4), fontsize=8)
    ax.set_xscale("log")
    ax.set_xlabel("frames/s on this machine (end to end)")
    ax.set_ylabel("mean PSNR, 3 scenes (dB; 95 % int.)")
    ax.legend(fontsize=8)
    save_figure(fig, str(path).replace(".png", "_pareto.png"))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train", choices=sorted(PRESETS), default=None, metavar="PRESET",
                        help=f"train TR0-TR4 with this preset ({', '.join(sorted(PRESETS))}) first; default: score "
                        "the bundled weights")
    parser.add_argument("--quick", action="store_true", help="smoke run: TR0 and TR1, 2 training steps, 8 frames")
    parser.add_argument("--scale", type=int, default=4, choices=[4, 8], help="upscaling factor (default 4)")
    parser.add_argument("--trs", type=int, nargs="+", default=None, help="temporal radii (default 0 1 2 3 4)")
    parser.add_argument("--frames", type=int, default=None,
                        help=f"frames scored per test scene, spread evenly over its {SEQUENCE_FRAMES} (default 100; "
                        f"{SEQUENCE_FRAMES}: all; --quick: the first 8)")
    parser.add_argument("--seed", type=int, default=0, help="noise seed of the test data")
    parser.add_argument("--sequence-form", action="store_true",
                        help="also score the bundled sequence-form models (tr<N>-seq)")
    parser.add_argument("--runs", default="runs/sweep_tr", help="training folder (default runs/sweep_tr)")
    parser.add_argument("--results", default="experiments/results", help="where the tables and plots go")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args()
    started = time.time()
    enable_compilation_cache()
    trs = args.trs or ([0, 1] if args.quick else [0, 1, 2, 3, 4])
    frames = args.frames or (8 if args.quick else 100)
    sensor = Sensor(optics=Optics.of_hr(Sensor().hr_shape, args.scale))
    pretrained = args.train is None and not args.quick
    preset = args.train or "cpu"
    suffix = ("_x8" if args.scale == 8 else "") + ("_quick" if args.quick else "" if pretrained else f"_{preset}")
    base = Path(args.results) / f"sweep_tr{suffix}"
    base.parent.mkdir(parents=True, exist_ok=True)

    clips = test_clips(frames, seed=args.seed, sensor=sensor, spread=not args.quick)
    bicubic, bicubic_frames = bicubic_row(clips, args.scale)
    clip0 = clips[TEST_SCENES[0]]
    min_time = 1.0 if args.quick else 3.0
    fps_bicubic = bicubic_fps(clip0, sensor=sensor, min_time=min_time)
    floor, floor_frames = scene_metrics(untrained(args.scale), clips)
    rows, models = {}, {}
    for tr in trs:
        t0 = time.time()
        model, card = get_model(tr, pretrained=pretrained, preset=preset, runs=Path(args.runs),
                                scale=args.scale, quick=args.quick, progress=not args.no_progress)
        scores, frames_psnr = scene_metrics(model, clips)
        fps = model_fps(model, clip0, min_time=min_time)
        rows[tr] = {"scores": scores, "frames": frames_psnr, "fps": fps, "card": card}
        if tr in (min(trs), max(trs)):
            models[f"TR{tr}"] = model
        print(f"TR{tr}: " + ", ".join(f"{SCENE_LABELS[n]} {p:.2f} dB / SSIM Eq. 2 {s:.3f} / windowed {w:.3f}"
                                      for n, (p, s, w) in scores.items())
              + f", {fps:.1f} frames/s ({time.time() - t0:.0f} s)", flush=True)
    seq_rows = {}  # the bundled sequence-form models (tr<N>-seq), scored the same way
    for tr in trs if pretrained and args.sequence_form else ():
        path = bundled(f"tr{tr}-seq")
        if path is None:
            print(f"TR{tr}-seq: not bundled since 0.2; `git checkout 949ee82 -- jaxsr/weights` restores it")
        else:
            model = jaxsr.load_model(path)
            scores, frames_psnr = scene_metrics(model, clips)
            seq_rows[tr] = {"scores": scores, "frames": frames_psnr, "fps": model_fps(model, clip0, min_time=min_time),
                            "card": jaxsr.read_metadata(path).get("card", {})}
            print(f"TR{tr}-seq: {np.mean([s.psnr for s in seq_rows[tr]['scores'].values()]):.2f} dB mean, "
                  f"{seq_rows[tr]['fps']:.1f} frames/s", flush=True)

    columns = ["method"] + [f"{SCENE_LABELS[n]} {m}" for n in TEST_SCENES for m in METRIC_LABELS] + ["frames/s"]
    table = [["bicubic"] + cells(bicubic) + [f"{fps_bicubic:.0f}"], ["TR0 untrained"] + cells(floor) + ["as TR0"]]
    table += [[f"TR{tr}"] + cells(r["scores"]) + [f"{r['fps']:.1f}"] for tr, r in rows.items()]
    table += [[f"TR{tr}-seq"] + cells(r["scores"]) + [f"{r['fps']:.1f}"] for tr, r in seq_rows.items()]
    paper = [["bicubic (paper)"] + paper_cells(PAPER_BICUBIC) + [f"{PAPER_BICUBIC[3]:.0f}"]]
    paper += [[f"TR{tr} (paper)"] + paper_cells(PAPER_TABLE1[tr]) + [f"{PAPER_TABLE1[tr][3]}"] for tr in trs]
    csv = ",".join(["method", *[f"{n}_{m}" for n in TEST_SCENES for m in Scores._fields], "fps"]) + "\n"
    csv += csv_row("bicubic", bicubic, fps_bicubic)
    csv += csv_row("TR0_untrained", floor, rows[0]["fps"] if 0 in rows else float("nan"))
    csv += "".join(csv_row(f"TR{tr}", r["scores"], r["fps"]) for tr, r in rows.items())
    csv += "".join(csv_row(f"TR{tr}-seq", r["scores"], r["fps"]) for tr, r in seq_rows.items())

    scored = (f"the first {frames} frames" if args.quick else f"all {SEQUENCE_FRAMES} frames"
              if frames >= SEQUENCE_FRAMES else f"{frames} frames spread evenly over the {SEQUENCE_FRAMES} frames")
    source = ("the bundled weights (jaxsr/weights)" if pretrained else
              "a 2-step smoke training (--quick: numbers are meaningless)" if args.quick else
              f"models trained here with the `{preset}` preset ({args.runs})")
    text = header(f"Temporal-radius sweep, x{args.scale} (paper Table 1, Fig. 5)", started)
    text += (f"Models: {source}. Test data: {scored} of each test scene (scenes 1-2 at SNR 1.3, "
             f"scene 3 at SNR 3, {jaxsr.config.DEFAULT_MEAN_SIGNAL:g} signal photons per LR pixel), "
             f"noise seed {args.seed}; "
             "PSNR (dB) and SSIM of the clipped output against the normalised HR ground truth, averaged over frames: "
             "SSIM Eq. 2 is the paper's (its Eq. 2: whole-frame means, variances and covariance, c1 = 1e-4, "
             "c2 = 9e-4, `jaxsr.ssim_global`), the one its SSIM columns are set beside; SSIM 11x11 is the windowed "
             "form (11 x 11 Gaussian window, sigma 1.5, `jaxsr.ssim`), which the paper does not report. "
             f"frames/s: end to end (histograms -> centre of mass -> network), {FPS_NOTE}, on this machine; "
             "the paper's "
             "are on an RTX 2070. TR0 untrained: the network with its initial weights (every dynamic filter a "
             "near-uniform 5 x 5 average, i.e. a box-smoothed LR depth upsampled): what smoothing alone gives, "
             "and what training starts from.\n\n")
    text += markdown_table(columns, table + paper)
    cards = [f"- TR{tr}: {r['card'].get('steps', '?')} steps, {r['card'].get('examples', '?')} examples, "
             f"{r['card'].get('wall_time_s', 0) / 60:.0f} min training on "
             f"{r['card'].get('hardware', {}).get('backend', '?')}"
             for tr, r in rows.items()]
    cards += [f"- TR{tr}-seq (the sequence form, `jaxsr.load_model('tr{tr}-seq')`): {r['card'].get('steps', '?')} "
              f"steps of {r['card'].get('train_config', {}).get('batch_size', '?')} clips, "
              f"{r['card'].get('wall_time_s', 0) / 60:.0f} min training" for tr, r in seq_rows.items()]
    text += "\nTraining of each model (from its card):\n\n" + "\n".join(cards) + "\n"
    vs_tr0 = {tr: interval(r["frames"], rows[0]["frames"]) for tr, r in rows.items() if tr} if 0 in rows else {}
    bought = interval(rows[0]["frames"], floor_frames) if 0 in rows else None
    checked = differences(rows, seq_rows, vs_tr0, bought) + "\n\n" + claims(rows, bicubic, vs_tr0)
    text += "\n" + checked + "\n"
    video_label = " | ".join(["bicubic", *models, "truth"])
    text += (f"\nPlots: `{base.name}.png` (PSNR and SSIM against TR), "
             f"`{base.name}_pareto.png` (PSNR against frames/s), PSNR with its 95 % interval over frames. "
             f"Video: `{base.name}.mp4`, {video_label} on the first {VIDEO_FRAMES} frames of "
             f"{SCENE_LABELS[TEST_SCENES[0]]}, in metres.\n")
    write_atomic(f"{base}.md", text)
    write_atomic(f"{base}.csv", csv)
    plot(f"{base}.png", rows, bicubic, fps_bicubic, seq_rows, bicubic_frames)
    n_video = comparison_video(f"{base}.mp4", clip0, models, args.scale, frames=VIDEO_FRAMES, sensor=sensor)
    print("\n" + markdown_table(columns, table + paper) + "\n" + checked)
    print(f"wrote {base}.md and {base}.csv (Table 1), {base}.png and {base}_pareto.png (the trade plots, with "
          f"intervals), {base}.mp4 ({video_label}, {n_video} frames) ({time.time() - started:.0f} s)")


def cells(scores) -> list[str]:
    """A table row's cells: PSNR, SSIM Eq. 2 and windowed SSIM of each test scene ({scene: `Scores`})."""
    return [f"{v:.{2 if i == 0 else 3}f}" for n in TEST_SCENES for i, v in enumerate(scores[n])]


def paper_cells(quoted) -> list[str]:
    """The paper's (PSNR, SSIM) per scene under PSNR and SSIM Eq. 2; it reports no windowed SSIM."""
    return [cell for psnr, ssim in quoted[:3] for cell in (f"{psnr:.2f}", f"{ssim:.3f}", "")]


def csv_row(label, scores, fps):
    return ",".join([label, *(f"{v:.4f}" for n in TEST_SCENES for v in scores[n]), f"{fps:.2f}"]) + "\n"


def differences(rows, seq_rows, vs_tr0, bought=None) -> str:
    """Every TR against TR0 (`vs_tr0`: TR -> interval), TR0 against its untrained self (`bought`) and each
    sequence-form model against the windowed one of its TR, with intervals."""
    lines = [f"Differences in mean PSNR over the three scenes (dB), with 95 % intervals from a paired bootstrap over "
             f"blocks of {BLOCK} consecutive scored frames (`jaxsr.paired_interval`; each scene resampled on its "
             "own). They say how "
             "much the frames chosen move a difference, not how much another training run would: for that, "
             "results/paper_scores.md (three seeds of every TR at the paper preset, all 500 frames).", ""]
    if bought is not None:
        lines.append(f"- TR0 - TR0 untrained (what training bought): {format_interval(bought)}")
    lines += [f"- TR{tr} - TR0: {format_interval(iv)}" for tr, iv in vs_tr0.items()]
    lines += [f"- TR{tr}-seq - TR{tr}: {format_interval(interval(r['frames'], rows[tr]['frames']))}"
              for tr, r in seq_rows.items() if tr in rows]
    return "\n".join(lines)


def claims(rows, bicubic, vs_tr0) -> str:
    """The paper's claims about this table, checked on the numbers above (not asserted)."""
    lines = ["Paper claims, measured:"]
    low_snr = [n for n in TEST_SCENES[:2]]
    margins = [rows[tr]["scores"][n][0] - bicubic[n][0] for tr in rows for n in low_snr]
    lines.append(f"- every TR beats bicubic by >= 4 dB at SNR 1.3 (scenes 1-2): smallest margin "
                 f"{min(margins):.2f} dB -> {'holds' if min(margins) >= 4 else 'does not hold'}")
    if 0 in rows and 4 in rows:
        gain = [rows[4]["scores"][n][0] - rows[0]["scores"][n][0] for n in TEST_SCENES]
        iv = vs_tr0[4]
        verdict = ("holds beyond the frame interval" if iv.low >= 0.5 else "holds on the mean only, inside the "
                   "frame interval" if iv.mean >= 0.5 else "does not hold")
        lines.append(f"- TR4 - TR0 >= 0.5 dB: {', '.join(f'{g:+.2f}' for g in gain)} dB per scene (mean "
                     f"{np.mean(gain):+.2f}, 95 % interval [{float(iv.low):+.2f}, {float(iv.high):+.2f}]) -> {verdict}")
    trs = sorted(rows)
    mean = [np.mean([rows[tr]["scores"][n][0] for n in TEST_SCENES]) for tr in trs]
    rising = all(b >= a - 0.05 for a, b in zip(mean, mean[1:]))
    lines.append(f"- PSNR rises with TR: mean PSNR {', '.join(f'TR{t} {m:.2f}' for t, m in zip(trs, mean))} -> "
                 f"{'monotone (within 0.05 dB)' if rising else 'not monotone'}")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
