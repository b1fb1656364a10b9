"""Shared header and writing helpers for the experiment scripts' result files."""

from __future__ import annotations

import datetime
import os
import platform
import sys
import time

import jax

from jaxsr._files import write_text_atomic


def machine() -> str:
    """A one-line description of where the experiment ran."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{cpu}, {os.cpu_count()} cores, JAX {jax.__version__} on {jax.default_backend()} ({jax.devices()[0]})"


def header(title: str, started: float) -> str:
    """Markdown header: title, the exact command, machine, date and wall time."""
    command = "python " + " ".join([os.path.relpath(sys.argv[0])] + sys.argv[1:])
    return (
        f"# {title}\n\n"
        f"- command: `{command}`\n"
        f"- machine: {machine()}\n"
        f"- date: {datetime.date.today().isoformat()}\n"
        f"- wall time: {time.time() - started:.0f} s\n"
        f"- load average at the end (1, 5, 15 min): {', '.join(f'{v:.1f}' for v in os.getloadavg())} "
        "(the run itself keeps the cores busy; well above the core count, other work shared the CPU and "
        "timings are low)\n\n"
    )


def write_atomic(path: str, text: str) -> None:
    """Write text to path atomically, replacing the previous result file."""
    write_text_atomic(path, text)


def markdown_table(columns, rows) -> str:
    """A GitHub markdown table from column names and rows of already formatted cells."""
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"
