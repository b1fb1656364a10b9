"""The `jaxsr` command. Subcommands are separate functions registered in `COMMANDS`:

    jaxsr simulate --kind street --frames 20 --fps 25 --snr 1.3 --seed 0 --out DIR [--force]
    jaxsr simulate --input AIRSIM_FOLDER --out DIR [--snr 1.3]
    jaxsr train --tr 4 --preset cpu --out runs/tr4 [--resume]

`simulate` renders a procedural scene (or reads an AirSim recording), simulates SPAD photon histograms and the
centre-of-mass depth, and writes DIR/histograms.npz (counts, ground-truth depth, config), DIR/com_depth.npy
(T, h, w normalised depth), DIR/gt_depth.npy (T, H, W radial metres) and PNG previews of the first frame.
To add a subcommand: write `add_<name>(subparsers)` that registers its arguments and sets `func=run_<name>`, and
append it to `COMMANDS`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

__all__ = ["COMMANDS", "main"]


SIMULATE_OUTPUTS = ("histograms.npz", "com_depth.npy", "gt_depth.npy", "preview_gt.png", "preview_com.png",
                    "preview_intensity.png", "preview_strip.png")


def _out_dir(path, force):
    out = Path(path)
    out.mkdir(parents=True, exist_ok=True)
    clash = [n for n in SIMULATE_OUTPUTS if (out / n).exists()]
    if clash and not force:
        raise FileExistsError(f"{out} already holds {', '.join(clash)}; pass --force to overwrite")
    return out


def run_simulate(args):
    """Render or read depth + intensity, simulate histograms, extract centre-of-mass depth, write outputs."""
    import jax
    import jax.numpy as jnp

    from . import io
    from .config import DEFAULT_MEAN_SIGNAL, SensorConfig
    from .baselines import bicubic
    from .metrics import psnr, ssim
    from .peaks import centre_of_mass
    from .previews import write_comparison, write_gray_preview, write_preview
    from .sensor import normalise_depth, simulate_histograms

    sensor = SensorConfig()
    out = _out_dir(args.out, args.force)
    if args.input:
        rec = io.read_airsim(args.input, sensor=sensor)
        depth, intensity, fps = rec["depth"], rec["intensity"], rec["fps"]
        if depth.shape[1:] != sensor.hr_shape:
            raise ValueError(f"{args.input}: frames are {depth.shape[1:]}, the sensor expects {sensor.hr_shape}")
        source = dict(input=str(args.input))
    else:
        from .scenes import sequence

        key = jax.random.key(args.seed)
        depth, intensity = jax.jit(
            lambda k: sequence(k, args.frames, args.fps, kind=args.kind, sensor=sensor, camera=args.camera)
        )(key)
        fps = args.fps
        source = dict(kind=args.kind, seed=args.seed, camera=args.camera)
    mean_signal = DEFAULT_MEAN_SIGNAL if args.mean_signal is None else args.mean_signal
    counts = simulate_histograms(jax.random.key(args.seed + 1), jnp.asarray(depth), jnp.asarray(intensity), sensor,
                                 snr=args.snr, mean_signal=mean_signal)
    com = np.asarray(centre_of_mass(counts, sensor))
    meta = dict(source, fps=float(fps), snr=args.snr, mean_signal=mean_signal, frames=int(depth.shape[0]))
    io.write_histograms(out / "histograms.npz", np.asarray(counts), depth=np.asarray(depth), sensor=sensor,
                        overwrite=True, **meta)
    io.write_sequence(out / "com_depth.npy", com, overwrite=True)
    io.write_sequence(out / "gt_depth.npy", np.asarray(depth), overwrite=True)
    write_preview(out / "preview_gt.png", np.asarray(depth[0]), d_max=float(sensor.d_max), overwrite=True)
    write_preview(out / "preview_com.png", com[0], d_max=float(sensor.d_max), normalised=True, overwrite=True)
    write_gray_preview(out / "preview_intensity.png", np.asarray(intensity[0]), overwrite=True)
    # The baseline a network has to beat: bicubic upsampling of the centre-of-mass depth.
    gt = np.asarray(normalise_depth(jnp.asarray(depth), sensor))
    up = np.asarray(bicubic(com, scale=sensor.scale))
    write_comparison(out / "preview_strip.png", com[0], np.clip(up[0], 0, 1), gt=gt[0],
                     labels=("centre of mass", "bicubic", "ground truth"), overwrite=True)
    quality = dict(bicubic_psnr_db=round(float(np.mean(psnr(up, gt))), 2),
                   bicubic_ssim=round(float(np.mean(ssim(up, gt))), 3))
    print(json.dumps(dict(meta, **quality, out=str(out), counts_shape=list(counts.shape))))
    return 0


def add_simulate(subparsers):
    p = subparsers.add_parser("simulate", help="scene or AirSim folder -> histograms, centre-of-mass depth, previews")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--kind", default="street", choices=["street", "road", "courtyard", "walkers"],
                     help="procedural scene kind (default street)")
    src.add_argument("--input", type=Path, help="an AirSim recording folder (airsim_rec.txt + images)")
    p.add_argument("--frames", type=int, default=20, help="frames to render (default 20)")
    p.add_argument("--fps", type=float, default=25.0, help="frame rate, frames per second (default 25)")
    p.add_argument("--snr", type=float, default=1.3, help="mean frame signal-to-background ratio (default 1.3)")
    p.add_argument("--mean-signal", type=float, default=None, help="mean signal photons per LR pixel")
    p.add_argument("--camera", default="static", choices=["static", "moving", "random"])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=run_simulate)


def add_train(subparsers):
    """`jaxsr train`: arguments and runner live with the trainer (`jaxsr.train.add_train_parser`)."""
    from .train import add_train_parser

    add_train_parser(subparsers)


def add_upscale(subparsers):
    """`jaxsr upscale`: see `jaxsr.upscale.add_upscale`."""
    from .upscale import add_upscale as add

    add(subparsers)


def add_info(subparsers):
    """`jaxsr info`: see `jaxsr.upscale.add_info`."""
    from .upscale import add_info as add

    add(subparsers)


COMMANDS = [add_simulate, add_train, add_upscale, add_info]


def build_parser():
    parser = argparse.ArgumentParser(prog="jaxsr", description="Video super-resolution for single-photon lidar.")
    subparsers = parser.add_subparsers(dest="command", required=True)
    for add in COMMANDS:
        add(subparsers)
    return parser


def main(argv=None):
    """Entry point of the `jaxsr` console script.

    Args: argv (list of str, default sys.argv[1:]). Returns the exit status (0 on success, 2 on a user error
    such as a missing file or an existing output, after printing the message to stderr)."""
    args = build_parser().parse_args(argv)
    if argv is None:  # run as a program (not called from Python, where the user owns JAX's devices)
        from .runtime import use_cpu_cores

        use_cpu_cores()
    try:
        return args.func(args)
    except (FileNotFoundError, FileExistsError, ValueError) as e:
        print(f"jaxsr {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
