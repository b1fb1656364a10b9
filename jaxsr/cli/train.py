"""`jaxsr train`: parse the options of `jaxsr.training.train` (a preset, on rendered scenes or on HR sequences
from an .npz), call it and say where the best epoch went. It writes OUT/metrics.jsonl, OUT/best.npz and
OUT/last.npz; a folder that already holds a run is refused unless --resume (continue it) or --force (start over).
--seeds 0,1,2 trains those seeds at once, stacked in one vmapped step, each into its own run folder OUT/seed<k>.
Across processes (--coordinator, --num-processes, --process-id, or $JAXSR_COORDINATOR, $JAXSR_NUM_PROCESSES,
$JAXSR_PROCESS_ID, or `srun`'s Slurm variables) every process runs this command and process 0 writes OUT."""

from __future__ import annotations

import sys
from pathlib import Path

import jax

from ..config import PRESETS, TEMPORAL_FORMS
from ..runtime import JOIN_TIMEOUT_S, init_distributed
from ..nn.model import architectures
from ..training.presets import MAX_TR, train
from ..training.folders import seed_folder
from ._args import add_force, add_output, add_quiet, int_range, positive_float, required_output, seed, seed_list


def add_parser(subparsers):
    p = subparsers.add_parser("train", help="train a super-resolution network (3 + TR blocks, or a learned baseline)")
    p.add_argument("--arch", choices=architectures(), default="duf",
                   help="the network: duf (the paper's, 3 + TR blocks) or a learned baseline at its published size")
    p.add_argument("--tr", type=int_range(0, MAX_TR, "memory and compute grow with the window of 2TR+1 frames"),
                   default=4, help=f"temporal radius TR (window of 2TR+1 frames), 0..{MAX_TR}")
    p.add_argument("--scale", type=int_range(1), default=4, help="upsampling factor (4, or 8)")
    p.add_argument("--preset", choices=sorted(PRESETS), default="cpu",
                   help="training preset (see jaxsr.config.PRESETS)")
    add_output(p, "output folder OUT (metrics.jsonl, best.npz, last.npz)")
    again = p.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true", help="continue the run in OUT (from last.npz or resume.npz)")
    add_force(p, "start a new run in OUT, replacing the run it holds", again)
    seeding = p.add_mutually_exclusive_group()
    seeding.add_argument("--seed", type=seed, default=None, help="override the preset's seed (0..2^32-1)")
    seeding.add_argument("--seeds", type=seed_list, default=None, metavar="K,K,...",
                         help="train several seeds at once (e.g. 0,1,2), each as --seed K alone would, stacked in one "
                         "vmapped step, each in its own run folder OUT/seedK with its own files, resume and early "
                         "stopping; meant for a GPU that one small run leaves idle: on CPU it is slower than the runs "
                         "one after another (docs/training.md, stacked seeds)")
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
    add_quiet(p)
    across = p.add_argument_group(
        "across processes", "one run over several processes or hosts (JAX's multi-controller runtime): every process "
        "runs this same command with its own --process-id; the preset's batch is the global one, split over all "
        "their devices; process 0 writes OUT. Each option defaults to its environment variable; under srun (Slurm) "
        "none is needed")
    across.add_argument("--coordinator", metavar="HOST:PORT", default=None,
                        help="process 0's host and a free port on it (default $JAXSR_COORDINATOR)")
    across.add_argument("--num-processes", metavar="N", type=int_range(1), default=None,
                        help="how many processes take part (default $JAXSR_NUM_PROCESSES, else 1 or Slurm's tasks)")
    across.add_argument("--process-id", metavar="I", type=int_range(0), default=None,
                        help="this process's id, 0..N-1; 0 writes OUT (default $JAXSR_PROCESS_ID)")
    across.add_argument("--join-timeout", metavar="SECONDS", type=positive_float, default=JOIN_TIMEOUT_S,
                        help=f"how long each process waits for the others to join before it gives up with an error "
                        f"(default {JOIN_TIMEOUT_S:g}; Ctrl-C ends the wait)")
    p.set_defaults(func=run, before_jax=join_processes)


def join_processes(args) -> None:
    """Before any JAX work: join the run across processes the options or the environment describe (nothing for one
    process), saying on stderr what it waits for; ValueError for a malformed or partial description, JoinError for
    processes that did not meet (a missing one at --join-timeout, the port in use)."""
    init_distributed(args.coordinator, args.num_processes, args.process_id, timeout=args.join_timeout,
                     say=lambda line: print(f"jaxsr train: {line}", file=sys.stderr, flush=True))


def run(args) -> int:
    """Train as the arguments say; prints the best epoch. Configs and data are built (and checked) before any work.
    A warning (e.g. a resumed run with nothing to train) is one line on stderr, as `jaxsr.cli.main` prints it."""
    out = required_output(args)
    result = train(out, arch=args.arch, tr=args.tr, scale=args.scale, temporal=args.temporal,
                   preset=args.preset, seed=args.seed, seeds=args.seeds, epochs=args.epochs,
                   clip_frames=args.clip_frames, data=args.data, init=args.init, resume=args.resume,
                   overwrite=args.force, checkpoint_minutes=args.checkpoint_minutes, progress=not args.no_progress)
    runs = {None: result} if args.seeds is None else result
    for k, (_, history) in runs.items():
        best = min(history, key=lambda r: r["val_loss"]) if history else None
        if best and jax.process_index() == 0:  # across processes: the one that wrote OUT
            folder = Path(out) if k is None else seed_folder(out, k)
            print(("" if k is None else f"seed {k}: ") + f"best epoch {best['epoch']}: val loss "
                  f"{best['val_loss']:.3e}, val PSNR {best['val_psnr']:.2f} dB -> {folder / 'best.npz'}")
    return 0
