"""`jaxsr simulate`: render a procedural scene (or read an AirSim recording), simulate SPAD photon histograms
and the centre-of-mass depth, and write DIR/histograms.npz (counts, ground-truth depth, config),
DIR/com_depth.npy ((T, h, w) normalised depth), DIR/gt_depth.npy ((T, H, W) radial metres) and PNG previews
of the first frame. Prints a JSON summary with the bicubic baseline's PSNR and SSIM. The outputs are written
into a hidden temporary folder beside DIR and moved into DIR when all are written, so a failed or stopped run
leaves nothing behind.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .. import io
from ..io.files import atomic_folder
from ..baselines.interpolation import bicubic
from ..config import DEFAULT_MEAN_SIGNAL, SensorConfig
from ..eval.metrics import psnr, ssim
from ..sensor.peaks import centre_of_mass
from ..io.previews import write_comparison, write_gray_preview, write_preview
from ..scenes import sequence
from ..sensor.forward import normalise_depth, simulate_histograms
from ._args import int_range, positive_float, seed

OUTPUTS = ("histograms.npz", "com_depth.npy", "gt_depth.npy", "preview_gt.png", "preview_com.png",
           "preview_intensity.png", "preview_strip.png")


def add_parser(subparsers):
    p = subparsers.add_parser("simulate", help="scene or AirSim folder -> histograms, centre-of-mass depth, previews")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--kind", default="street", choices=["street", "road", "courtyard", "walkers"],
                     help="procedural scene kind (default street)")
    src.add_argument("--input", type=Path, help="an AirSim recording folder (airsim_rec.txt + images)")
    p.add_argument("--frames", type=int_range(1), default=20, help="frames to render (default 20)")
    p.add_argument("--fps", type=positive_float, default=25.0, help="frame rate, frames per second (default 25)")
    p.add_argument("--snr", type=positive_float, default=1.3,
                   help="mean frame signal-to-background ratio (default 1.3)")
    p.add_argument("--mean-signal", type=positive_float, default=None, help="mean signal photons per LR pixel")
    p.add_argument("--camera", default="static", choices=["static", "moving", "random"])
    p.add_argument("--seed", type=seed, default=0, help="random seed, 0..2^32-1 (default 0)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=run)


def _out_dir(path, force):
    """The output folder, checked (nothing is created yet): refuse (FileExistsError) a file, or a folder that
    already holds any of `OUTPUTS` unless `force`."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"{out} is a file; --out is a folder")
    clash = [n for n in OUTPUTS if (out / n).exists()]
    if clash and not force:
        raise FileExistsError(f"{out} already holds {', '.join(clash)}; pass --force to overwrite")
    return out


def _check_memory(frames):
    """Refuse (ValueError) a --frames that cannot fit this machine's memory: rendering, the photon draw and the
    outputs hold the whole sequence, about 15 MB per frame (measured: 0.8 GB for 10 frames, 1.8 GB for 80)."""
    need = 0.7e9 + 15e6 * frames
    try:
        have = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # not a POSIX system: no check
        return
    if need > have:
        raise ValueError(f"--frames {frames} needs about {need / 1e9:.0f} GB of memory (15 MB per frame), more than "
                         f"this machine's {have / 1e9:.0f} GB; simulate the recording in parts (--seed)")


def _scene(args, sensor):
    """(depth (T, H, W) radial m, intensity (T, H, W), fps, source metadata) from --input or --kind."""
    if args.input:
        rec = io.read_airsim(args.input, sensor=sensor)
        depth, intensity = rec["depth"], rec["intensity"]
        if depth.shape[1:] != sensor.hr_shape:
            raise ValueError(f"{args.input}: frames are {depth.shape[1:]}, the sensor expects {sensor.hr_shape}")
        return depth, intensity, rec["fps"], dict(input=str(args.input))
    depth, intensity = jax.jit(
        lambda k: sequence(k, args.frames, args.fps, kind=args.kind, sensor=sensor, camera=args.camera)
    )(jax.random.key(args.seed))
    return depth, intensity, args.fps, dict(kind=args.kind, seed=args.seed, camera=args.camera)


def run(args) -> int:
    """Render or read depth + intensity, simulate histograms, extract centre-of-mass depth, write outputs."""
    sensor = SensorConfig()
    out = _out_dir(args.out, args.force)
    if not args.input:
        _check_memory(args.frames)
    depth, intensity, fps, source = _scene(args, sensor)
    mean_signal = DEFAULT_MEAN_SIGNAL if args.mean_signal is None else args.mean_signal
    counts = simulate_histograms(jax.random.key(args.seed + 1), jnp.asarray(depth), jnp.asarray(intensity), sensor,
                                 snr=args.snr, mean_signal=mean_signal)
    com = np.asarray(centre_of_mass(counts, sensor))
    meta = dict(source, fps=float(fps), snr=args.snr, mean_signal=mean_signal, frames=int(depth.shape[0]))
    # The baseline a network has to beat: bicubic upsampling of the centre-of-mass depth.
    gt = np.asarray(normalise_depth(jnp.asarray(depth), sensor))
    up = np.asarray(bicubic(com, scale=sensor.scale))
    with atomic_folder(out) as tmp:
        io.write_histograms(tmp / "histograms.npz", np.asarray(counts), depth=np.asarray(depth), sensor=sensor, **meta)
        io.write_sequence(tmp / "com_depth.npy", com)
        io.write_sequence(tmp / "gt_depth.npy", np.asarray(depth))
        write_preview(tmp / "preview_gt.png", np.asarray(depth[0]), d_max=float(sensor.d_max))
        write_preview(tmp / "preview_com.png", com[0], d_max=float(sensor.d_max), normalised=True)
        write_gray_preview(tmp / "preview_intensity.png", np.asarray(intensity[0]))
        write_comparison(tmp / "preview_strip.png", com[0], np.clip(up[0], 0, 1), gt=gt[0],
                         labels=("centre of mass", "bicubic", "ground truth"))
    quality = dict(bicubic_psnr_db=round(float(np.mean(psnr(up, gt))), 2),
                   bicubic_ssim=round(float(np.mean(ssim(up, gt))), 3))
    print(json.dumps(dict(meta, **quality, out=str(out), counts_shape=list(counts.shape))))
    return 0
