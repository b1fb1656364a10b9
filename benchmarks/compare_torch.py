"""JAX vs PyTorch: full-frame inference speed of the same network on the same CPU.

For each temporal radius and batch size, super-resolves one random LR sequence (frames, 32, 64) ->
(frames, 128, 256) with `jaxsr.super_resolve(model, lr_seq, batch_size=B)` and with the PyTorch port
(benchmarks/torch_reference.py, same weights), and reports frames/s of both, their ratio and the largest
difference between the two outputs. Writes experiments/results/torch_compare.md.

    pip install torch==2.13.0          # only for this script; torch is not a jaxsr dependency
    python benchmarks/compare_torch.py [--tr 0 1 2 3 4] [--batch 1 8] [--frames 32] [--threads 2]
                                       [--rounds 3] [--variants ...] [--compile]
                                       [--out experiments/results/torch_compare.md]

Fair to torch: every (layout, conv) variant of the port is timed (`--variants`; channels-last or
channels-first activations, one conv3d or a sum of per-tap conv2d) and the table compares JAX with the
fastest; batch norm after the 1x1x1 convolution is folded into it; `--compile` adds `torch.compile`d
variants (inductor with weight freezing; each compiles for 10-60 s). `torch.set_num_threads(--threads)`
(default: every core, as XLA:CPU uses). `OMP_WAIT_POLICY` defaults to PASSIVE (unless set in the
environment): on a loaded machine torch's spinning OpenMP threads were measured 4-20x slower at 2 threads.
Timing: warm-up passes (compilation, oneDNN primitive creation) are excluded; then `--rounds` rounds
alternate JAX and every torch variant, so that a background load hits all of them alike; frames/s counts
the fastest round of each (frames / best wall time), and the JAX / torch ratio is also given round by round
(median and range), which is the steadier figure on a shared host. Weights are random
(`torch_reference.random_model`): the speed does not depend on them.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

# before torch is imported: sleeping rather than spinning OpenMP threads (see the docstring)
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import jax  # noqa: E402
import numpy as np  # noqa: E402

import jaxsr  # noqa: E402

# JAX as users run it (`jaxsr upscale`): each core a CPU device, a batch split over them when they divide it.
# Before any JAX operation.
N_DEVICES = jaxsr.runtime.use_cpu_cores()
CORES = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))  # experiments/: the shared harness
from harness.reports import header, markdown_table, write_atomic  # noqa: E402

TORCH_MISSING = ("The JAX vs PyTorch comparisons need PyTorch, which is not a jaxsr dependency; "
                 "install the CPU build with:\n"
                 "    pip install torch==2.13.0")
LR_SHAPE = (32, 64)


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tr", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="temporal radii")
    parser.add_argument("--batch", type=int, nargs="+", default=[1, 2, 8], help="frames per network call")
    parser.add_argument("--frames", type=int, default=32, help="length of the LR sequence")
    parser.add_argument("--threads", type=int, default=CORES, help="torch.set_num_threads (default: usable cores)")
    parser.add_argument("--rounds", type=int, default=3, help="timed passes per engine (the best counts)")
    parser.add_argument("--variants", nargs="+", default=None, metavar="LAYOUT/CONV",
                        help="torch variants to time (default: all of channels_last|channels_first x native|taps)")
    parser.add_argument("--compile", action="store_true", help="also time torch.compile'd variants")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="experiments/results/torch_compare.md")
    args = parser.parse_args(argv)
    if min(args.tr) < 0 or min(args.batch) < 1 or args.frames < 1 or args.threads < 1 or args.rounds < 1:
        parser.error("--tr must be >= 0; --batch, --frames, --threads and --rounds >= 1")
    return args


def timed(fn):
    """(result, wall seconds) of fn()."""
    t = time.perf_counter()
    result = fn()
    return result, time.perf_counter() - t


def main(argv=None):
    args = parse_args(argv)
    started = time.time()
    try:
        import torch
    except ImportError:
        sys.exit(TORCH_MISSING)
    import torch_reference as tref

    variants = tref.VARIANTS if args.variants is None else [tuple(v.split("/")) for v in args.variants]
    for v in variants:
        if len(v) != 2 or v not in tref.VARIANTS:
            sys.exit(f"--variants: expected LAYOUT/CONV among {['/'.join(x) for x in tref.VARIANTS]}, got {v}")
    candidates = [(layout, conv, False) for layout, conv in variants]
    if args.compile:
        import torch._inductor.config as inductor_config

        inductor_config.freezing = True  # weights as constants: conv+bias fusion and oneDNN weight prepacking
        candidates += [(layout, conv, True) for layout, conv in variants]
    torch.set_num_threads(args.threads)
    names = [f"{layout}/{conv}" + (" +compile" if comp else "") for layout, conv, comp in candidates]
    load_before = os.getloadavg()

    rng = np.random.default_rng(args.seed)
    lr_seq = rng.uniform(0.0, 1.0, (args.frames, *LR_SHAPE)).astype(np.float32)
    rows, sweep_rows = [], []
    for tr in args.tr:
        model = tref.random_model(tr, seed=args.seed)
        model = jax.tree_util.tree_map(jax.numpy.asarray, model)  # weights on the device once, as load_model does
        for b in args.batch:
            def run_jax():
                return jax.block_until_ready(jaxsr.super_resolve(model, lr_seq, batch_size=b))

            hr_jax, compile_s = timed(run_jax)  # warm-up: jit compilation
            runners, diffs = [], []
            for layout, conv, comp in candidates:
                net = tref.build_torch_net(model, layout=layout, conv=conv, compile=comp)
                run = (lambda net=net: tref.torch_super_resolve(net, lr_seq, batch_size=b))
                hr_torch, _ = timed(run)  # warm-up: oneDNN primitives, torch.compile
                runners.append(run)
                diffs.append(float(np.max(np.abs(hr_torch - hr_jax))))
            jax_s, torch_s = [], [[] for _ in runners]  # wall seconds per round
            for _ in range(args.rounds):  # interleaved, so that a background load hits every engine alike
                jax_s.append(timed(run_jax)[1])
                for i, run in enumerate(runners):
                    torch_s[i].append(timed(run)[1])
            fps_jax = args.frames / min(jax_s)
            fps_torch = [args.frames / min(t) for t in torch_s]
            i = int(np.argmax(fps_torch))
            # the same ratio round by round: rounds run back to back, so a slow spell of the host hits both sides
            paired = np.asarray(torch_s[i]) / np.asarray(jax_s)
            rows.append([tr, b, f"{fps_jax:.2f}", f"{fps_torch[i]:.2f}", names[i], f"{fps_jax / fps_torch[i]:.2f}",
                         f"{np.median(paired):.2f} ({paired.min():.2f}-{paired.max():.2f})", f"{diffs[i]:.1e}"])
            sweep_rows.append([tr, b, f"{fps_jax:.2f}"] + [f"{f:.2f}" for f in fps_torch] + [f"{max(diffs):.1e}"])
            print(f"tr={tr} batch={b}: JAX {fps_jax:.2f} frames/s (first call {compile_s:.1f} s), torch "
                  + ", ".join(f"{n} {f:.2f}" for n, f in zip(names, fps_torch))
                  + f"; max |JAX - torch| {max(diffs):.1e}", flush=True)

    load_after = os.getloadavg()
    notes = (
        f"Full-frame inference, LR {LR_SHAPE[0]}x{LR_SHAPE[1]} -> HR {LR_SHAPE[0] * 4}x{LR_SHAPE[1] * 4}, a random "
        f"sequence of {args.frames} frames, random weights. JAX: `jaxsr.super_resolve(model, lr_seq, batch_size=B)` "
        f"(XLA:CPU, {N_DEVICES} CPU devices over {CORES} cores: a batch divisible by {N_DEVICES} is split over them, "
        f"as `jaxsr.runtime.use_cpu_cores` sets up; compiled with `jaxsr.runtime.compiler_options()` = "
        f"{jaxsr.runtime.compiler_options()}; "
        f"`conv3d_impl=\"auto\"`: temporal taps stacked where `stacked_use` >= 0.7). "
        f"PyTorch {torch.__version__}: the port in "
        f"`benchmarks/torch_reference.py` (`torch_super_resolve`, eval mode, `torch.inference_mode()`, BN folded "
        f"into the preceding 1x1x1 convolution), `torch.set_num_threads({args.threads})`, oneDNN "
        f"{'on' if torch.backends.mkldnn.is_available() and torch.backends.mkldnn.enabled else 'off'}, "
        f"OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY')}. Warm-up excluded; {args.rounds} interleaved rounds, "
        f"the fastest counts. frames/s = {args.frames} / best wall time of the whole sequence. "
        f"Load average (1 min) {load_before[0]:.1f} before, {load_after[0]:.1f} after: other processes on the "
        f"machine slow every engine, so compare within a row, not across runs.\n\n"
        "**JAX / torch** > 1 means JAX is faster (the project requires >= 1): the ratio of the best rounds, and "
        "the median (min-max) of the same ratio taken round by round, JAX against the same torch variant in the "
        "same round. The torch column is the fastest "
        "torch variant of the row (all of them are in the second table). max |diff| is the largest absolute "
        "difference between the two HR outputs (normalised depth).\n\n"
    )
    table = markdown_table(
        ["TR", "batch", "JAX frames/s", "torch frames/s", "torch variant", "JAX / torch (best rounds)",
         "JAX / torch per round: median (range)", "max abs diff"], rows
    )
    sweep = markdown_table(["TR", "batch", "JAX"] + names + ["max abs diff (all)"], sweep_rows)
    text = (header("JAX vs PyTorch inference speed on CPU", started) + notes + table
            + "\n## Every torch variant (frames/s)\n\n" + sweep)
    write_atomic(args.out, text)
    print(table + "\n" + sweep + f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
