"""One bounded session on an accelerator: a training-throughput sweep, then photon fine-tunes, within a wall clock.

    python experiments/studies/accelerator_session.py --out OUT --minutes 8 [--runs /tmp/runs] [--sweep-tr]

For a borrowed accelerator with a fixed budget. The sweep (`train_throughput.py --sweep`, run as a command; none with a bare
`--sweep-tr`) runs alone first, so that its times are the device's alone; then the fine-tunes
(`photon_finetune.py`, resumable) train side by side until the budget's end, when they are interrupted and each
run's `best.npz` (the weights it selected, with their card) and `metrics.jsonl` are copied to OUT, flat, with the
sweep's results and the logs: what a budget-limited copy back can carry (no Adam state: a later session continues
from the weights with `--init`). The copies are also refreshed every 30 s, so a call killed at its limit still
brings back what it reached; keep `--minutes` inside the call's limit all the same.

On 2026-11-27's H200 two tr4 fine-tunes side by side took 16.7 s an epoch each against 10-11 s for one alone in the
lease before (1.3x the epochs together), after 281 s of start-up and validation drawing (each SNR of `--val-snrs`
then compiled a simulation of its own; now one compiles for all) and 130 s for their first epoch: 8 epochs each in
9 minutes (experiments/results/edges_lease.md). On 2026-11-26's H200 a first version that ran both at once,
pausing the fine-tunes (SIGSTOP) while the sweep was timed, left them making no progress once continued (cause not
found); and compilation takes a core per process for a minute or more, so the sweep's configurations are few by
default.
"""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # experiments/: the shared harness
from harness.workers import epochs_of, stop, watch  # noqa: E402

# the fine-tunes (photon_finetune.py arguments): each continues a bundled photon model on the wide regime
# the ambient models' common settings: SNR up to 100 (a real recording, tower, reads 45), 500 steps of 16 an epoch
_AMBIENT = ["--photons", "--ambient", "--paper-share", "0.3", "--snr-range", "0.05", "100", "--batch-size", "16",
            "--epochs", "30", "--val-batches", "64"]
_TR4_AMBIENT = ["--tr", "4", *_AMBIENT, "--steps-per-epoch", "500"]
_SNR_GRID = ["--val-snrs", "0.1", "1.3", "5", "45"]  # model selection at fixed SNRs, tower's 45 among them
_EDGES = ["--no-return-prob", "0.9"]  # no-return regions on 90 % of the clips (their default share is 50 %)
# tr4-ambient-edges continued from what its first lease kept (experiments/photon_weights), the rate cut at epoch 12
_EDGES_MORE = [*_TR4_AMBIENT, *_SNR_GRID, *_EDGES, "--init",
               str(HERE.parent / "photon_weights" / "tr4-ambient-edges.npz"), "--decay-epochs", "12", "--lr", "1e-4"]
FINETUNES = {
    "tr4-photons": ["--tr", "4", "--photons", "--paper-share", "0.3", "--init", "tr4-photons", "--batch-size", "16",
                    "--epochs", "14", "--steps-per-epoch", "1000", "--decay-epochs", "6", "--lr", "1e-4"],
    "tr0-photons": ["--tr", "0", "--photons", "--paper-share", "0.3", "--init", "tr0-photons", "--batch-size", "16",
                    "--epochs", "14", "--steps-per-epoch", "2000", "--decay-epochs", "6", "--lr", "1e-4"],
    # the photon models widened to the ambient channel
    "tr4-ambient": [*_TR4_AMBIENT, "--decay-epochs", "8", "--lr", "1e-4"],
    "tr0-ambient": ["--tr", "0", *_AMBIENT, "--steps-per-epoch", "1500", "--decay-epochs", "8", "--lr", "1e-4"],
    # the bundled tr4-ambient continued at 1e-4 for longer (its first run's validation still rose when the rate
    # was cut at epoch 8); the cut at epoch 20 falls inside one 10-minute call on an H100/H200 (about 14 s an epoch
    # after a 2-minute compile)
    "tr4-ambient-more": [*_TR4_AMBIENT, *_SNR_GRID, "--init", "tr4-ambient", "--epochs", "40", "--decay-epochs", "20",
                         "--lr", "1e-4"],
    # the bundled tr4-ambient (tr4-ambient-more's epoch 13) at the rates that run never reached: 1e-5, then 1e-6
    "tr4-ambient-cut": [*_TR4_AMBIENT, *_SNR_GRID, "--init", "tr4-ambient", "--decay-epochs", "15", "--lr", "1e-5"],
    # the whole network at the regions' edges: refitting the no-return branch alone on fixed features, with the
    # same loss, moved the edges little (experiments/results/no_return_head.md), so the trunk trains too, with
    # more clips with regions, at 1e-4 (tr4-ambient-more's rate) cut at epoch 15; the epoch kept is still chosen
    # by validation loss on the default regime, so score the edges (no_return_head.py --model on it,
    # photon_regimes.py) before replacing the bundled model
    "tr4-ambient-edges": [*_TR4_AMBIENT, *_SNR_GRID, *_EDGES, "--init", "tr4-ambient", "--decay-epochs", "15",
                          "--lr", "1e-4"],
    # the same with the head's cross-entropy weighed 5x (0.05): whether the trunk's features follow the loss (run
    # beside tr4-ambient-edges on 2026-11-27, experiments/results/edges_lease.md; its weights were not kept)
    "tr4-ambient-edges-ce": [*_TR4_AMBIENT, *_SNR_GRID, *_EDGES, "--init", "tr4-ambient", "--decay-epochs", "15",
                             "--lr", "1e-4", "--no-return-weight", "0.05"],
    # tr4-ambient-edges continued from what its first lease kept (epoch 5 of 8, experiments/photon_weights), alone
    # (two side by side train 1.3x the epochs of one, each at 0.65x), the rate cut at epoch 12
    "tr4-ambient-edges-more": _EDGES_MORE,
    # the same with 30 % static clips: every training clip moved, and on static scenes (the real recordings'
    # photon videos) tr4-ambient's head drops 2-3x the returns inside surfaces (results/photon_regimes_static.md);
    # its validation draws static clips as often, so its losses are not comparable with the runs above
    "tr4-ambient-edges-static": [*_EDGES_MORE, "--static-prob", "0.3"],
}


def collect(run: Path, out: Path, name: str) -> None:
    """Copy a run's best.npz and metrics.jsonl to out as <name>-<file>, each whole or not at all, when changed."""
    for f in ("best.npz", "metrics.jsonl"):
        src, dest = run / f, out / f"{name}-{f}"
        # copy2 keeps the time stamp: a file the run has not rewritten since is not copied again
        if src.exists() and not (dest.exists() and dest.stat().st_mtime_ns == src.stat().st_mtime_ns):
            tmp = out / f"{name}-{f}.part"
            shutil.copy2(src, tmp)
            os.replace(tmp, dest)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="where results, weights and logs go (flat)")
    ap.add_argument("--runs", type=Path, default=Path("runs/accelerator"), help="the fine-tunes' run folders")
    ap.add_argument("--minutes", type=float, default=8.0, help="wall-clock budget of the whole session")
    ap.add_argument("--sweep-tr", type=int, nargs="*", default=[0, 4])
    ap.add_argument("--sweep-batch", type=int, nargs="+", default=[16, 64])
    ap.add_argument("--sweep-precision", nargs="+", default=["default", "bfloat16"])
    ap.add_argument("--finetunes", nargs="*", default=["tr4-ambient-edges-static"], choices=list(FINETUNES),
                    help="which to train side by side (default: the next planned, tr4-ambient-edges-static)")
    ap.add_argument("--extra", nargs="*", default=[],
                    help="arguments added to every fine-tune, as one string (e.g. for a test)")
    args = ap.parse_args(argv)
    t_end = time.perf_counter() + 60 * args.minutes
    args.out.mkdir(parents=True, exist_ok=True)
    log = open(args.out / "workers.log", "ab")

    def say(msg: str) -> None:
        print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)

    if args.sweep_tr:
        n = len(args.sweep_tr) * len(args.sweep_batch) * len(args.sweep_precision)
        say(f"sweep: {n} configurations compiling")
        # the sweep may take at most half the budget; what is not compiled by then is recorded as such
        timeout = max(10.0, (t_end - time.perf_counter()) / 2 - 60)
        throughput = [sys.executable, str(HERE / "train_throughput.py")]
        subprocess.run([*throughput, "--sweep", str(args.out), "--tr", *map(str, args.sweep_tr),
                        "--batch", *map(str, args.sweep_batch), "--precision", *args.sweep_precision,
                        "--compile-timeout", str(timeout)], stdout=log, stderr=subprocess.STDOUT)
        say("sweep timed")
        subprocess.run([*throughput, "--report", str(args.out / "throughput.jsonl")])
    env = dict(os.environ, XLA_PYTHON_CLIENT_PREALLOCATE="false", PYTHONUNBUFFERED="1")
    trainers = {name: subprocess.Popen(
        [sys.executable, str(HERE / "photon_finetune.py"), *FINETUNES[name], "--out", str(args.runs / name),
         "--no-progress", "--checkpoint-minutes", "2", *(a for e in args.extra for a in shlex.split(e))],
        env=env, stdout=log, stderr=subprocess.STDOUT) for name in args.finetunes}
    say(f"fine-tunes started: {', '.join(trainers)}")
    def refresh():
        for name in trainers:
            try:
                collect(args.runs / name, args.out, name)
            except OSError as e:  # a failed copy must not stop the budget's watch; the last copy retries
                say(f"{name}: copy failed ({e})")

    watch(trainers, until=t_end - 20, refresh=refresh, poll_s=2.0)
    stop(trainers)
    for name, p in trainers.items():
        collect(args.runs / name, args.out, name)
        epochs = epochs_of(args.runs / name)
        say(f"{name}: exit {p.returncode}, {len(epochs)} epochs" +
            (f", last val PSNR {epochs[-1]['val_psnr']:.2f} dB" if epochs else ""))
    shutil.rmtree(args.out / "sync", ignore_errors=True)


if __name__ == "__main__":
    main()
