"""Writing the experiments' result files: a header saying how and where a result was made (command, machine,
date, wall time, load, CPU steal), markdown tables, figures, atomic writes, and the hand-written commentary a
regenerated file keeps."""

from __future__ import annotations

import datetime
import os
import platform
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from jaxsr.io.files import write_text_atomic


def cpu_times() -> tuple[int, int] | None:
    """(steal, total) CPU time of the machine so far, in clock ticks summed over its cores, from /proc/stat.

    Steal is time the hypervisor ran something else on this virtual machine's cores: a timing taken while it
    is high is low for reasons outside the code. None where /proc/stat is not there (not Linux)."""
    try:
        with open("/proc/stat") as f:
            fields = [int(v) for v in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    # user nice system idle iowait irq softirq steal [guest guest_nice, already counted in user and nice]
    return (fields[7], sum(fields[:8])) if len(fields) >= 8 else None


def steal_share(since: tuple[int, int] | None, until: tuple[int, int] | None = None) -> float | None:
    """The share of CPU time stolen by the hypervisor between two `cpu_times()` readings (until: now)."""
    until = cpu_times() if until is None else until
    if since is None or until is None or until[1] <= since[1]:
        return None
    return (until[0] - since[0]) / (until[1] - since[1])


# when the experiment script imported this module, i.e. about when it started (`header` reports the CPU steal
# since then)
_CPU_TIMES_AT_START = cpu_times()


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
    """Markdown header: title, the exact command, machine, date, wall time, load and CPU steal during the run."""
    command = "python " + " ".join([os.path.relpath(sys.argv[0])] + sys.argv[1:])
    return (
        f"# {title}\n\n"
        f"- command: `{command}`\n"
        f"- machine: {machine()}\n"
        f"- date: {datetime.date.today().isoformat()}\n"
        f"- wall time: {time.time() - started:.0f} s\n"
        f"- load average at the end (1, 5, 15 min): {', '.join(f'{v:.1f}' for v in os.getloadavg())} "
        "(the run itself keeps the cores busy; a load well above the core count would mean other work shared "
        "the CPU and timings are low)\n"
        + _steal_line()
        + "\n"
    )


def _steal_line() -> str:
    share = steal_share(_CPU_TIMES_AT_START)
    if share is None:
        return ""
    return (f"- CPU steal during the run: {100 * share:.0f} % of the machine's CPU time went to other virtual "
            "machines on the same host (0 on a dedicated machine; the higher, the slower every timing here)\n")


def write_atomic(path: str, text: str) -> None:
    """Write text to path atomically, replacing the previous result file."""
    write_text_atomic(path, text)


def hand_written_tail(path, marker: str) -> str:
    """The commentary written by hand at the end of an earlier results file, from the line `marker` on ('' if
    none): a script that regenerates the file appends it, so a re-run keeps the reading (check it still holds)."""
    text = Path(path).read_text() if Path(path).is_file() else ""
    i = text.find(marker)
    return "\n" + text[i:] if i >= 0 else ""


def save_figure(fig, path, *, dpi: int = 120) -> None:
    """Lay out a matplotlib figure, write it to `path` and free it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def markdown_table(columns, rows) -> str:
    """A GitHub markdown table from column names and rows of already formatted cells."""
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def step_timer(step, carry: list):
    """run(i) -> seconds of one call step(*carry, key i, i) of a compiled train step (the carry, a list of its
    state, kept up to date), results waited for; compiles on creation."""
    def run(i):
        t0 = time.perf_counter()
        *carry[:], metrics = step(*carry, jax.random.key(i), jnp.int32(i))
        jax.block_until_ready(metrics)
        return time.perf_counter() - t0

    run(0)
    return run
