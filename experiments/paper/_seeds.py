"""Other training runs of a TR (other seeds) scored beside the studied weights (`--seed-runs`): how far retraining
moves a study's TR differences, next to how far its choice of frames moves them (the frame intervals)."""

from __future__ import annotations

from pathlib import Path

from campaign import tr_differences

import jaxsr

MAIN = "main"  # the run name of the weights a study scores (--weights, default the bundled ones)


def add_seed_run_args(parser) -> None:
    parser.add_argument("--seed-runs", nargs="+", type=Path, default=[], metavar="CHECKPOINT",
                        help="other trained runs (e.g. experiments/paper_weights/s1/tr0/best.npz), each scored beside "
                        "the studied model of its TR, so that every TR difference is also given over every pair of "
                        "runs (what retraining moves)")


def load_seed_runs(paths) -> dict[str, jaxsr.Model]:
    """{name: model} of the checkpoints `paths`, named by their path (a missing file ends the script first)."""
    missing = [str(p) for p in paths if not Path(p).is_file()]
    if missing:
        raise SystemExit(f"--seed-runs: no such checkpoint: {', '.join(missing)}")
    return {str(p): jaxsr.load_model(p) for p in paths}


def seed_summary(runs: dict[str, jaxsr.Model]) -> str:
    """'TR0: 2 more runs (a, b)' for the runs of each TR, for a study's text."""
    by_tr: dict[int, list[str]] = {}
    for name, model in runs.items():
        by_tr.setdefault(model.config.tr, []).append(name)
    return "; ".join(f"TR{tr}: {len(names)} more run{'s' * (len(names) > 1)} ({', '.join(names)})"
                     for tr, names in sorted(by_tr.items()))


def pairs_differences(main: dict, extra: dict, extra_tr: dict) -> dict:
    """Every TR against TR0 over all runs, from per-frame PSNR (frames,) on the same frames: main[tr] of the
    studied weights, extra[name] of the other runs (of TR extra_tr[name]). Returns `campaign.tr_differences`'s
    {tr: {"mean", "runs": (lowest, highest) over pairs, "frames": interval, "beyond"}}."""
    scores = {(MAIN, tr): p[None] for tr, p in main.items()}
    scores.update({(name, extra_tr[name]): p[None] for name, p in extra.items()})
    return tr_differences(scores)


def format_pairs(d: dict) -> str:
    """'+0.13 [+0.05, +0.20]': a difference of the run means and its range over pairs of runs."""
    return f"{d['mean']:+.2f} [{d['runs'][0]:+.2f}, {d['runs'][1]:+.2f}]"
