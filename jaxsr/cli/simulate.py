"""`jaxsr simulate`: render a procedural scene (or read an AirSim recording), simulate SPAD photon histograms
and the centre-of-mass depth, and write DIR/histograms.npz (counts, ground-truth depth, config),
DIR/com_depth.npy ((T, h, w) normalised depth), DIR/gt_depth.npy ((T, H, W) radial metres) and PNG previews
of the first frame. Prints a JSON summary with the bicubic baseline's PSNR and SSIM.
"""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .. import io
from ..baselines import bicubic
from ..config import DEFAULT_MEAN_SIGNAL, SensorConfig
from ..metrics import psnr, ssim
from ..peaks import centre_of_mass
from ..previews import write_comparison, write_gray_preview, write_preview
from ..scenes import sequence
from ..sensor import normalise_depth, simulate_histograms

OUTPUTS = ("histograms.npz", "com_depth.npy", "gt_depth.npy", "preview_gt.png", "preview_com.png",
           "preview_intensity.png", "preview_strip.png")


def add_parser(subparsers):
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
    p.set_defaults(func=run)


def _out_dir(path, force):
    """Create the output folder; refuse (FileExistsError) if it already holds any of `OUTPUTS`, unless `force`."""
    out = Path(path)
    out.mkdir(parents=True, exist_ok=True)
    clash = [n for n in OUTPUTS if (out / n).exists()]
    if clash and not force:
        raise FileExistsError(f"{out} already holds {', '.join(clash)}; pass --force to overwrite")
    return out


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
    depth, intensity, fps, source = _scene(args, sensor)
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
