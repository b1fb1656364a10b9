"""Worker processes of a bounded session on a lent accelerator: stopped at the budget's end as Ctrl-C would, and
their run logs read back. Standard library only, so that a session's supervisor starts at once."""

from __future__ import annotations

import json
import signal
import subprocess
import time
from pathlib import Path

__all__ = ["watch", "stop", "epochs_of"]


def watch(workers: dict, *, until: float, refresh, every_s: float = 30.0, poll_s: float = 1.0) -> None:
    """Wait while any process of `workers` runs and `time.perf_counter()` is before `until`, calling `refresh()`
    every `every_s` seconds: a call killed at its limit still brings back what was reached."""
    last = time.perf_counter()
    while time.perf_counter() < until and any(p.poll() is None for p in workers.values()):
        time.sleep(poll_s)
        if time.perf_counter() - last > every_s:
            refresh()
            last = time.perf_counter()


def stop(workers: dict, *, grace_s: float = 15.0) -> None:
    """Interrupt each running process of `workers` ({name: Popen}) with SIGINT, so that it saves what it reached,
    then wait for each up to `grace_s` seconds and kill what is still running (one compiling ignores SIGINT)."""
    for p in workers.values():
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in workers.values():
        try:
            p.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def epochs_of(run: Path) -> list[dict]:
    """The epoch records of the run in folder `run` (its metrics.jsonl), [] where it has none."""
    log = Path(run) / "metrics.jsonl"
    return [json.loads(s) for s in log.read_text().splitlines() if s.strip()] if log.exists() else []
