"""Cold and warm start of `jaxsr upscale`: wall time of the same command with an empty persistent compilation
cache, then again with the cache the first run filled (and once with the cache disabled).

    python experiments/studies/startup.py [--model tr4] [--frames 8]

Each run is a fresh process (`python -m jaxsr.cli upscale ...`), so the time includes importing JAX, loading
the weights, compiling (or reading compiled code from the cache) and super-resolving the frames.
Writes experiments/results/startup.md.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import header, markdown_table, write_atomic  # noqa: E402


def run(args, cache, inp, out):
    env = dict(os.environ, JAXSR_CACHE_DIR=str(cache))
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "jaxsr.cli", "upscale", str(inp), "-o", str(out), "-m", args.model,
                    "--no-progress", "--force"], env=env, check=True, capture_output=True)
    return time.perf_counter() - t0


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["tr0", "tr4"])
    parser.add_argument("--frames", type=int, default=8)
    args = parser.parse_args()
    started = time.time()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        inp = tmp / "in.npy"
        np.save(inp, np.random.default_rng(0).uniform(0.1, 0.9, (args.frames, 32, 64)).astype(np.float32))
        for model in args.models:
            args.model = model
            cache = tmp / f"cache_{model}"
            off = run(args, "off", inp, tmp / "o.npy")
            cold = run(args, cache, inp, tmp / "o.npy")
            warm = run(args, cache, inp, tmp / "o.npy")
            size = sum(f.stat().st_size for f in cache.rglob("*") if f.is_file()) / 2**20
            rows.append([model, f"{off:.1f}", f"{cold:.1f}", f"{warm:.1f}", f"{size:.1f}"])
            print(*rows[-1], flush=True)
    text = header("Cold and warm start of `jaxsr upscale`", started)
    text += (f"Wall time (s) of `jaxsr upscale in.npy -o out.npy -m M` on {args.frames} frames of 32 x 64, each "
             "a fresh process: with the compilation cache disabled (JAXSR_CACHE_DIR=off), with an empty cache "
             "(cold), and again with the cache the cold run filled (warm).\n\n")
    text += markdown_table(["model", "no cache", "cold", "warm", "cache MB"], rows)
    write_atomic("experiments/results/startup.md", text)


if __name__ == "__main__":
    main()
