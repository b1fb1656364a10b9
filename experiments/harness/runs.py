"""Training runs on disk, as the experiments' training campaign lays them out (experiments/paper/campaign.py): one
folder per (seed, TR) under a root, each written by `jaxsr.training.fit` (metrics.jsonl, best.npz, last.npz)."""

from __future__ import annotations

import json
from pathlib import Path

# The training preset of the campaign's runs (`jaxsr.config.PRESETS`)
CAMPAIGN_PRESET = "long"


def run_dir(root: Path, seed: int, tr: int) -> Path:
    """The folder of the campaign's run of TR`tr` with seed `seed` under `root`: root/s<seed>/tr<tr>."""
    return Path(root) / f"s{seed}" / f"tr{tr}"


def history(run: Path) -> list[dict]:
    """The run's per-epoch records (metrics.jsonl), [] before its first epoch."""
    path = Path(run) / "metrics.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.exists() else []
