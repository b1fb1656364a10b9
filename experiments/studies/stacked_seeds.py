"""Stacked seeds against the same runs one after another: training frames/s of `fit(seeds=...)` (`jaxsr train
--seeds`), whose one jitted step is the recipe's vmapped over the seeds, against the single runs' own steps.

    python experiments/studies/stacked_seeds.py [--seeds 3] [--tr 0] [--patch 16 32] [--rounds 6] [--steps 4]
        [--out experiments/results/stacked_seeds.md]

Two measurements in one run, TR0 on the `cpu` preset's 16 x 32 LR crops (batch 4, scenes rendered and photons
simulated inside the step, as `jaxsr train` trains), the devices and mesh `jaxsr train` uses (`use_cpu_cores`,
`choose_mesh("auto")`):

- steps: interleaved rounds, each `--steps` steps of every seed's single run in turn (one after another), then
  `--steps` steps of the stacked run, each step waited for as `fit` waits for its metrics; the step functions
  are the loop's own (`jaxsr.training.epochs._advance`, stacked and not), compiled before the first round. The
  ratio is taken per round (both under the same load) and its median reported, with the fastest round's.
- fit: `fit` itself, `--fit-epochs` epochs of `--fit-steps` steps, the stacked run against the seeds' runs one
  after another, each epoch's training frames/s as `metrics.jsonl` records it (`examples_per_s`: the time of
  the steps, not of validation); the first epoch compiles, so the last is reported.

A window-form example trains one output frame, so frames/s = examples/s. Writes
experiments/results/stacked_seeds.md (the command, the machine and the date in its header; `--out` another file,
e.g. experiments/results/stacked_seeds_gpu.md from a GPU). About 4 minutes on 2 CPU cores.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import tempfile
import time
from pathlib import Path

import jax

from jaxsr.runtime import use_cpu_cores

DEVICES = use_cpu_cores()  # as `jaxsr train` runs: before any JAX operation

import numpy as np  # noqa: E402

from jaxsr.config import PRESETS, ModelConfig, Sensor  # noqa: E402
from jaxsr.training import choose_mesh, fit, recipe, replicate, run_keys  # noqa: E402
from jaxsr.training.epochs import _advance, _stack  # noqa: E402 (the loop's own steps, timed alone)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import header, markdown_table, write_atomic  # noqa: E402



def _timer(advance, train, runs: int):
    """run(step) -> seconds of one step of `advance` for `runs` runs, all active (its metrics fetched, as `fit`
    fetches them), the train state carried from call to call."""
    state, active = [train], np.ones(runs, bool)

    def run(step):
        t0 = time.perf_counter()
        state[0], metrics = advance(state[0], step, active)
        jax.device_get(metrics)
        return time.perf_counter() - t0

    return run


def measure_steps(cfg, train_cfg, seeds, *, rounds: int, steps: int):
    """Per round: (seconds of `steps` steps of each seed's run in turn, seconds of `steps` stacked steps)."""
    how, sensor = recipe(cfg), Sensor()
    mesh = choose_mesh("auto", train_cfg.batch_size)
    make_batch = how.data(cfg, train_cfg, sensor)
    step_fn = how.step(cfg, train_cfg, make_batch, sensor=sensor, mesh=mesh)
    keys = [run_keys(s) for s in seeds]
    trains = [how.init(k_init, cfg, None) for k_init, _, _ in keys]
    singles = [_advance(step_fn, [k_data], stacked=False) for _, k_data, _ in keys]
    stacked = _advance(step_fn, [k_data for _, k_data, _ in keys], stacked=True)
    single_runs = [_timer(a, replicate(t, mesh), 1) for a, t in zip(singles, trains)]
    stacked_run = _timer(stacked, replicate(_stack(trains), mesh), len(seeds))
    times, step = [], 0
    for r in range(rounds + 1):  # round 0 compiles
        one_by_one = sum(run(step + i) for run in single_runs for i in range(steps))
        together = sum(stacked_run(step + i) for i in range(steps))
        step += steps
        if r:
            times.append((one_by_one, together))
            print(f"round {r}: one after another {one_by_one:.2f} s, stacked {together:.2f} s, "
                  f"x{one_by_one / together:.2f}", flush=True)
    return times, mesh


def measure_fit(cfg, train_cfg, seeds, *, epochs: int, steps: int):
    """Training frames/s of the last of `epochs` epochs: (the stacked run's, all seeds together; the runs' one after
    another, their frames over their summed training time)."""
    train_cfg = dataclasses.replace(train_cfg, epochs=epochs, examples_per_epoch=steps * train_cfg.batch_size,
                                    val_frames=2)
    make_batch = recipe(cfg).data(cfg, train_cfg, Sensor())  # one source: the single runs share a compile
    frames = steps * train_cfg.batch_size
    with tempfile.TemporaryDirectory() as tmp:
        together = fit(cfg, train_cfg, out=f"{tmp}/stacked", seeds=list(seeds), make_batch=make_batch,
                       progress=False)
        stacked_s = max(frames / h[-1]["examples_per_s"] for _, h in together.values())  # one shared time
        alone = [fit(cfg, dataclasses.replace(train_cfg, seed=s), out=f"{tmp}/seed{s}", make_batch=make_batch,
                     progress=False)[1] for s in seeds]
        alone_s = sum(frames / h[-1]["examples_per_s"] for h in alone)
    n = len(seeds)
    return n * frames / stacked_s, n * frames / alone_s


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3, help="how many seeds (0, 1, ...)")
    parser.add_argument("--tr", type=int, default=0)
    parser.add_argument("--patch", type=int, nargs=2, default=list(PRESETS["cpu"].patch), help="LR crop rows cols")
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--steps", type=int, default=4, help="steps of each run per round")
    parser.add_argument("--fit-epochs", type=int, default=2)
    parser.add_argument("--fit-steps", type=int, default=16, help="steps per epoch of the fit measurement")
    parser.add_argument("--out", default="experiments/results/stacked_seeds.md", help="the result file")
    args = parser.parse_args()
    started = time.time()
    cfg = ModelConfig(tr=args.tr)
    train_cfg = dataclasses.replace(PRESETS["cpu"], patch=tuple(args.patch))
    seeds = tuple(range(args.seeds))
    times, mesh = measure_steps(cfg, train_cfg, seeds, rounds=args.rounds, steps=args.steps)
    ratios = [a / b for a, b in times]
    frames = args.seeds * args.steps * train_cfg.batch_size
    best_alone, best_stacked = min(a for a, _ in times), min(b for _, b in times)
    fit_stacked, fit_alone = measure_fit(cfg, train_cfg, seeds, epochs=args.fit_epochs, steps=args.fit_steps)
    print(f"fit: stacked {fit_stacked:.1f} frames/s, one after another {fit_alone:.1f} frames/s", flush=True)
    where = (f"{DEVICES} device(s) ({jax.devices()[0].device_kind}), the batch "
             + ("split over them" if mesh is not None else "on one device"))
    rows = [
        ["steps, median round", f"{frames / statistics.median(a for a, _ in times):.1f}",
         f"{frames / statistics.median(b for _, b in times):.1f}", f"x{statistics.median(ratios):.2f}"],
        ["steps, fastest round", f"{frames / best_alone:.1f}", f"{frames / best_stacked:.1f}",
         f"x{best_alone / best_stacked:.2f}"],
        [f"fit, epoch {args.fit_epochs} of {args.fit_steps} steps", f"{fit_alone:.1f}", f"{fit_stacked:.1f}",
         f"x{fit_stacked / fit_alone:.2f}"],
    ]
    text = header(f"{args.seeds} seeds stacked against one after another", started)
    text += (f"Training frames/s (window form: one output frame per example) of {args.seeds} seeds of TR{args.tr}, "
             f"batch {train_cfg.batch_size} of {args.patch[0]} x {args.patch[1]} LR crops, scenes rendered and "
             f"photons simulated inside the step, on {where}: the seeds' runs one after another (each its own "
             f"step) against the stacked run (`fit(seeds=...)`, `jaxsr train --seeds`: one step vmapped over the "
             f"seeds). Steps: {args.rounds} interleaved rounds of {args.steps} steps of each run, the ratio per "
             "round. fit: the whole loop, the last epoch's `examples_per_s` of each run's metrics (the steps' "
             "time, not validation's). Frames/s count every seed's frames.\n\n")
    text += markdown_table(["measured", "one after another (frames/s)", "stacked (frames/s)", "stacked / one after "
                            "another"], rows)
    text += f"\nPer-round ratios: {', '.join(f'{r:.2f}' for r in ratios)}.\n"
    write_atomic(args.out, text)
    print(text)


if __name__ == "__main__":
    main()
