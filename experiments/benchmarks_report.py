"""Run the pytest-benchmark suites and write experiments/results/benchmarks.md.

    python experiments/benchmarks_report.py [pytest -k expression]

Each row: the benchmark, its mean and standard deviation per call, and the throughput it records
(`items_per_s` / `examples_per_s` in extra_info: LR frames, HR frames or training examples per second).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _report import header, markdown_table, write_atomic

ROOT = Path(__file__).resolve().parent.parent
SUITES = ["benchmarks/bench_sensor.py", "benchmarks/bench_scenes.py", "benchmarks/bench_train.py",
          "benchmarks/bench_inference.py"]


def main():
    started = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "bench.json"
        command = [sys.executable, "-m", "pytest", *SUITES, "--benchmark-enable", "-q", f"--benchmark-json={report}"]
        if len(sys.argv) > 1:
            command += ["-k", sys.argv[1]]
        subprocess.run(command, cwd=ROOT, check=True)
        results = json.loads(report.read_text())["benchmarks"]
    rows = []
    for b in results:
        info = b.get("extra_info", {})
        rate = info.get("items_per_s", info.get("examples_per_s"))
        gflops = info.get("gflops_per_s")
        rows.append([f"`{b['fullname'].split('/')[-1]}`", f"{1e3 * b['stats']['mean']:.1f}",
                     f"{1e3 * b['stats']['stddev']:.1f}", f"{rate:.1f}" if rate else "",
                     f"{gflops:.0f}" if gflops else ""])
    text = header("Benchmarks (pytest-benchmark)", started)
    text += (
        "Steady state after compilation, float32, XLA:CPU. Throughput: LR frames/s for the sensor suite "
        "(histograms simulated from HR depth + intensity, then centre of mass, batch of 64 frames), HR frames/s "
        "for rendering, examples/s for training steps (batch 4, cpu preset: 16 x 32 LR crops), HR frames/s for "
        "inference (16 frames of 32 x 64 per call; `super_resolve_histograms` includes the centre of mass). "
        "The suites expose the host's cores as JAX CPU devices (`jaxsr.use_cpu_cores`, benchmarks/conftest.py), "
        "as `jaxsr upscale` does: `test_super_resolve[tr-None]` is the default batch, one frame per device, "
        "split over them; `[tr-1]` runs one frame at a time on one device; `[tr-8]` splits 8 frames. "
        "GFLOP/s: the network's convolutions and dynamic filter (`flops_per_frame`) per second; "
        "`test_matmul_peak` is a 2048^2 float32 matrix product, the ceiling XLA:CPU reaches here.\n\n"
    )
    text += markdown_table(["benchmark", "mean ms / call", "std ms", "items / s", "GFLOP/s"], rows)
    write_atomic(str(ROOT / "experiments/results/benchmarks.md"), text)


if __name__ == "__main__":
    main()
