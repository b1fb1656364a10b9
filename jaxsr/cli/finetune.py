"""`jaxsr finetune`: fine-tune a trained model to a sensor described in a TOML file (`jaxsr.training.finetune`,
`jaxsr.training.read_sensor_file`): bins, bin width, gate, pulse (a sigma or a measured IRF), resolution, photon
levels and SNR. It writes OUT/metrics.jsonl, OUT/best.npz and OUT/last.npz as `jaxsr train` does (--resume
continues, --force starts over), and says how to run the result: `jaxsr upscale --model OUT` with the sensor's
gate flags."""

from __future__ import annotations

import argparse
import shlex

from pathlib import Path

from ..config import PRESETS
from ..io.checkpoint import read_metadata
from ..training.presets import finetune
from ..training.sensor_file import read_sensor_file
from ._args import OldSpelling, add_force, add_output, add_quiet, int_range, required_output, seed


def add_parser(subparsers):
    p = subparsers.add_parser("finetune", help="fine-tune a model to your sensor (a TOML file of its parameters)")
    p.add_argument("--sensor", required=True, metavar="FILE",
                   help="the sensor's TOML file: [sensor] bins, bin width, gate, pulse, resolution; [photons] "
                   "signal and SNR ranges (see docs/finetune.md)")
    p.add_argument("-m", "--model", dest="init", default="tr4", metavar="MODEL",
                   help="the model to start from: tr0..tr4 (bundled), a checkpoint or a run folder (default tr4)")
    p.add_argument("--from", dest="init", action=OldSpelling, new="-m/--model", help=argparse.SUPPRESS)
    add_output(p, "output folder OUT (metrics.jsonl, best.npz, last.npz)")
    again = p.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true", help="continue the run in OUT (from last.npz or resume.npz)")
    add_force(p, "start a new run in OUT, replacing the run it holds", again)
    p.add_argument("--epochs", type=int_range(1), default=10, metavar="N", help="epochs to train (default 10)")
    p.add_argument("--steps-per-epoch", type=int_range(1), default=256, metavar="N",
                   help="optimiser steps per epoch (default 256, of the preset's batch of 4)")
    p.add_argument("--val-batches", type=int_range(1), default=16, metavar="N",
                   help="batches of the sensor's regime to validate on after each epoch (default 16)")
    p.add_argument("--preset", choices=sorted(PRESETS), default="bundle",
                   help="the preset whose batch, crops and rate (x 0.1) the fine-tune uses (default bundle)")
    p.add_argument("--photons", action="store_true",
                   help="read the photons behind each depth too (signal and background) and mark no return "
                   "(widens a depth-only model; it then needs histograms or time tags)")
    p.add_argument("--seed", type=seed, default=None, help="override the preset's seed (0..2^32-1)")
    p.add_argument("--checkpoint-minutes", type=float, default=10.0, metavar="M",
                   help="save the train state inside an epoch (OUT/resume.npz) every this many minutes of training "
                   "(default 10; 0: every step; inf: never)")
    add_quiet(p)
    p.set_defaults(func=run)


def _summary(info: dict) -> list[str]:
    """Lines for people: the gate, the pulse (and the IRF fit), the frame."""
    gate, irf = info["gate"], info["irf"]
    lines = [f"sensor {info['path']}: {gate['bins']} bins of {gate['bin_width_m']:.4g} m from {gate['start_m']:.6g} m "
             f"(the network's 0 .. 1 spans {gate['span_m']:.4g} m), {info['lr_shape'][0]} x {info['lr_shape'][1]} "
             f"LR pixels"]
    if irf["source"] == "irf_file":
        fit = irf["fit"]
        chi2 = "" if fit["reduced_chi2"] is None else f", reduced chi-square {fit['reduced_chi2']:.3g}"
        lines.append(f"pulse: Gaussian fitted to {irf['file']}: sigma {irf['sigma_bins']:.4g} bins, relative RMS "
                     f"residual {fit['residual']:.2%}{chi2} ({fit['samples']} samples)")
    else:
        lines.append(f"pulse: Gaussian, sigma {irf['sigma_bins']:.4g} bins")
    return lines


def run(args) -> int:
    """Fine-tune as the arguments say; prints the sensor, the best epoch and the upscale command."""
    out = required_output(args)
    _, _, info = read_sensor_file(args.sensor)  # a bad file is one error line before anything else
    for line in _summary(info):
        print(line)
    _, history = finetune(out, sensor_file=args.sensor, init=args.init, epochs=args.epochs,
                          steps_per_epoch=args.steps_per_epoch, val_batches=args.val_batches, preset=args.preset,
                          photons=True if args.photons else None, seed=args.seed, resume=args.resume,
                          overwrite=args.force, checkpoint_minutes=args.checkpoint_minutes,
                          progress=not args.no_progress)  # a warning: one line on stderr (`jaxsr.cli.main`)
    best = min(history, key=lambda r: r["val_loss"]) if history else None
    if best:
        start = read_metadata(Path(out) / "best.npz").get("card", {}).get("finetune", {}).get("start")
        against = [f"bicubic {best['val_bicubic_psnr']:.2f} dB"] if best.get("val_bicubic_psnr") is not None else []
        against += [f"the starting model {start['val_psnr']:.2f} dB"] if start else []
        print(f"best epoch {best['epoch']}: val loss {best['val_loss']:.3e}, val PSNR {best['val_psnr']:.2f} dB"
              + (f" ({', '.join(against)})" if against else "") + f" -> {Path(out) / 'best.npz'}")
    print(f"run it: jaxsr upscale RECORDING -o OUTPUT -m {shlex.quote(str(out))} --sensor "
          f"{shlex.quote(str(args.sensor))}  (RECORDING: the sensor's histograms, or time tags with -k timetags "
          "--time-unit ...)")
    return 0
