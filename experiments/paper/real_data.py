"""Three public recordings end to end: two single-photon lidar scans of photon time tags and a ToF
camera depth video, each super-resolved x4 by the bundled TR0 and TR4 models and TR4 in the sequence form.

    python experiments/paper/real_data.py --data ../shared/realdata [--fraction 0.1] [--seed 0]

The data are not part of the project (sources: README "Real recordings"). No ground truth exists at 4x, so this
measures what can be measured: agreement of the SR output, averaged back over each 4 x 4 block, with the LR
input (how much the network changes the measured depth), and for the video the share of flickering pixels on
the static background. For tower it also builds the depth from a random 10 % of the photons (seeded),
super-resolves it and measures its agreement with the depth from all photons. Writes
experiments/results/real_data.{md,png}; a hand-written section of the .md (from HAND_WRITTEN on) is kept.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import scipy.io  # noqa: E402

import jaxsr  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import hand_written_tail, header, markdown_table, write_atomic  # noqa: E402

RESULTS = Path(__file__).resolve().parents[1] / "results"
MODELS = (("TR0", "tr0", "window"), ("TR4", "tr4", "window"), ("TR4 sequence", "tr4", "sequence"))
# The results file's commentary is written by hand after a run; a re-run regenerates everything above it.
HAND_WRITTEN = "## What this shows and what it does not"
# An all-photon tower pixel counts as the building (a reliable reference depth) when its peak bin holds at least
# this many photons: the ~6000 background photons spread over 160 x 160 x 16 bins put 3 in one bin almost never.
RELIABLE_PEAK = 3


def tags_to_lr(path, *, bins, time_unit_s, span=None):
    """Time tags -> (1, h, w) network depth, the gate spanning the photons seen; (lr, gate, scale, tags)."""
    tags = jaxsr.read_time_tags(path, time_unit_s=time_unit_s)
    gate = jaxsr.sensor.gate_of_tags(tags, bins=bins)
    scale = jaxsr.DepthScale.for_gate(gate, gate.length if span == "gate" else span)
    return tags_depth(tags, gate, scale), gate, scale, tags


def tags_depth(tags, gate, scale):
    """(T, h, w) network depth of time tags: histograms over `gate`, centre of mass, `scale`."""
    counts = jaxsr.histogram_time_tags(tags, gate)
    return np.asarray(jaxsr.sensor.to_network_depth(jaxsr.sensor.gate_depth(counts, gate), scale), np.float32)


def subsample_tags(tags, fraction: float, seed: int):
    """A random `fraction` of the photons, drawn without replacement (seeded): what a recording `fraction` as
    long would have caught (thinning a Poisson process leaves a Poisson process)."""
    keep = np.random.default_rng(seed).choice(tags.time.size, round(fraction * tags.time.size), replace=False)
    keep.sort()
    return dataclasses.replace(tags, pixel=tags.pixel[keep], frame=tags.frame[keep], time=tags.time[keep])


def depth_errors(estimate, reference, mask, *, metres: float, tolerance: float):
    """|estimate - reference| over `mask`: RMS and median (metres), the share within `tolerance` metres and the
    share the estimate gives no return (1.0).

    estimate, reference: network depth on the same grid; the estimate is clipped to [0, 1] and its 1.0 (no
    return) counts as a miss at that distance. metres: the scale's span (network 1.0 in metres)."""
    estimate = np.clip(estimate, 0, 1)
    err = np.abs(estimate - reference)[mask] * metres
    return (float(np.sqrt(np.mean(err ** 2))), float(np.median(err)), float(np.mean(err <= tolerance)),
            float(np.mean(estimate[mask] >= 1.0)))


def block_mean(hr, r=4):
    t, h, w = hr.shape
    return hr.reshape(t, h // r, r, w // r, r).mean(axis=(2, 4))


def agreement(lr, sr):
    """RMS of (SR averaged over each 4x4 block - LR) over LR pixels with a return (< 1), normalised units."""
    valid = lr < 1.0
    return float(np.sqrt(np.mean((np.clip(block_mean(sr), 0, 1) - lr)[valid] ** 2)))


def flicker(seq, static, eps=0.01):
    """Share of (t, pixel) on the static mask whose value changes by more than eps between frames."""
    d = np.abs(np.diff(np.clip(seq, 0, 1), axis=0)) > eps
    return float(d[:, static].mean())


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="folder holding tower.mat, two_layer.mat, tof_radar.mat")
    ap.add_argument("--frames", type=int, default=100, help="frames of the ToF video to run")
    ap.add_argument("--fraction", type=float, default=0.1, help="share of tower's photons in the subsample")
    ap.add_argument("--seed", type=int, default=0, help="seed of the tower photon subsample")
    args = ap.parse_args()
    jaxsr.runtime.use_cpu_cores()
    started = time.time()
    data = Path(args.data)
    models = {name: jaxsr.load_model(m, temporal=form) for name, m, form in MODELS}
    rows, notes = [], []

    # tower.mat: ps time tags, gate mm..MM (200 ns = 30 m), 3.7 photons per pixel; 16 bins as the trained sensor
    lr, gate, scale, tags = tags_to_lr(data / "tower.mat", bins=16, time_unit_s=1e-12)
    notes.append(f"tower: {tags.time.size} photons over {tags.shape[0]} x {tags.shape[1]} pixels "
                 f"({tags.photons_per_pixel:.2f} per pixel), gate {gate.length:.2f} m in 16 bins of "
                 f"{gate.bin_width:.3f} m, network 0 at the gate start, span 35 m; warnings: "
                 f"{jaxsr.sensor.gate_warnings(gate, scale) or 'none'}")
    # the same gate and scale for the subsample, so its depth compares with the all-photon depth directly
    lr_sub = tags_depth(subsample_tags(tags, args.fraction, args.seed), gate, scale)
    peak = jaxsr.histogram_time_tags(tags, gate).max(axis=-1)
    # two_layer.mat: times in the system's bins of unknown width: the gate filled onto the network's [0, 1]
    lr2, gate2, scale2, tags2 = tags_to_lr(data / "two_layer.mat", bins=16, time_unit_s=1e-12, span="gate")
    notes.append(f"two_layer: {tags2.time.size} photons over {tags2.shape[0]} x {tags2.shape[1]} pixels "
                 f"({tags2.photons_per_pixel:.1f} per pixel), time unit unknown (a nominal 1 ps; the depth is "
                 "then relative), 16 bins over the photons' span mapped onto [0, 1]; warnings: "
                 f"{jaxsr.sensor.gate_warnings(gate2, scale2) or 'none'}")
    # tof_radar.mat: normalised ToF depth (no metric scale), (100, 64, 64)
    video = np.asarray(scipy.io.loadmat(str(data / "tof_radar.mat"))["ToF_radar"], np.float32)[: args.frames]
    video = np.clip(np.nan_to_num(video, nan=1.0), 0.0, 1.0)

    timings = {}
    outputs = {}
    for rec, seq in (("tower", lr), ("two_layer", lr2), ("tof_radar", video)):
        for name, model in models.items():
            t0 = time.time()
            sr = jaxsr.super_resolve(model, seq, form="model")
            timings[(rec, name)] = time.time() - t0
            outputs[(rec, name)] = sr
            rows.append([rec, name, f"{seq.shape[1]} x {seq.shape[2]} x {seq.shape[0]}",
                         f"{agreement(seq, sr):.4f}", f"{timings[(rec, name)]:.1f}"])
        bic = np.asarray(jaxsr.bicubic(seq, scale=4))
        rows.append([rec, "bicubic", f"{seq.shape[1]} x {seq.shape[2]} x {seq.shape[0]}",
                     f"{agreement(seq, bic):.4f}", "-"])
        outputs[(rec, "bicubic")] = bic

    # tower, all photons against a subsample: outputs of the subsample on the LR grid against the all-photon depth
    for name in ("TR0", "TR4"):
        outputs[("tower_sub", name)] = jaxsr.super_resolve(models[name], lr_sub, form="model")
    outputs[("tower_sub", "bicubic")] = np.asarray(jaxsr.bicubic(lr_sub, scale=4))
    masks = {"with a return": lr < 1.0, f"building (peak bin >= {RELIABLE_PEAK} photons)": peak >= RELIABLE_PEAK}
    estimates = [(f"LR, {args.fraction:.0%} of photons", lr_sub)]
    estimates += [(f"{n} of the {args.fraction:.0%}, block mean", block_mean(outputs[("tower_sub", n)]))
                  for n in ("bicubic", "TR0", "TR4")]
    estimates += [(f"{n} of all photons, block mean", block_mean(outputs[("tower", n)])) for n in ("TR0", "TR4")]
    sub_rows = []
    for mask_name, mask in masks.items():
        for est_name, est in estimates:
            rms, med, within, none = depth_errors(est, lr, mask, metres=scale.span, tolerance=gate.bin_width)
            sub_rows.append([mask_name, f"{int(mask.sum())}", est_name, f"{rms:.2f}", f"{med:.2f}", f"{within:.3f}",
                             f"{none:.3f}"])
    # the same comparison at 4x against each method's own all-photon output: how much 90 % fewer photons move it
    hr_mask = np.kron(masks[f"building (peak bin >= {RELIABLE_PEAK} photons)"], np.ones((1, 4, 4), bool))
    self_rows = []
    for n in ("bicubic", "TR0", "TR4"):
        rms, med, within, none = depth_errors(outputs[("tower_sub", n)], np.clip(outputs[("tower", n)], 0, 1),
                                              hr_mask, metres=scale.span, tolerance=gate.bin_width)
        self_rows.append([n, f"{rms:.2f}", f"{med:.2f}", f"{within:.3f}", f"{none:.3f}"])

    # flicker on the video's static background: LR pixels in the lowest quartile of temporal std
    std = video.std(axis=0)
    static_lr = std <= np.quantile(std, 0.25)
    static = np.kron(static_lr, np.ones((4, 4), bool))
    nearest = np.kron(video, np.ones((1, 4, 4), np.float32))
    fl = [["LR (nearest)", f"{flicker(nearest, static):.4f}"]]
    fl += [[name, f"{flicker(outputs[('tof_radar', name)], static):.4f}"] for name in ("bicubic", *models)]

    # pictures: LR | SR per model | (no reference at 4x) for the two scans and one video frame
    fig, axes = plt.subplots(4, 5, figsize=(20, 16))
    rows_pic = (("tower", lr, 0), ("tower_sub", lr_sub, 0), ("two_layer", lr2, 0),
                ("tof_radar", video, len(video) // 2))
    for i, (rec, seq, t) in enumerate(rows_pic):
        pics = [("LR input", seq[t])] + [(n, np.clip(outputs[(rec, n)][t], 0, 1)) for n in ("bicubic", *models)
                                         if (rec, n) in outputs]
        ref = lr if rec == "tower_sub" else seq  # the subsample on the all-photon colour scale
        vmax = float(np.quantile(ref[ref < 1], 0.99))
        for ax, (title, img) in zip(axes[i], pics):
            ax.imshow(np.ma.masked_greater_equal(img, 1.0), cmap="turbo", vmin=0, vmax=vmax, interpolation="nearest")
            ax.set_title(f"{rec}: {title}")
        for ax in axes[i]:
            ax.axis("off")
    fig.tight_layout()
    fig.savefig(RESULTS / "real_data.png", dpi=60)
    # strip over time: frames 40..47 of the video, LR | TR0 | TR4
    fig, axes = plt.subplots(3, 8, figsize=(20, 8))
    for j, t in enumerate(range(40, 48)):
        for i, (title, img) in enumerate((("LR", video[t]), ("TR0", outputs[("tof_radar", "TR0")][t]),
                                          ("TR4", outputs[("tof_radar", "TR4")][t]))):
            axes[i, j].imshow(np.clip(img, 0, 1), cmap="turbo", vmin=0, vmax=1, interpolation="nearest")
            axes[i, j].set_title(f"{title} t={t}")
            axes[i, j].axis("off")
    fig.tight_layout()
    fig.savefig(RESULTS / "real_data_strip.png", dpi=60)

    text = header("Real recordings, end to end", started)
    text += "\n" + "\n".join(f"- {n}" for n in notes) + "\n\n"
    text += "Agreement of the output with its input (RMS of SR averaged over 4 x 4 blocks minus LR, on LR pixels "
    text += "with a return, normalised depth) and time per recording:\n\n"
    text += markdown_table(["recording", "method", "LR h x w x T", "block-mean RMS vs LR", "s"], rows)
    text += f"\nFlicker on the tof_radar video's static background ({int(static_lr.sum())} LR pixels, " \
            "the quarter with " \
            "the least temporal std; share of pixel-frames changing by > 0.01):\n\n"
    text += markdown_table(["method", "flicker"], fl)
    text += ("\nThe script also writes real_data.png (LR | bicubic | TR0 | TR4 | TR4 sequence; tower_sub: the "
             "subsample) and real_data_strip.png "
             "(the video, frames 40-47) beside this file: ![frames](real_data.png) ![video strip](real_data_strip.png) "
             "(pictures of the third-party recordings named above, shown as results; the recordings themselves are not "
             "part of the project: README 'Real recordings' says where each comes from).\n")
    n_sub = round(args.fraction * tags.time.size)
    text += (f"\ntower, all photons against a {args.fraction:.0%} subsample ({n_sub} of {tags.time.size} photons, "
             f"drawn without replacement with seed {args.seed}; {n_sub / (lr.shape[1] * lr.shape[2]):.2f} per pixel), "
             "both histogrammed over the same gate. Reference: the all-photon LR depth (centre of mass), a "
             "measurement no model has touched; each 4x output of the subsample is averaged over its 4 x 4 blocks "
             "onto that grid. Errors in metres (network 1.0 = 35 m); a no-return output counts as a miss at its "
             f"distance; 'within' = share within one bin ({gate.bin_width:.2f} m); 'no return' = share of the "
             "pixels the estimate leaves empty (1.0). The all-photon outputs' own block means, last rows, show how "
             "far each model moves from that reference when given every photon.\n\n")
    text += markdown_table(["pixels (all photons)", "LR pixels", "estimate", "RMS (m)", "median (m)", "within 1 bin",
                            "no return"], sub_rows)
    text += ("\nAt 4x, on the building's pixels: each method's output from the subsample against its own output from "
             "all photons (self-consistency, not accuracy):\n\n")
    text += markdown_table(["method", "RMS (m)", "median (m)", "within 1 bin", "no return"], self_rows)
    text += hand_written_tail(RESULTS / "real_data.md", HAND_WRITTEN)
    write_atomic(RESULTS / "real_data.md", text)
    print(text)


if __name__ == "__main__":
    main()
