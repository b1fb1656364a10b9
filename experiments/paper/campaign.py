"""The long training campaign: every TR trained 8x longer than the bundle, TR0-TR2 with three seeds, one epoch
at a time across sessions; its learning curves and where each run stands.

    python experiments/paper/campaign.py [--hours 2.5] [--runs runs/campaign] [--only s0/tr0 s0/tr4]
    python experiments/paper/campaign.py --report      # experiments/results/campaign.md and campaign.png
    python experiments/paper/campaign.py --score       # test scenes: every TR against TR0, seed spread, frame interval

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
(at least 8 epochs in, so that the quarter is not a single noisy epoch); the report says which are. `--score`
scores each run's selected weights (best.npz) on the test scenes (--frames spread over each, as sweep_tr.py) and
writes experiments/results/campaign_scores.md (per-frame scores in campaign_scores.json, reused for runs whose
weights did not change, `harness.score_cache`):
every TR against TR0 with the spread over every pair of runs (seeds) and the frame interval, and whether the
difference holds beyond both.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import jaxsr
from jaxsr.io.checkpoint import save_model
from jaxsr.config import PRESETS
from jaxsr.training import fit, resume_config

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import BLOCK, SCENE_LABELS, TEST_SCENES, format_interval, interval, scene_scores, test_clips  # noqa: E402
from harness.reports import header, machine, markdown_table, save_figure, write_atomic  # noqa: E402
from harness.score_cache import (  # noqa: E402
    cached_frame_scores,
    code_digest,
    data_digest,
    read_cache,
    weights_digest,
    write_cache,
)
from harness.runs import CAMPAIGN_PRESET, history, run_dir  # noqa: E402

PRESET = CAMPAIGN_PRESET
# The campaign's runs (seed, tr) in priority order: one seed of every TR, then the seed spread where the TR effects
# are smallest (the run with the fewest epochs trains next; the order breaks ties)
RUNS = [(0, tr) for tr in range(5)] + [(s, tr) for s in (1, 2) for tr in range(3)]
# Every run that scoring, the report and `keep` read, in (seed, tr) order: the campaign's and the seed spread of
# TR3-TR4 (trained at the paper preset on a lent GPU, not by the campaign)
REPORTED_RUNS = sorted(RUNS + [(s, tr) for s in (1, 2) for tr in (3, 4)])
CONVERGED_DB = 0.2
# A quarter of fewer epochs is one epoch, and one epoch that loses validation PSNR (it varies by a few tenths of a
# dB from epoch to epoch) would read as converged: the last quarter holds at least two epochs.
MIN_EPOCHS_CONVERGED = 8
# How the campaign's runs were trained, for its report (other drivers, e.g. train_paper.py, say their own)
CAMPAIGN_HOW = ("trained in turns across sessions (`python experiments/paper/campaign.py`; each turn's machine and "
                "commit in turns.jsonl). Minutes: training wall time so far (sessions and machines mixed)")
BEYOND = {True: "yes", False: "no", None: "one run of a side: its retraining not measured"}


def finished(records: list[dict], cfg) -> bool:
    """All epochs done, or stopped early (no lower validation loss in `patience` epochs)."""
    if len(records) >= cfg.epochs:
        return True
    losses = [r["val_loss"] for r in records]
    return bool(losses) and len(losses) - 1 - int(np.argmin(losses)) >= cfg.patience


def gain_last_quarter(records: list[dict]) -> float | None:
    """Validation PSNR gained over the last quarter of the epochs so far (None before `MIN_EPOCHS_CONVERGED`)."""
    if len(records) < MIN_EPOCHS_CONVERGED:
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


def expected_epoch_s(root: Path, seed: int, tr: int) -> float:
    """How long the run's next epoch should take: its own last epoch, else the last epoch of another seed of the
    same TR (the same work), else 0 (nothing known: the epoch starts whatever the deadline)."""
    for s in [seed] + [s for s, t in RUNS if t == tr and s != seed]:
        records = history(run_dir(root, s, tr))
        if records:
            return float(records[-1]["epoch_time_s"])
    return 0.0


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def train(root: Path, hours: float, only) -> None:
    cfg = PRESETS[PRESET]
    deadline = time.time() + 3600 * hours
    jaxsr.runtime.use_cpu_cores()
    commit = _commit()  # the code this process runs, not whatever is checked out when an epoch ends
    stuck = set()  # runs fit found finished by a rule `finished` does not mirror
    while (pick := next_run(root, cfg, only, stuck)) is not None:
        seed, tr = pick
        run = run_dir(root, seed, tr)
        records = history(run)
        expected = expected_epoch_s(root, seed, tr)
        if time.time() + expected > deadline:
            print(f"s{seed}/tr{tr}: the next epoch (~{expected / 60:.0f} min) would end after --hours; stopping")
            return
        t0 = time.time()
        fit(jaxsr.ModelConfig(tr=tr), resume_config(run, dataclasses.replace(cfg, seed=seed, epochs=len(records) + 1)),
            out=run, resume=bool(records), progress=False)
        after = history(run)
        if len(after) == len(records):
            stuck.add(pick)
            continue
        record = after[-1]
        turn = {"run": f"s{seed}/tr{tr}", "epoch": record["epoch"], "val_psnr": record["val_psnr"],
                "seconds": round(time.time() - t0, 1), "machine": machine(), "commit": commit,
                "date": time.strftime("%Y-%m-%d %H:%M")}
        with open(root / "turns.jsonl", "a") as f:
            f.write(json.dumps(turn) + "\n")
        print(json.dumps(turn), flush=True)
    print("every run is finished")


def tr_differences(scores: dict, *, against_previous: bool = False) -> dict:
    """Every TR against TR0 (`against_previous`: against the TR below it, TR k - TR k-1, whether PSNR rises
    step by step) from per-frame PSNR of the runs, scores[(seed, tr)]: (scenes, frames) on the same frames. Returns
    {tr: {"mean": difference of the seed means (dB), "runs": (lowest, highest) difference over every pair of a
    TR-k run and a run of the TR compared with, "frames": the paired block-bootstrap interval
    (`harness.scoring.interval`) of the seed-averaged per-frame scores, "beyond": whether every pair and the frame
    interval lie on the same side of 0, None when either side has a single run (its retraining spread is not
    measured, so no range of pairs can cover it)}} for each TR > 0 that has runs, when the TR it is compared with
    has."""
    by_tr = {}
    for (_, tr), frames in sorted(scores.items()):
        by_tr.setdefault(tr, []).append(np.asarray(frames, np.float64))
    out = {}
    for tr, runs in by_tr.items():
        base = by_tr.get(tr - 1 if against_previous else 0)
        if tr == 0 or base is None:
            continue
        pairs = [float(a.mean(-1).mean() - b.mean(-1).mean()) for a in runs for b in base]
        frames = interval(np.mean(runs, axis=0), np.mean(base, axis=0))
        same_side = (min(pairs) > 0 and float(frames.low) > 0) or (max(pairs) < 0 and float(frames.high) < 0)
        same_side = same_side if len(runs) > 1 and len(base) > 1 else None
        out[tr] = {"mean": float(np.mean(pairs)), "runs": (min(pairs), max(pairs)), "frames": frames,
                   "beyond": same_side}
    return out


# The kept weights of seeds 1 and 2 left the tree (it travels to lent GPUs, which take 64 MiB); git keeps them.
RESTORE_WEIGHTS = "git checkout 949ee82 -- experiments/paper_weights"


def score(root: Path, frames: int, out: str, only=None, *, title: str = "Training campaign") -> None:
    """Score every run's best.npz (those in `only`; None: all) on the test scenes and write the TR differences
    (see `tr_differences`) under `title`. Per-frame scores are kept beside `out` (.json) and reused while a run's
    weights, the test data and the scoring code are unchanged (`harness.score_cache`), so adding a run scores
    that run only."""
    started = time.time()
    clips = test_clips(frames, spread=True)
    shape = (len(clips), frames)
    data, code = data_digest(clips), code_digest()
    cache_path = Path(out).with_suffix(".json")
    cache = read_cache(cache_path)
    scores, rows, trained, earlier = {}, [], set(), []
    for seed, tr in REPORTED_RUNS:
        run = run_dir(root, seed, tr)
        if only is not None and f"s{seed}/tr{tr}" not in only:
            continue
        if not (run / "best.npz").exists():
            if (run / "metrics.jsonl").exists():  # a kept run whose weights are not in the tree
                print(f"s{seed}/tr{tr}: no weights in {run} (seeds 1-2 are kept out of the tree: "
                      f"`{RESTORE_WEIGHTS}` restores them)", flush=True)
            continue
        name, key = f"s{seed}/tr{tr}", {"weights": weights_digest(run / "best.npz"), "data": data, "code": code}
        # (scenes, frames) in TEST_SCENES order
        scores[(seed, tr)], computed = cached_frame_scores(
            cache, name, key, shape, lambda run=run: scene_scores(jaxsr.load_model(run / "best.npz"), clips)[1])
        if computed:
            write_cache(cache_path, cache)  # after each run: an interrupted scoring keeps the others' scores
        records = history(run)
        per_scene = scores[(seed, tr)].mean(-1)
        selected = selected_steps(run)
        # what the TR differences below compare at: each run's training length (without a kept curve, that of its
        # selected weights), whose weights validation may have picked at an earlier epoch
        length = records[-1]["step"] if records else selected
        if length is not None:
            trained.add(length)
        if records and selected is not None and selected < records[-1]["step"]:
            earlier.append(f"{name} ({selected})")
        selected = "?" if selected is None else selected
        rows.append([name, f"{selected} of {records[-1]['step']}" if records else f"{selected}",
                     *(f"{p:.2f}" for p in per_scene), f"{per_scene.mean():.2f}",
                     "now" if computed else cache[name]["date"]])
        print(*rows[-1], flush=True)
    if not scores:
        raise SystemExit(f"{title}: no runs with weights (best.npz) under {root}")
    text = header(f"{title}: the TRs on the test scenes, with seed spread and frame intervals", started)
    text += (f"Each run's selected weights (best.npz: lowest validation loss so far) under {root}, scored on {frames} "
             f"frames spread evenly over each 500-frame test scene (as sweep_tr.py); PSNR (dB), per frame in "
             f"{cache_path.name}. Scored: now, or when the scores reused from there were computed (on the machine "
             "that file names; reused while the run's weights, the test data, the scoring code and the JAX version "
             "are unchanged). Steps: those of the "
             "selected weights, of the run's training so far (not finished while its report says `training`; "
             "a single number: the run's learning curve was not kept)."
             + (" **The runs differ in training length, so the differences below mix training length with TR: "
                "an interim reading, not a result of training to the end.**" if len(trained) > 1 else "")
             + (f" Validation selected an earlier epoch's weights of {', '.join(earlier)}: the runs are compared as "
                "their validation (the paper's early stopping) picks them." if earlier else "") + "\n\n")
    text += markdown_table(["run", "steps", *(SCENE_LABELS[n] for n in TEST_SCENES), "mean", "scored"], rows)
    diffs = tr_differences(scores)
    if diffs:
        text += ("\nEvery TR against TR0, mean over the three scenes (dB): the difference of the seed means; its "
                 "range over every pair of a TR-k run and a TR0 run (what retraining moves); and the 95 % paired "
                 f"bootstrap interval over blocks of {BLOCK} consecutive scored frames of the seed-averaged scores "
                 "(what the choice of frames moves). Beyond both: every pair and the interval on one side of 0.\n\n")
        text += differences_table(diffs)
    rises = {tr: d for tr, d in tr_differences(scores, against_previous=True).items() if tr > 1}  # TR1: above
    if rises:
        text += ("\nEach TR from TR2 against the TR below it (does PSNR rise with every step of TR?): the difference "
                 "of the seed means, its range over every pair of runs of the two TRs, the frame interval of the "
                 "seed-averaged scores and whether all lie on one side of 0.\n\n")
        text += differences_table(rises, against_previous=True)
    write_atomic(out, text)
    print(text)


def differences_table(diffs: dict, *, against_previous: bool = False) -> str:
    """`tr_differences(..., against_previous=against_previous)`'s result as a markdown table."""
    return markdown_table(["TRs", "difference", "over pairs of runs", "frame interval", "beyond both"],
                          [[f"TR{tr} - TR{tr - 1 if against_previous else 0}", f"{d['mean']:+.2f}",
                            f"[{d['runs'][0]:+.2f}, {d['runs'][1]:+.2f}]", format_interval(d["frames"]),
                            BEYOND[d["beyond"]]] for tr, d in diffs.items()])


def plot(path, curves, cfg):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    for (seed, tr), (steps, psnr) in curves.items():  # a colour per TR, a line style per seed
        ax.plot(steps, psnr, ("o-", ".--", "x:")[seed % 3], color=f"C{tr}", ms=3, label=f"s{seed}/tr{tr}")
    ax.set_xlabel(f"training steps (batch {cfg.batch_size})")
    ax.set_ylabel(f"validation PSNR (dB, 3 x {cfg.val_frames} frames)")
    if curves:  # runs kept without their curves have no line
        ax.legend(fontsize=7, ncol=2)
    save_figure(fig, path)


def selected_card(run: Path) -> dict | None:
    """The training card of a run's selected weights (best.npz), None without them."""
    return jaxsr.read_metadata(run / "best.npz").get("card", {}) if (run / "best.npz").exists() else None


def selected_steps(run: Path) -> int | None:
    """The steps of a run's selected weights, None without them."""
    return (selected_card(run) or {}).get("steps")


def keep(root: Path, dest: Path, *, force: bool = False) -> list[str]:
    """Copy each run's selected weights (best.npz, stored as float16 with its card) and learning curve
    (metrics.jsonl) from `root` into `dest`, in the same layout, so that scoring and the report can be re-run from
    a clone of the project (run folders are not committed). A kept copy is replaced only by later weights of the
    run (more steps), or with `force`. Returns the runs copied."""
    copied = []
    for seed, tr in REPORTED_RUNS:
        run, target = run_dir(root, seed, tr), run_dir(dest, seed, tr)
        card, kept_steps = selected_card(run), selected_steps(target)
        steps = (card or {}).get("steps")
        if steps is None:
            continue
        if force or kept_steps is None or steps > kept_steps:
            card = dict(card, storage={**card.get("storage", {}), "dtype": "float16", "kept_from": str(run)})
            save_model(target / "best.npz", jaxsr.load_model(run / "best.npz"), card=card, storage_dtype="float16")
            copied.append(f"s{seed}/tr{tr}")
            print(f"kept s{seed}/tr{tr} ({steps} steps) in {target}", flush=True)
        elif steps < kept_steps:
            print(f"s{seed}/tr{tr}: the kept copy has later weights ({kept_steps} steps, here {steps}); left as it "
                  "is (force to replace it)")
        # the curve goes on past the selected epoch: kept whenever it is longer than the kept one
        curve = history(run)
        if len(curve) > len(history(target)) or (force and curve):
            write_atomic(str(target / "metrics.jsonl"), (run / "metrics.jsonl").read_text())
    return copied


def validated_on(run: Path) -> str:
    """The validation sequences a run selected its weights on, from its best.npz card ("?" without one)."""
    names = (selected_card(run) or {}).get("train_config", {}).get("val_sequences", ["?"])
    return ", ".join(n.split("_")[0] for n in names)


def _row_without_curve(name: str, run: Path) -> list:
    """A report row for a run kept without its learning curve: its selected weights' card."""
    card = selected_card(run)
    val, best = card.get("validation", {}), card.get("best_epoch")
    return [name, f"{card.get('steps', '?')}", "-", "-",
            f"{val['psnr']:.2f} (epoch {best + 1})" if "psnr" in val and best is not None else "-", "-",
            f"{val['bicubic_psnr']:.2f}" if "bicubic_psnr" in val else "-", "weights kept, curve not",
            validated_on(run), trained_on(run)]


def trained_on(run: Path) -> str:
    """The device a run trained on, from its best.npz card ("?" without one)."""
    card = selected_card(run)
    if card is None:
        return "?"
    hardware = card.get("hardware", {})
    return f"{hardware.get('device_kind', '?')}, JAX {hardware.get('jax', '?')}"


def report(root: Path, out: str, *, preset: str = PRESET, title: str = "Training campaign",
           how: str = CAMPAIGN_HOW) -> None:
    """The learning curves of the runs under `root` (trained with `preset`; `how`: how they were trained and
    what the minutes column means): a table of where each stands, the device each trained on (this report's
    header names the machine that wrote it), and a plot."""
    started = time.time()
    cfg = PRESETS[preset]
    rows, curves = [], {}
    for seed, tr in REPORTED_RUNS:
        records, name = history(run_dir(root, seed, tr)), f"s{seed}/tr{tr}"
        if not records:
            if (run_dir(root, seed, tr) / "best.npz").exists():
                rows.append(_row_without_curve(name, run_dir(root, seed, tr)))
            continue
        curves[(seed, tr)] = ([r["step"] for r in records], [r["val_psnr"] for r in records])
        best = max(records, key=lambda r: r["val_psnr"])
        gain = gain_last_quarter(records)
        state = ("finished" if finished(records, cfg) else "training") + (
            "" if gain is None else ", converged" if gain < CONVERGED_DB else ", still gaining")
        rows.append([name, f"{records[-1]['step']}", f"{records[-1]['wall_time_s'] / 60:.0f}",
                     f"{records[-1]['val_psnr']:.2f}", f"{best['val_psnr']:.2f} (epoch {best['epoch']})",
                     "-" if gain is None else f"{gain:+.2f}", f"{records[-1]['val_bicubic_psnr']:.2f}", state,
                     validated_on(run_dir(root, seed, tr)), trained_on(run_dir(root, seed, tr))])
    if not rows:
        names = ", ".join(f"s{s}/tr{t}" for s, t in REPORTED_RUNS)
        raise SystemExit(f"{title}: no runs under {root} (none of {names})")
    text = header(f"{title}: learning curves", started)
    text += (f"Runs of the `{preset}` preset ({cfg.epochs} epochs x {cfg.steps_per_epoch} steps, batch "
             f"{cfg.batch_size}, rate cut after epoch {cfg.decay_epochs}, validation on 3 x {cfg.val_frames} "
             f"frames) under {root}, {how}. Gain: validation PSNR gained over the last quarter of the epochs so "
             "far; under "
             f"{CONVERGED_DB} dB counts as converged (from epoch {MIN_EPOCHS_CONVERGED}). The machine above wrote "
             "this report; each run's validation sequences and training device are in its last columns (from its "
             "card): validation PSNR compares only between runs validated on the same sequences. A run whose "
             "learning curve was not kept shows its selected weights' card.\n\n")
    text += markdown_table(["run", "steps", "minutes", "val PSNR now", "best val PSNR", "gain, last quarter",
                            "bicubic", "state", "validation", "trained on"], rows)
    text += f"\nPlot: `{Path(out).stem}.png`.\n"
    write_atomic(out, text)
    plot(str(Path(out).with_suffix(".png")), curves, cfg)
    print(text)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", default="runs/campaign")
    parser.add_argument("--hours", type=float, default=2.5, help="start no epoch that would end after this")
    parser.add_argument("--only", nargs="+", default=None, help="train (or score) only these runs (e.g. s0/tr0 s0/tr4)")
    parser.add_argument("--report", action="store_true", help="write the results table and plot, train nothing")
    parser.add_argument("--score", action="store_true",
                        help="score the runs on the test scenes (results/campaign_scores.md), train nothing")
    parser.add_argument("--frames", type=int, default=100, help="with --score: frames scored per test scene")
    parser.add_argument("--out", default=None, help="the results file (default experiments/results/campaign.md, "
                        "with --score campaign_scores.md)")
    args = parser.parse_args()
    root = Path(args.runs)
    if args.score:
        score(root, args.frames, args.out or "experiments/results/campaign_scores.md",
              set(args.only) if args.only else None)
    elif args.report:
        report(root, args.out or "experiments/results/campaign.md")
    else:
        root.mkdir(parents=True, exist_ok=True)
        train(root, args.hours, set(args.only) if args.only else None)


if __name__ == "__main__":
    main()
