"""The long training campaign: every TR trained 8x longer than the bundle, TR0-TR2 with three seeds, one epoch
at a time across sessions; its learning curves and where each run stands.

    python experiments/campaign.py [--hours 2.5] [--runs runs/campaign] [--only s0/tr0 s0/tr4]
    python experiments/campaign.py --report      # experiments/results/campaign.md and campaign.png

Each run trains with the `long` preset (20 epochs x 512 steps of batch 4 = 10240 steps, 16 x 32 LR crops, the
rate cut from 1e-3 to 1e-4 after epoch 10, early stopping after 6 epochs without a lower validation loss,
validation on 3 x 64 frames) from random weights, into runs/campaign/s<seed>/tr<N> (the layout
`bundle_weights.py --runs runs/campaign/s0` reads). No CPU session holds a whole campaign (about 20 hours on 2
cores), so the script works in turns: it always extends the run with the fewest finished epochs (seed 0 of every
TR first, then the extra seeds of TR0-TR2) by one epoch, as a resume of that run, and stops starting epochs
once the next one would not end within `--hours`. An interrupted epoch is lost, nothing else: run the same
command again, here or on another machine after copying runs/campaign. Each finished epoch appends a line to
runs/campaign/turns.jsonl (run, epoch, wall time, machine, the code's git commit), since the code may change
between sessions.

A run counts as converged when its validation PSNR gained under 0.2 dB over the last quarter of its epochs
(at least 4 epochs in); the report says which are.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import time
from pathlib import Path

import numpy as np

import jaxsr
from jaxsr.config import PRESETS
from jaxsr.train import fit

from _report import header, machine, markdown_table, save_figure, write_atomic

PRESET = "long"
# (seed, tr) in priority order: one seed of every TR, then the seed spread where the TR effects are smallest
RUNS = [(0, tr) for tr in range(5)] + [(s, tr) for s in (1, 2) for tr in range(3)]
CONVERGED_DB = 0.2


def run_dir(root: Path, seed: int, tr: int) -> Path:
    return root / f"s{seed}" / f"tr{tr}"


def history(run: Path) -> list[dict]:
    """The run's per-epoch records (metrics.jsonl), [] before its first epoch."""
    path = run / "metrics.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.exists() else []


def finished(records: list[dict], cfg) -> bool:
    """All epochs done, or stopped early (no lower validation loss in `patience` epochs)."""
    if len(records) >= cfg.epochs:
        return True
    losses = [r["val_loss"] for r in records]
    return bool(losses) and len(losses) - 1 - int(np.argmin(losses)) >= cfg.patience


def gain_last_quarter(records: list[dict]) -> float | None:
    """Validation PSNR gained over the last quarter of the epochs so far (None before 4 epochs)."""
    if len(records) < 4:
        return None
    psnr = [r["val_psnr"] for r in records]
    start = len(psnr) - max(1, len(psnr) // 4) - 1
    return max(psnr[start + 1:]) - max(psnr[:start + 1])


def next_run(root: Path, cfg, only, skip=frozenset()) -> tuple[int, int] | None:
    """The unfinished run with the fewest epochs (ties: priority order), among those in `only` (None: all) and
    not in `skip`, or None when none is left."""
    candidates = []
    for i, (s, tr) in enumerate(RUNS):
        if (only is not None and f"s{s}/tr{tr}" not in only) or (s, tr) in skip:
            continue
        records = history(run_dir(root, s, tr))
        if not finished(records, cfg):
            candidates.append((len(records), i, (s, tr)))
    return min(candidates)[2] if candidates else None


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def train(root: Path, hours: float, only) -> None:
    cfg = PRESETS[PRESET]
    deadline = time.time() + 3600 * hours
    jaxsr.use_cpu_cores()
    stuck = set()  # runs fit found finished by a rule `finished` does not mirror
    while (pick := next_run(root, cfg, only, stuck)) is not None:
        seed, tr = pick
        run = run_dir(root, seed, tr)
        records = history(run)
        expected = records[-1]["epoch_time_s"] if records else 0.0  # its last epoch predicts the next
        if time.time() + expected > deadline:
            print(f"s{seed}/tr{tr}: the next epoch (~{expected / 60:.0f} min) would end after --hours; stopping")
            return
        t0 = time.time()
        fit(jaxsr.ModelConfig(tr=tr), dataclasses.replace(cfg, seed=seed, epochs=len(records) + 1), out=run,
            resume=bool(records), progress=False)
        after = history(run)
        if len(after) == len(records):
            stuck.add(pick)
            continue
        record = after[-1]
        turn = {"run": f"s{seed}/tr{tr}", "epoch": record["epoch"], "val_psnr": record["val_psnr"],
                "seconds": round(time.time() - t0, 1), "machine": machine(), "commit": _commit(),
                "date": time.strftime("%Y-%m-%d %H:%M")}
        with open(root / "turns.jsonl", "a") as f:
            f.write(json.dumps(turn) + "\n")
        print(json.dumps(turn), flush=True)
    print("every run is finished")


def plot(path, curves):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    for name, (steps, psnr) in curves.items():
        ax.plot(steps, psnr, "o-" if name.startswith("s0/") else ".--", ms=3, label=name)
    ax.set_xlabel("training steps (batch 4)")
    ax.set_ylabel("validation PSNR (dB, 3 x 64 frames)")
    ax.legend(fontsize=7, ncol=2)
    save_figure(fig, path)


def report(root: Path, out: str) -> None:
    started = time.time()
    cfg = PRESETS[PRESET]
    rows, curves = [], {}
    for seed, tr in RUNS:
        records = history(run_dir(root, seed, tr))
        if not records:
            continue
        name = f"s{seed}/tr{tr}"
        curves[name] = ([r["step"] for r in records], [r["val_psnr"] for r in records])
        best = max(records, key=lambda r: r["val_psnr"])
        gain = gain_last_quarter(records)
        state = ("finished" if finished(records, cfg) else "training") + (
            "" if gain is None else ", converged" if gain < CONVERGED_DB else ", still gaining")
        rows.append([name, f"{records[-1]['step']}", f"{records[-1]['wall_time_s'] / 60:.0f}",
                     f"{records[-1]['val_psnr']:.2f}", f"{best['val_psnr']:.2f} (epoch {best['epoch']})",
                     "-" if gain is None else f"{gain:+.2f}", f"{records[-1]['val_bicubic_psnr']:.2f}", state])
    if not rows:
        raise SystemExit(f"no campaign runs under {root}: start them with `python experiments/campaign.py`")
    text = header("Training campaign: learning curves of the long runs", started)
    text += (f"Runs of the `{PRESET}` preset ({cfg.epochs} epochs x {cfg.steps_per_epoch} steps, batch "
             f"{cfg.batch_size}, rate cut after epoch {cfg.decay_epochs}, validation on 3 x {cfg.val_frames} "
             f"frames) under {root}, trained in turns across sessions (`python experiments/campaign.py`; each "
             "turn's machine and commit in turns.jsonl). Minutes: training wall time so far (sessions and "
             f"machines mixed). Gain: validation PSNR gained over the last quarter of the epochs so far; under "
             f"{CONVERGED_DB} dB counts as converged.\n\n")
    text += markdown_table(["run", "steps", "minutes", "val PSNR now", "best val PSNR", "gain, last quarter",
                            "bicubic", "state"], rows)
    text += f"\nPlot: `{Path(out).stem}.png`.\n"
    write_atomic(out, text)
    plot(str(Path(out).with_suffix(".png")), curves)
    print(text)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", default="runs/campaign")
    parser.add_argument("--hours", type=float, default=2.5, help="start no epoch that would end after this")
    parser.add_argument("--only", nargs="+", default=None, help="train only these runs (e.g. s0/tr0 s0/tr4)")
    parser.add_argument("--report", action="store_true", help="write the results table and plot, train nothing")
    parser.add_argument("--out", default="experiments/results/campaign.md")
    args = parser.parse_args()
    root = Path(args.runs)
    if args.report:
        report(root, args.out)
    else:
        root.mkdir(parents=True, exist_ok=True)
        train(root, args.hours, set(args.only) if args.only else None)


if __name__ == "__main__":
    main()
