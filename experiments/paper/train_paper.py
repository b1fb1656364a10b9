"""The `paper` preset on an accelerator: every TR trained with the paper's schedule (15500 full-frame examples per
epoch, batch 4, the rate x0.1 every 10 epochs, patience 5, validation on 3 x 500 frames), for as many of its 100
epochs as a lease affords.

    python experiments/paper/train_paper.py --probe                      # each TR's train step: compile and step time
    python experiments/paper/train_paper.py --epochs 6 [--tr 0 1 2 3 4] [--seeds 0] [--runs runs/paper]
    python experiments/paper/train_paper.py --keep       # the runs' selected weights and curves into paper_weights/
    python experiments/paper/train_paper.py --report     # experiments/results/paper_runs.md and .png: learning curves
    python experiments/paper/train_paper.py --score      # experiments/results/paper_scores.md: test scenes, 500 frames

Every (seed, TR) trains in its own process, all at once, so that one run's compilation, validation and checkpoint
writing overlap the others' steps on the shared device (each process gets an equal share of its memory). Every
run stops at the same `--epochs` (unless early stopping ends it sooner), so the TRs compare at equal steps; runs
are resumable (the same command, or one with a larger --epochs, continues them, `fit(resume=True)`: from last.npz
at an epoch's end or resume.npz, written every 10 minutes inside an epoch, so a stopped run loses at most that), and
best.npz, rewritten whenever an epoch lowers the validation loss, carries its training card (steps, device, JAX
version). Run folders are not committed: `--keep` copies each run's best.npz (float16) and metrics.jsonl into
experiments/paper_weights/, which `--report` and `--score` read by default, so that the results can be re-made
from a clone. This is for a GPU: on 2 CPU cores (as two devices, as `--probe` and each run use them) TR0's step
took 0.58 s and its epoch 38 minutes on 2026-11-24's EPYC, TR1's step 1.7 s on one device (about 110 minutes an
epoch), TR4's several times that; on one H100, eight runs at once (seeds 1-2 of TR1-TR4) took their 3 epochs in
11-17 minutes each, 18 minutes in all (2026-11-24). CPU sessions train with `campaign.py`, whose report and scoring
these reuse (its runs: seed 0 of every TR, then seeds 1-2 of TR0-TR2). Bundle the result with
`bundle_weights.py --runs runs/paper/s0`.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import jax
from campaign import REPORTED_RUNS, keep, report, score

import jaxsr
from jaxsr.config import PRESETS
from jaxsr.nn import init_model
from jaxsr.training.optim import adam_init
from jaxsr.training import choose_mesh, default_data, fit, make_train_step, replicate, resume_config

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import step_timer  # noqa: E402

PRESET = "paper"
# The runs' selected weights and learning curves, committed (float16), which --score and --report read by default:
# run folders are not committed and are lost with the machine that trained them.
KEPT = Path("experiments/paper_weights")  # from the project's root, as the results files


def probe(trs, steps: int) -> None:
    """Print each TR's train step at the preset, as `fit` runs it (the batch split over the devices when there are
    several that divide it): compilation (with the first step) and the mean of `steps` steps."""
    cfg = PRESETS[PRESET]
    n = jaxsr.runtime.use_cpu_cores()  # as train_one
    mesh = choose_mesh("auto", cfg.batch_size)  # as fit chooses
    print(f"backend {jax.default_backend()}, {n} x {jax.devices()[0].device_kind}, jax {jax.__version__}", flush=True)
    for tr in trs:
        model_cfg = jaxsr.ModelConfig(tr=tr)
        params, state = init_model(jax.random.key(0), model_cfg)
        t0 = time.perf_counter()
        run = step_timer(make_train_step(model_cfg, cfg, default_data(model_cfg, cfg), mesh=mesh),
                         list(replicate((params, state, adam_init(params)), mesh)))
        compile_s = time.perf_counter() - t0
        step_s = sum(run(i) for i in range(1, steps + 1)) / steps
        print(f"TR{tr}: compile + first step {compile_s:.1f} s, step {1e3 * step_s:.1f} ms "
              f"(epoch of {cfg.steps_per_epoch} steps ~{cfg.steps_per_epoch * step_s:.0f} s)", flush=True)


def train_one(root: Path, seed: int, tr: int, epochs: int) -> None:
    run = root / f"s{seed}" / f"tr{tr}"
    # a CPU host's cores as devices, over which fit splits each batch (TR0 at this preset: 0.58 s a step on two
    # cores as two devices, 0.78 s as one, 2026-11-24); on an accelerator this changes nothing
    jaxsr.runtime.use_cpu_cores()
    # resume=True also starts a run afresh: fit resumes only from a saved train state (last.npz or resume.npz; a
    # run killed between its first best.npz and last.npz then starts over instead of being refused)
    fit(jaxsr.ModelConfig(tr=tr), resume_config(run, dataclasses.replace(PRESETS[PRESET], seed=seed, epochs=epochs)),
        out=run, resume=True, progress=False,
        callback=lambda r: print(f"s{seed}/tr{tr} epoch {r['epoch']}: val PSNR {r['val_psnr']:.2f}, "
                                 f"{r['epoch_time_s']:.0f} s", flush=True))


def train_all(root: Path, runs, epochs: int) -> None:
    """One process per (seed, tr) in `runs`, each with an equal share of the device's memory; waits for all (and
    stops them if this process is stopped). This process never touches the device: JAX would take 75 % of its
    memory here before the children start."""
    env = dict(os.environ, XLA_PYTHON_CLIENT_MEM_FRACTION=f"{0.9 / len(runs):.3f}")
    procs = []
    try:
        for s, tr in runs:
            procs.append(subprocess.Popen([sys.executable, __file__, "--one", f"s{s}/tr{tr}", "--epochs", str(epochs),
                                           "--runs", str(root)], env=env))
        failed = [f"s{s}/tr{tr}" for (s, tr), p in zip(runs, procs) if p.wait() != 0]
    finally:
        for p in procs:
            if p.poll() is None:
                p.terminate()
    if failed:
        raise SystemExit(f"runs failed: {', '.join(failed)} (their finished epochs are kept; run again to resume)")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--probe", action="store_true", help="time each TR's train step and exit")
    ap.add_argument("--probe-steps", type=int, default=50)
    ap.add_argument("--epochs", type=int, default=PRESETS[PRESET].epochs,
                    help="train every run to this many epochs (of the preset's 100)")
    ap.add_argument("--tr", type=int, nargs="+", default=list(range(5)), choices=range(5))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--runs", type=Path, default=None,
                    help=f"the runs' folder (default runs/paper; with --score and --report {KEPT.name}/)")
    mode.add_argument("--report", action="store_true", help="write the learning curves, train nothing")
    mode.add_argument("--score", action="store_true", help="score the runs on the test scenes, train nothing")
    mode.add_argument("--keep", action="store_true",
                      help=f"copy the runs' selected weights (float16) and learning curves into {KEPT.name}/")
    ap.add_argument("--force", action="store_true",
                    help="with --keep: replace kept copies even by earlier or the same weights")
    ap.add_argument("--frames", type=int, default=500,
                    help="with --score: frames scored per test scene (spread evenly over its 500)")
    mode.add_argument("--one", help=argparse.SUPPRESS)  # "s<seed>/tr<k>": the child process of one run
    args = ap.parse_args(argv)
    if args.runs is None:
        args.runs = KEPT if args.score or args.report else Path("runs/paper")
    if args.probe:
        probe(args.tr, args.probe_steps)
    elif args.report:
        report(args.runs, "experiments/results/paper_runs.md", preset=PRESET, title="The paper preset",
               how="one process per run (`python experiments/paper/train_paper.py`), on an accelerator shared by the "
                   "runs or on a CPU host (see the last column). Minutes: each run's wall time, beside the others "
                   "where they shared a device, not its cost alone")
    elif args.keep:
        if not keep(args.runs, KEPT, force=args.force):
            print(f"nothing new to keep from {args.runs}")
    elif args.score:
        score(args.runs, args.frames, "experiments/results/paper_scores.md", title="The paper preset")
    elif args.one:
        match = re.fullmatch(r"s(\d+)/tr([0-4])", args.one)
        if match is None:
            ap.error(f"--one: expected s<seed>/tr<0-4>, got {args.one!r}")
        train_one(args.runs, int(match[1]), int(match[2]), args.epochs)
    else:
        runs = [(s, tr) for s in sorted(set(args.seeds)) for tr in sorted(set(args.tr))]
        unknown = [f"s{s}/tr{tr}" for s, tr in runs if (s, tr) not in REPORTED_RUNS]
        if unknown:
            ap.error(f"{', '.join(unknown)}: not among the runs the report and scoring read "
                     f"({', '.join(f's{s}/tr{t}' for s, t in REPORTED_RUNS)})")
        if args.epochs < 1:
            ap.error(f"--epochs must be >= 1, got {args.epochs}")
        train_all(args.runs, runs, args.epochs)


if __name__ == "__main__":
    main()
