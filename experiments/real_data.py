"""Three public recordings end to end (issue 16): two single-photon lidar scans of photon time tags and a ToF
camera depth video, each super-resolved x4 by the bundled TR0 and TR4 models and TR4 in the sequence form.

    python experiments/real_data.py --data ../shared/realdata

The data are not part of the project (sources: README "Real recordings"). No ground truth exists at 4x, so this
measures what can be measured: agreement of the SR output, averaged back over each 4 x 4 block, with the LR
input (how much the network changes the measured depth), and for the video the share of flickering pixels on
the static background. Writes experiments/results/real_data.{md,png}.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import scipy.io  # noqa: E402

import jaxsr  # noqa: E402
from _report import header, markdown_table, write_atomic  # noqa: E402

RESULTS = Path(__file__).parent / "results"
MODELS = (("TR0", "tr0", "window"), ("TR4", "tr4", "window"), ("TR4 sequence", "tr4", "sequence"))


def tags_to_lr(path, *, bins, time_unit_s, span=None):
    """Time tags -> (1, h, w) network depth, the gate spanning the photons seen; (lr, gate, scale)."""
    tags = jaxsr.read_time_tags(path, time_unit_s=time_unit_s)
    gate = jaxsr.gate_of_tags(tags, bins=bins)
    scale = jaxsr.DepthScale.for_gate(gate, gate.length if span == "gate" else span)
    counts = jaxsr.histogram_time_tags(tags, gate)
    lr = np.asarray(jaxsr.to_network_depth(jaxsr.gate_depth(counts, gate), scale), np.float32)
    return lr, gate, scale, tags


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
    args = ap.parse_args()
    jaxsr.use_cpu_cores()
    started = time.time()
    data = Path(args.data)
    models = {name: jaxsr.load_model(m, temporal=form) for name, m, form in MODELS}
    rows, panels, notes = [], [], []

    # tower.mat: ps time tags, gate mm..MM (200 ns = 30 m), 3.7 photons per pixel; 16 bins as the trained sensor
    lr, gate, scale, tags = tags_to_lr(data / "tower.mat", bins=16, time_unit_s=1e-12)
    notes.append(f"tower: {tags.time.size} photons over {tags.shape[0]} x {tags.shape[1]} pixels "
                 f"({tags.photons_per_pixel:.2f} per pixel), gate {gate.length:.2f} m in 16 bins of "
                 f"{gate.bin_width:.3f} m, network 0 at the gate start, span 35 m; warnings: "
                 f"{jaxsr.gate_warnings(gate, scale) or 'none'}")
    # two_layer.mat: times in the system's bins of unknown width: the gate filled onto the network's [0, 1]
    lr2, gate2, scale2, tags2 = tags_to_lr(data / "two_layer.mat", bins=16, time_unit_s=1e-12, span="gate")
    notes.append(f"two_layer: {tags2.time.size} photons over {tags2.shape[0]} x {tags2.shape[1]} pixels "
                 f"({tags2.photons_per_pixel:.1f} per pixel), time unit unknown (a nominal 1 ps; the depth is "
                 "then relative), 16 bins over the photons' span mapped onto [0, 1]; warnings: "
                 f"{jaxsr.gate_warnings(gate2, scale2) or 'none'}")
    # tof_radar.mat: normalised ToF depth (no metric scale), (100, 64, 64)
    video = np.asarray(scipy.io.loadmat(str(data / "tof_radar.mat"))["ToF_radar"], np.float32)[: args.frames]
    video = np.clip(np.nan_to_num(video, nan=1.0), 0.0, 1.0)

    timings = {}
    outputs = {}
    for rec, seq in (("tower", lr), ("two_layer", lr2), ("tof_radar", video)):
        for name, model in models.items():
            t0 = time.time()
            sr = jaxsr.super_resolve(model, seq)
            timings[(rec, name)] = time.time() - t0
            outputs[(rec, name)] = sr
            rows.append([rec, name, f"{seq.shape[1]} x {seq.shape[2]} x {seq.shape[0]}",
                         f"{agreement(seq, sr):.4f}", f"{timings[(rec, name)]:.1f}"])
        bic = np.asarray(jaxsr.bicubic(seq, scale=4))
        rows.append([rec, "bicubic", f"{seq.shape[1]} x {seq.shape[2]} x {seq.shape[0]}",
                     f"{agreement(seq, bic):.4f}", "-"])
        outputs[(rec, "bicubic")] = bic

    # flicker on the video's static background: LR pixels in the lowest quartile of temporal std
    std = video.std(axis=0)
    static_lr = std <= np.quantile(std, 0.25)
    static = np.kron(static_lr, np.ones((4, 4), bool))
    nearest = np.kron(video, np.ones((1, 4, 4), np.float32))
    fl = [["LR (nearest)", f"{flicker(nearest, static):.4f}"]]
    fl += [[name, f"{flicker(outputs[('tof_radar', name)], static):.4f}"] for name in ("bicubic", *models)]

    # pictures: LR | SR per model | (no reference at 4x) for the two scans and one video frame
    fig, axes = plt.subplots(3, 5, figsize=(20, 12))
    for i, (rec, seq, t) in enumerate((("tower", lr, 0), ("two_layer", lr2, 0), ("tof_radar", video, len(video) // 2))):
        pics = [("LR input", seq[t])] + [(n, np.clip(outputs[(rec, n)][t], 0, 1)) for n in ("bicubic", *models)]
        for ax, (title, img) in zip(axes[i], pics):
            ax.imshow(np.ma.masked_greater_equal(img, 1.0), cmap="turbo", vmin=0, vmax=float(np.quantile(seq[seq < 1], 0.99)),
                      interpolation="nearest")
            ax.set_title(f"{rec}: {title}")
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
    text += f"\nFlicker on the tof_radar video's static background ({int(static_lr.sum())} LR pixels, the quarter with " \
            "the least temporal std; share of pixel-frames changing by > 0.01):\n\n"
    text += markdown_table(["method", "flicker"], fl)
    text += ("\nThe script also writes real_data.png (LR | bicubic | TR0 | TR4 | TR4 sequence) and real_data_strip.png "
             "(the video, frames 40-47) beside this file; they are pictures of third-party data and are not "
             "committed (.gitignore): run the command to see them.\n")
    write_atomic(RESULTS / "real_data.md", text)
    print(text)


if __name__ == "__main__":
    main()
