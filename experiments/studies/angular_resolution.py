"""What a different angular resolution costs: the bundled models (trained on 32 x 64 LR frames over a 30 deg
horizontal field of view, 0.47 deg per LR pixel) on the three test scenes rendered with other sensors.

    python experiments/studies/angular_resolution.py [--frames 16] [--trs 0 4] [--weights DIR]

Each setting renders the same fixed scenes (same cameras, same motion) through another `Sensor`
(HR = 4 x LR, square pixels), simulates histograms at each scene's SNR, takes the centre of mass and scores
bicubic and the models against that sensor's own HR ground truth. Two photon levels: the calibrated
14 signal photons per LR pixel for every sensor (the sensor is changed, the photon budget per pixel is not),
and, for the finer and coarser pitch, the photons a pixel of that solid angle would collect from the same
laser and exposure (14 x (pitch / 0.47 deg)^2).
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import NamedTuple
from pathlib import Path

import jax
import numpy as np

import jaxsr
from jaxsr import scenes
from jaxsr.config import DEFAULT_MEAN_SIGNAL, Optics, Sensor
from jaxsr.runtime import enable_compilation_cache

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import SCENE_LABELS, TEST_SCENES, add_model_args, load_tr, score, simulate_clip, weights_source  # noqa: E402
from harness.reports import hand_written_tail, header, markdown_table, write_atomic  # noqa: E402

NATIVE = Sensor()


class Setting(NamedTuple):
    """A sensor to render the test scenes with: LR (rows, cols), horizontal field of view (deg), and the signal
    photons per LR pixel relative to the calibrated level (1: same per pixel)."""

    label: str
    lr_shape: tuple[int, int]
    fov_deg: float
    photon_factor: float = 1.0


def pitch_deg(lr_shape, fov_deg) -> float:
    """Mean horizontal angle per LR pixel (deg)."""
    return fov_deg / lr_shape[1]


def same_laser_factor(lr_shape, fov_deg) -> float:
    """Signal photons per pixel relative to the native sensor for the same laser and exposure: a pixel collects
    in proportion to its solid angle, (pitch / native pitch)^2 for square pixels."""
    return (pitch_deg(lr_shape, fov_deg) / pitch_deg(NATIVE.lr_shape, float(NATIVE.fov_deg))) ** 2


def sensor_of(setting: Setting) -> Sensor:
    """The simulated sensor of a setting: HR = scale x LR, the setting's field of view, all else native."""
    h, w = setting.lr_shape
    return Sensor(optics=Optics.of_hr((h * NATIVE.scale, w * NATIVE.scale), fov_deg=setting.fov_deg))


SETTINGS = (
    Setting("native (trained)", (32, 64), 30.0),
    Setting("coarser, same FOV", (16, 32), 30.0),
    Setting("finer, same FOV", (64, 128), 30.0),
    Setting("same pitch, half FOV", (32, 32), 15.0),
    Setting("finer, half FOV", (64, 64), 15.0),
    Setting("coarser, same FOV, same laser", (16, 32), 30.0, same_laser_factor((16, 32), 30.0)),
    Setting("finer, same FOV, same laser", (64, 128), 30.0, same_laser_factor((64, 128), 30.0)),
)


def pitch_ratio(setting: Setting) -> int:
    """How many of the setting's pixels make one native-pitch pixel along each axis (2: twice as fine; -2: twice
    as coarse; 1: the native pitch). Only whole ratios are resampled."""
    r = pitch_deg(NATIVE.lr_shape, float(NATIVE.fov_deg)) / pitch_deg(setting.lr_shape, setting.fov_deg)
    return round(r) if r >= 1 else -round(1 / r)


def block_mean(x, r: int):
    """(..., h, w) -> (..., h / r, w / r): the mean over r x r blocks."""
    *lead, h, w = x.shape
    return x.reshape(*lead, h // r, r, w // r, r).mean(axis=(-3, -1))


def via_trained_pitch(model, counts, ratio: int):
    """Super-resolve at the pitch the model was trained on, then return to the sensor's HR grid.

    Finer sensor (ratio r > 1): sum the histograms of r x r pixels (binning on the sensor, r^2 the photons),
    centre of mass, x4, bicubic x r. Coarser (ratio -r): centre of mass, bicubic x r to the trained pitch, x4,
    mean over r x r blocks. Returns (T, 4h, 4w) normalised depth on the sensor's HR grid."""
    if ratio > 1:
        t, h, w, k = counts.shape
        binned = counts.reshape(t, h // ratio, ratio, w // ratio, ratio, k).sum(axis=(2, 4))
        sr = jaxsr.super_resolve(model, np.asarray(jaxsr.centre_of_mass(binned, NATIVE)), form="model")
        return np.asarray(jaxsr.bicubic(sr, scale=ratio))
    lr = np.clip(np.asarray(jaxsr.bicubic(jaxsr.centre_of_mass(counts, NATIVE), scale=-ratio)), 0, 1)  # overshoots
    return block_mean(jaxsr.super_resolve(model, lr, form="model"), -ratio)


def run_setting(setting: Setting, models: dict, *, frames: int, seed: int, sequences: dict):
    """Scores of bicubic and each model at one setting. Returns {method: [(psnr, ssim) per scene]}."""
    sensor = sensor_of(setting)
    mean_signal = DEFAULT_MEAN_SIGNAL * setting.photon_factor
    ratio = pitch_ratio(setting)
    result = {m: [] for m in ("bicubic", *models)}
    for i, name in enumerate(TEST_SCENES):
        clip = simulate_clip(jax.random.key(seed * 1000 + i), sequences[name], sensor=sensor,
                             mean_signal=mean_signal)
        result["bicubic"].append(score(np.asarray(jaxsr.bicubic(clip.lr, scale=sensor.scale)), clip.gt))
        for m, model in models.items():
            result[m].append(score(jaxsr.super_resolve(model, clip.lr, form="model"), clip.gt))
            if ratio != 1:
                result.setdefault(f"{m} at the trained pitch", []).append(
                    score(via_trained_pitch(model, clip.counts, ratio), clip.gt))
    return result


def cell(scores) -> str:
    """'PSNR / SSIM' of the mean over scenes."""
    p, s = np.mean(scores, axis=0)
    return f"{p:.2f} / {s:.3f}"


def gain(scores, base) -> str:
    """Mean PSNR gain (dB) over `base`."""
    return f"{np.mean([a[0] - b[0] for a, b in zip(scores, base)]):+.2f}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=16, help="frames per scene (default 16)")
    add_model_args(parser, trs=(0, 4))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="experiments/results/angular_resolution.md")
    args = parser.parse_args()
    started = time.time()
    enable_compilation_cache()
    models = {f"TR{tr}": load_tr(tr, args.weights) for tr in args.trs}
    methods = ["bicubic", *models]
    rendered, results, seconds = {}, {}, {}
    for setting in SETTINGS:
        t0 = time.time()
        geometry = (setting.lr_shape, setting.fov_deg)
        if geometry not in rendered:  # the photon-level variants reuse the rendering
            rendered[geometry] = scenes.test_sequences(n_frames=args.frames, names=TEST_SCENES,
                                                       sensor=sensor_of(setting))
        results[setting] = run_setting(setting, models, frames=args.frames, seed=args.seed,
                                       sequences=rendered[geometry])
        seconds[setting] = time.time() - t0
        print(f"{setting.label}: " + ", ".join(f"{m} {cell(v)}" for m, v in results[setting].items())
              + f" ({seconds[setting]:.0f} s)", flush=True)

    columns = ["setting", "LR (rows x cols)", "FOV (deg)", "deg / LR px", "signal photons / LR px", *methods,
               *(f"{m} - bicubic (dB)" for m in models)]
    rows = [[s.label, f"{s.lr_shape[0]} x {s.lr_shape[1]}", f"{s.fov_deg:g}",
             f"{pitch_deg(s.lr_shape, s.fov_deg):.3f}", f"{DEFAULT_MEAN_SIGNAL * s.photon_factor:g}",
             *(cell(results[s][m]) for m in methods),
             *(gain(results[s][m], results[s]["bicubic"]) for m in models)] for s in SETTINGS]
    resampled = [s for s in SETTINGS if pitch_ratio(s) != 1]
    resampled_rows = [[s.label, f"{pitch_ratio(s):+d}"] + [cell(results[s][f"{m}{how}"]) for m in models
                                                          for how in ("", " at the trained pitch")]
                      for s in resampled]
    scene_rows = [[s.label, m] + [f"{p:.2f} / {q:.3f}" for p, q in v] for s in SETTINGS for m, v in results[s].items()]
    text = header("Angular resolution: the bundled models on sensors they were not trained on", started)
    text += (f"The three test scenes (same scene parameters, cameras and motion as Table 1), first {args.frames} "
             f"frames each, rendered with each sensor (HR = 4 x LR), simulated at each scene's SNR (1.3, 1.3, 3) "
             f"with noise seed {args.seed}, centre of mass, then bicubic and {', '.join(models)} "
             f"({weights_source(args.weights)}), scored against that sensor's HR ground truth (PSNR dB / SSIM, "
             "windowed; mean of the three scenes). The models were trained on the first row's sensor only. "
             "'same laser' rows scale the signal photons per pixel with the pixel's solid angle (the ambient "
             "follows from the SNR); the training draws 7-28 photons per pixel, so 3.5 and 56 lie outside it. "
             "With 16 frames the native row differs from Table 1 (100 frames).\n\n")
    text += markdown_table(columns, rows)
    text += ("\nRun at the sensor's own pitch (as above) or resampled to the pitch the models were trained on: a "
             "finer sensor's histograms summed over 2 x 2 pixels (4x the photons per pixel), x4, then bicubic x2 to "
             "the sensor's HR grid; a coarser sensor's depth bicubic x2, x4, then averaged over 2 x 2 blocks. "
             "Ratio: sensor pixels per trained pixel along each axis (-2: twice as coarse).\n\n")
    text += markdown_table(["setting", "ratio", *(f"{m}{how}" for m in models
                                                  for how in (", own pitch", ", trained pitch"))], resampled_rows)
    text += "\nPer scene:\n\n"
    text += markdown_table(["setting", "method", *(SCENE_LABELS[n] for n in TEST_SCENES)], scene_rows)
    text += "\nSeconds per setting (render, simulate, super-resolve, score): " + ", ".join(
        f"{s.label} {seconds[s]:.0f}" for s in SETTINGS) + "\n"
    text += hand_written_tail(args.out, "## Reading")
    write_atomic(args.out, text)
    print(f"wrote {args.out} ({time.time() - started:.0f} s)")


if __name__ == "__main__":
    main()
