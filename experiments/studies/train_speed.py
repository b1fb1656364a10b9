"""Training throughput: the train steps of 2026-11-22, of main before the sequence step, and the new one.

    python experiments/studies/train_speed.py            (about 15 minutes on 2 busy CPU cores)

Runs `benchmarks/bench_train.py -k today_vs_new` (windowed TR0 and TR4, sequence-form TR4; the step of the
2026-11-22 baseline, of main before this change, and the new one on 1 and 2 devices, timed in interleaved
rounds of one run)
and writes its table to experiments/results/train_speed.md; the hand-written profile and reading at the end of
that file (from "## Reading") are kept on re-runs.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import hand_written_tail, header, markdown_table, write_atomic  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "experiments" / "results" / "train_speed.md"
HAND_WRITTEN = "## Reading"


def run_benchmark() -> list[dict]:
    """The benchmark's records: one per (form, TR), its extra_info {variant: {step_s, ...}}."""
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "bench.json"
        cmd = [sys.executable, "-m", "pytest", "benchmarks/bench_train.py", "-n", "0", "-q", "-s",
               "--benchmark-enable", "--benchmark-only", "-k", "today_vs_new", f"--benchmark-json={report}"]
        subprocess.run(cmd, cwd=ROOT, check=True)
        return json.loads(report.read_text())["benchmarks"]


def table(records: list[dict]) -> str:
    rows = []
    for rec in records:
        form, tr = rec["params"]["form"], rec["params"]["tr"]
        for name, info in rec["extra_info"].items():
            if not isinstance(info, dict):
                continue
            rows.append([form, tr, name, f"{1e3 * info['step_s']:.1f}", f"{info['examples_per_s']:.2f}",
                         f"{info['frames_per_s']:.2f}", f"{info['gflop_per_s']:.1f}",
                         "" if name == "inference" else f"{info['speed_up_vs_2026_11_22']:.2f}",
                         "" if name == "inference" else f"{info['speed_up_vs_main']:.2f}"])
    return markdown_table(["form", "TR", "step", "ms/step (fastest round)", "examples/s", "supervised frames/s",
                           "GFLOP/s", "speed-up vs 2026-11-22", "speed-up vs main"], rows)


def main():
    started = time.time()
    records = run_benchmark()
    text = header("Training throughput: windowed and sequence-form train steps", started)
    text += (
        "Interleaved rounds of one run (`benchmarks/bench_train.py::test_train_step_today_vs_new`), the fastest "
        "round of each step; only the ratios carry over to another machine. The `cpu` preset: batch 4, 16 x 32 LR "
        "crops; the windowed form on windows of 2 TR + 1 frames, the sequence form on clips of 2R + 8 frames "
        "(loss on the 8 inner frames); data simulated inside the step from a synthetic HR sequence "
        "(`sequence_clips`, no rendering). Steps: 2026-11-22 = the step of 2026-11-22 (each example's whole clip "
        "simulated, then cropped; stacked layers' gradients through the stacked form; one device); main = the "
        "step before this change (photons drawn for the crop only); new = main's data with the stacked layers' "
        "gradients through the temporal taps (`jaxsr.nn.layers.STACKED_GRADIENT`), on one device and split over "
        "both cores as devices (what `fit` does under `jaxsr.runtime.use_cpu_cores()`). inference = the forward pass "
        "(BN from running statistics, `compiler_options()`) on the same inputs, the reference arithmetic rate. "
        "GFLOP/s = `flops_per_frame` x supervised frames (x 3 for forward + backward) / step time.\n\n"
    )
    text += table(records)
    write_atomic(OUT, text + hand_written_tail(OUT, HAND_WRITTEN))
    print(OUT.read_text())


if __name__ == "__main__":
    main()
