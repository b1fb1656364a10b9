"""A run's folder: the files `fit` writes there, the seeds' folders of a stacked run, and what a folder must
hold for `fit` to start, resume or overwrite a run in it.

A run folder holds `metrics.jsonl`, `best.npz`, `last.npz` (the train state at an epoch's end) and, inside an
epoch, `resume.npz` (`RUN_FILES`); a stacked run (`fit(seeds=...)`) keeps each seed's run in `out/seed<k>`.
"""

from __future__ import annotations

import dataclasses
import numbers
from pathlib import Path

from ..config import TrainConfig
from ..io.checkpoint import read_metadata

__all__ = ["RESUME_FILE", "RUN_FILES", "resume_config", "seed_folder"]


RESUME_FILE = "resume.npz"  # the train state inside an epoch; last.npz keeps the last epoch's end
RUN_FILES = ("metrics.jsonl", "last.npz", "best.npz", RESUME_FILE)  # what `fit` writes into its folder


def _check_seeds(seeds) -> tuple | None:
    """The seeds of a stacked run (`fit(seeds=...)`) checked: None stays None, else a tuple of at least one
    distinct integer 0..2^32-1 (ValueError naming what is wrong)."""
    if seeds is None:
        return None
    if isinstance(seeds, (str, bytes)) or not hasattr(seeds, "__iter__"):
        raise ValueError(f"fit: seeds must be a list of integers, got {seeds!r}")
    seeds = tuple(seeds)
    bad = [s for s in seeds if isinstance(s, bool) or not isinstance(s, numbers.Integral) or not 0 <= s < 2**32]
    if bad or not seeds:
        raise ValueError(f"fit: seeds must be integers 0..2^32-1, at least one, got {list(seeds)!r}")
    twice = sorted({int(s) for s in seeds if seeds.count(s) > 1})
    if twice:
        raise ValueError(f"fit: seeds must differ, got {', '.join(map(str, twice))} more than once")
    return tuple(int(s) for s in seeds)


def seed_folder(out, seed: int) -> Path:
    """The run folder of seed `seed` of a stacked run in `out`: `out/seed<seed>`."""
    return Path(out) / f"seed{seed}"


def _check_stack_folder(out: Path):
    """A stacked run's folder `out` (its seeds' run folders go inside) is not a file, nor a run folder itself."""
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"{out} is a file; fit's out is a folder")
    held = [name for name in RUN_FILES if (out / name).exists()]
    if held:
        raise FileExistsError(f"{out} holds a training run ({', '.join(held)}); a stacked run trains each seed in "
                              "a folder inside out (seed<k>), not next to a run: choose another out")


def _latest_state(out: Path) -> Path | None:
    """The train state to resume the run in folder `out` from: `resume.npz` (inside an epoch) when it is ahead of
    `last.npz` (an epoch's end; ahead of it when a kill fell between writing it and removing resume.npz), None
    when neither exists."""
    saved = [p for p in (out / "last.npz", out / RESUME_FILE) if p.is_file()]
    return max(saved, key=lambda p: read_metadata(p).get("run", {}).get("step", 0), default=None)


def resume_config(out, train_cfg: TrainConfig) -> TrainConfig:
    """`train_cfg` with the validation sequences of the run saved in folder `out`, so that `fit(resume=True)`
    continues it: runs begun before 2026-11-24 validate on val1_street and val3_courtyard, which the presets
    dropped, and fit refuses to resume under other settings. Every other setting is left for fit to check. A
    folder without a run (no last.npz or resume.npz) gives `train_cfg` unchanged."""
    saved_run = _latest_state(Path(out))
    if saved_run is None:
        return train_cfg
    saved = read_metadata(saved_run).get("train_config", {}).get("val_sequences")
    return train_cfg if saved is None else dataclasses.replace(train_cfg, val_sequences=tuple(saved))


def _first_epoch_kill(out: Path, held: list) -> bool:
    """Whether the run files `held` in `out`, with no train state, are what a kill inside the first epoch's save
    leaves (best.npz of epoch 1 alone: last.npz and metrics.jsonl come after it): a resume starts that run afresh."""
    if held != ["best.npz"]:
        return False
    try:
        return read_metadata(out / "best.npz").get("card", {}).get("epochs") == 1
    except ValueError:
        return False


def _held_run_files(out: Path, *, resume: bool, overwrite: bool) -> list:
    """The run files (`RUN_FILES`) folder `out` holds, checked against what `fit` was asked to do with them:
    FileExistsError for a run neither resumed nor overwritten, or one to resume without its train state."""
    held = [name for name in RUN_FILES if (out / name).exists()]
    if held and not (resume or overwrite):
        raise FileExistsError(f"{out} holds a training run ({', '.join(held)}); pass resume=True (--resume) to "
                              "continue it or overwrite=True (--force) to start a new one in its place")
    if resume and held and _latest_state(out) is None and not _first_epoch_kill(out, held):
        raise FileExistsError(f"{out} holds a run without its train state ({', '.join(held)}; no last.npz or "
                              f"{RESUME_FILE}), so it cannot be resumed; overwrite=True (--force) starts over in "
                              "its place")
    return held
