"""Run the pytest-benchmark suites and write experiments/results/benchmarks.md.

    python experiments/studies/benchmarks_report.py [pytest -k expression]
    python experiments/studies/benchmarks_report.py --json bench.json --out experiments/results/benchmarks_gpu.md

The second form writes the report of a pytest-benchmark JSON recorded elsewhere (e.g. on a lent GPU, where the
suites run as `pytest benchmarks/bench_inference.py --benchmark-enable --benchmark-json bench.json`): the machine
and date are the JSON's, not this host's.

Each row: the benchmark, its mean and standard deviation per call, and the throughput it records
(`items_per_s` / `examples_per_s` in extra_info: LR frames, HR frames or training examples per second).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import header, markdown_table, write_atomic  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SUITES = ["benchmarks/bench_sensor.py", "benchmarks/bench_scenes.py", "benchmarks/bench_train.py",
          "benchmarks/bench_inference.py"]


CPU_NOTE = (
    "Steady state after compilation, float32, XLA:CPU. Throughput: LR frames/s for the sensor suite "
    "(histograms simulated from HR depth + intensity, then centre of mass, batch of 64 frames), HR frames/s "
    "for rendering, examples/s for training steps (batch 4, cpu preset: 16 x 32 LR crops), HR frames/s for "
    "inference (16 frames of 32 x 64 per call; `super_resolve_histograms` includes the centre of mass). "
    "The suites expose the host's cores as JAX CPU devices (`jaxsr.runtime.use_cpu_cores`, benchmarks/conftest.py), "
    "as `jaxsr upscale` does: `test_super_resolve[tr-None]` is the default batch, one frame per device, "
    "split over them; `[tr-1]` runs one frame at a time on one device; `[tr-8]` splits 8 frames. "
    "GFLOP/s: the network's convolutions and dynamic filter (`flops_per_frame`) per second; "
    "`test_matmul_peak[float32]` is a 2048^2 float32 matrix product, the ceiling XLA:CPU reaches here, and "
    "`[bfloat16]` the same of bfloat16 operands with float32 sums, the ceiling of `precision=\"bfloat16\"`; "
    "'of ceiling': an inference benchmark's GFLOP/s over the ceiling of its precision, measured in the same run "
    "(`test_precision_from_histograms` runs the convolutions in bfloat16 where its name says so).\n\n"
)


def table(results: list[dict]) -> str:
    """One row per benchmark: mean and std per call, items/s, GFLOP/s and the share of the matrix-product ceiling
    of its precision where it records them (the last column only where some benchmark does)."""
    rows = []
    shares = any("share_of_matmul_peak" in b.get("extra_info", {}) for b in results)
    for b in results:
        info = b.get("extra_info", {})
        rate = info.get("items_per_s", info.get("examples_per_s"))
        gflops = info.get("gflops_per_s")
        share = info.get("share_of_matmul_peak")
        rows.append([f"`{b['fullname'].split('/')[-1]}`", f"{1e3 * b['stats']['mean']:.1f}",
                     f"{1e3 * b['stats']['stddev']:.1f}", f"{rate:.1f}" if rate else "",
                     f"{gflops:.0f}" if gflops else ""] + ([f"{100 * share:.0f} %" if share else ""] if shares else []))
    return markdown_table(["benchmark", "mean ms / call", "std ms", "items / s", "GFLOP/s"]
                          + (["of ceiling"] if shares else []), rows)


def run_suites(k: str | None) -> list[dict]:
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "bench.json"
        command = [sys.executable, "-m", "pytest", *SUITES, "--benchmark-enable", "-q", f"--benchmark-json={report}"]
        if k:
            command += ["-k", k]
        subprocess.run(command, cwd=ROOT, check=True)
        return json.loads(report.read_text())["benchmarks"]


def recorded_elsewhere(path: Path, machine: str | None, command: str | None) -> str:
    """The report of a JSON recorded on another machine: its title block names that machine (`machine`, else
    what the JSON says) and date."""
    data = json.loads(path.read_text())
    results = data["benchmarks"]
    devices = sorted({b.get("extra_info", {}).get("device", "?") for b in results})
    info = data.get("machine_info", {})
    return (
        f"# Benchmarks (pytest-benchmark), recorded on another machine\n\n"
        f"- source: `{path.name}` (pytest-benchmark JSON), rendered by "
        f"`python experiments/studies/benchmarks_report.py --json {path.name} ...`\n"
        + (f"- recorded with: `{command}`\n" if command else "")
        + f"- machine: {machine or info.get('cpu', {}).get('brand_raw', '?') + ' host'}; JAX devices "
        f"{', '.join(devices)}; Python {info.get('python_version', '?')}\n"
        f"- date: {data.get('datetime', '?')[:10]}\n\n"
        "Steady state after compilation, float32 (the backend's default precision). Items/s as each suite "
        "counts them (the module docstrings of benchmarks/: e.g. HR frames/s for inference, examples/s for "
        "training steps). GFLOP/s: `flops_per_frame` per second.\n\n"
        + table(results)
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("k", nargs="?", help="a pytest -k expression selecting benchmarks")
    ap.add_argument("--json", type=Path, help="report this pytest-benchmark JSON instead of running the suites")
    ap.add_argument("--machine", help="with --json: the machine it ran on, where the JSON does not say (GPU model)")
    ap.add_argument("--recorded-with", help="with --json: the command that recorded it")
    ap.add_argument("--out", help="the report (default experiments/results/benchmarks.md; required with --json)")
    args = ap.parse_args()
    if args.json and (args.k or args.out is None):
        ap.error("--json renders a recorded report: give --out (not the CPU report's file) and no -k expression")
    if not args.json and (args.machine or args.recorded_with):
        ap.error("--machine and --recorded-with describe a --json report")
    if args.json:
        write_atomic(args.out, recorded_elsewhere(args.json, args.machine, args.recorded_with))
        return
    started = time.time()
    results = run_suites(args.k)
    text = header("Benchmarks (pytest-benchmark)", started) + CPU_NOTE + table(results)
    write_atomic(args.out or str(ROOT / "experiments/results/benchmarks.md"), text)


if __name__ == "__main__":
    main()
