"""`jaxsr train`: train a super-resolution network with `jaxsr.fit` on a preset, on rendered scenes (the
default) or on HR sequences from an .npz (--data); writes OUT/metrics.jsonl, OUT/best.npz and OUT/last.npz.
A folder that already holds a run is refused unless --resume (continue it) or --force (start over)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from .. import io
from ..io.files import removing_new_folder
from ..config import PRESETS, TEMPORAL_FORMS, ModelConfig, SensorConfig
from ..training.data import sequence_batches, sequence_clips
from ..training.loop import fit, resume_config
from ._args import int_range, seed

# The network has 3 + TR blocks over windows of 2TR+1 frames, so memory and compute grow with TR; the paper
# uses TR 0-4, and a TR beyond this does not fit a training batch in the memory of a usual machine.
MAX_TR = 8


def add_parser(subparsers):
    p = subparsers.add_parser("train", help="train a super-resolution network (3 + TR blocks)")
    p.add_argument("--tr", type=int_range(0, MAX_TR, "memory and compute grow with the window of 2TR+1 frames"),
                   default=4, help=f"temporal radius TR (window of 2TR+1 frames), 0..{MAX_TR}")
    p.add_argument("--scale", type=int_range(1), default=4, help="upsampling factor (4, or 8)")
    p.add_argument("--preset", choices=sorted(PRESETS), default="cpu", help="training preset (see jaxsr.config.PRESETS)")
    p.add_argument("--out", required=True, help="output folder (metrics.jsonl, best.npz, last.npz)")
    again = p.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true", help="continue the run in OUT (from last.npz or resume.npz)")
    again.add_argument("--force", action="store_true", help="start a new run in OUT, replacing the run it holds")
    p.add_argument("--seed", type=seed, default=None, help="override the preset's seed (0..2^32-1)")
    p.add_argument("--epochs", type=int_range(1), default=None, help="override the preset's number of epochs")
    p.add_argument("--data", default=None,
                   help="train on HR sequences from an .npz with arrays depth (radial m) and intensity, (N, T, H, W)")
    p.add_argument("--temporal", choices=TEMPORAL_FORMS, default="window",
                   help="the network's form: window (the paper: one window of 2TR+1 frames per output) or sequence "
                   "(all 3+TR blocks temporally valid, run over whole sequences and streams; trains on clips)")
    p.add_argument("--clip-frames", type=int, default=None,
                   help="with --temporal sequence: LR frames per training clip, at least 2(3+TR)+1 "
                   "(default: 2(3+TR) + jaxsr.config.DEFAULT_CLIP_OUTPUTS)")
    p.add_argument("--init", default=None,
                   help="start from these weights (tr0..tr4 or a checkpoint of the same architecture but for its "
                   "TR, in either form): the same TR, e.g. to fine-tune a windowed model into the sequence form, or a "
                   "smaller one, grown to --tr (jaxsr.nn.grow_tr: a warm start from its function)")
    p.add_argument("--checkpoint-minutes", type=float, default=10.0,
                   help="save the train state inside an epoch (OUT/resume.npz) every this many minutes of training, so "
                   "that a stopped run resumes (--resume) with at most that much lost (default 10; 0: every step; "
                   "inf: never)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _sequence_data(path, tr, cfg, sensor, clip=None):
    """The data source for --data: HR sequences from an .npz, read and checked now; windows for the window form,
    clips of `clip` frames for the sequence form."""
    if Path(path).suffix.lower() != ".npz":
        raise ValueError(f"--data {path}: expected an .npz file with arrays depth (radial m) and intensity, "
                         "(N, T, H, W)")
    d = io.read_npz_arrays(path, ["depth", "intensity"])
    for name in ("depth", "intensity"):
        if d[name].dtype.kind not in "iuf":
            raise ValueError(f"--data {path}: {name} holds {d[name].dtype} values; expected real numbers")
    if clip is None:
        make_batch = sequence_batches(d["depth"], d["intensity"], tr, cfg, sensor=sensor)
    else:
        make_batch = sequence_clips(d["depth"], d["intensity"], clip, cfg, sensor=sensor)
    make_batch.description = f"{path}: " + make_batch.description
    return make_batch


def run(args) -> int:
    """Train as the arguments say; prints the best epoch. Configs and data are built (and checked) before any work."""
    changes = {k: v for k, v in (("seed", args.seed), ("epochs", args.epochs), ("clip_frames", args.clip_frames))
               if v is not None}
    cfg = dataclasses.replace(PRESETS[args.preset], **changes)
    sensor = SensorConfig() if args.scale == 4 else SensorConfig(scale=args.scale)
    model_cfg = ModelConfig(tr=args.tr, scale=args.scale, temporal=args.temporal)
    clip = cfg.clip_length(model_cfg) if args.temporal == "sequence" else None  # checked before any work
    if not args.checkpoint_minutes >= 0:  # also refuses NaN
        raise ValueError(f"--checkpoint-minutes {args.checkpoint_minutes}: expected a number of minutes >= 0")
    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise FileExistsError(f"{args.out} is a file; --out is a folder")
    make_batch = _sequence_data(args.data, args.tr, cfg, sensor, clip) if args.data else None
    with removing_new_folder(args.out):  # a run that fails or stops before its first save leaves no folder
        cfg = resume_config(args.out, cfg) if args.resume else cfg  # a run keeps the validation it began with
        _, history = fit(model_cfg, cfg, out=args.out, make_batch=make_batch, sensor=sensor, resume=args.resume,
                         overwrite=args.force, progress=not args.no_progress, init=args.init,
                         checkpoint_every_s=60 * args.checkpoint_minutes)
    best = min(history, key=lambda r: r["val_loss"]) if history else None
    if best:
        print(f"best epoch {best['epoch']}: val loss {best['val_loss']:.3e}, val PSNR {best['val_psnr']:.2f} dB "
              f"-> {Path(args.out) / 'best.npz'}")
    return 0
