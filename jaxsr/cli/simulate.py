"""`jaxsr simulate`: render a procedural scene (or read an AirSim recording), simulate SPAD photon histograms
and the centre-of-mass depth, and write DIR/histograms.npz (counts, ground-truth depth, config),
DIR/com_depth.npy ((T, h, w) normalised depth), DIR/gt_depth.npy ((T, H, W) radial metres) and PNG previews
of the first frame. Prints a JSON summary with the bicubic baseline's PSNR and SSIM.

Argument parsing and messages only: the work is `jaxsr.app.simulate_recording` (the same options as
keyword arguments), which writes into a hidden temporary folder beside DIR and moves the files into DIR when all
are written, so a failed or stopped run leaves nothing behind.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..app.simulate import simulate_recording
from ..checks import MEMORY_SHARE
from ._args import OldSpelling, add_force, add_output, int_range, memory, positive_float, required_output, seed


def add_parser(subparsers):
    p = subparsers.add_parser("simulate", help="scene or AirSim folder -> histograms, centre-of-mass depth, previews")
    p.add_argument("source", nargs="?", type=Path, default=None, metavar="AIRSIM_DIR",
                   help="an AirSim recording folder (airsim_rec.txt + images) to read instead of a procedural scene")
    p.add_argument("--input", dest="old_input", type=Path, default=None, action=OldSpelling, new="AIRSIM_DIR",
                   help=argparse.SUPPRESS)
    scenes = ["street", "road", "courtyard", "walkers"]
    p.add_argument("--scene", default=None, choices=scenes, help="procedural scene (default street)")
    p.add_argument("--kind", dest="scene", choices=scenes, action=OldSpelling, new="--scene", help=argparse.SUPPRESS)
    p.add_argument("--frames", type=int_range(1), default=20, help="frames to render (default 20)")
    p.add_argument("--fps", type=positive_float, default=25.0, help="frame rate, frames per second (default 25)")
    p.add_argument("--snr", type=positive_float, default=1.3,
                   help="mean frame signal-to-background ratio (default 1.3)")
    p.add_argument("--mean-signal", type=positive_float, default=None, help="mean signal photons per LR pixel")
    p.add_argument("--camera", default="static", choices=["static", "moving", "random"])
    p.add_argument("--seed", type=seed, default=0, help="random seed, 0..2^32-1 (default 0)")
    add_output(p, "output folder")
    add_force(p, "overwrite existing outputs")
    p.add_argument("--max-memory", type=memory, default=None, metavar="SIZE",
                   help=f"the memory the command may take, such as 16GB (default {MEMORY_SHARE * 100:.0f}%% of this "
                   "machine's RAM): the frames' memory is estimated before any work, and refused beyond it")
    p.set_defaults(func=run)


def run(args) -> int:
    out = Path(required_output(args))
    if args.source is not None and args.old_input is not None:
        raise ValueError("two AirSim folders: give AIRSIM_DIR alone")
    source = args.source if args.source is not None else args.old_input
    if source is not None and args.scene is not None:
        raise ValueError("--scene draws a procedural scene; AIRSIM_DIR reads a recorded one: give one")
    result = simulate_recording(out, kind=args.scene or "street", input=source, frames=args.frames, fps=args.fps,
                                snr=args.snr, mean_signal=args.mean_signal, camera=args.camera, seed=args.seed,
                                overwrite=args.force, max_memory=args.max_memory,
                                report=lambda line: print(f"jaxsr simulate: {line}", file=sys.stderr, flush=True))
    print(json.dumps(result.summary()))
    return 0
