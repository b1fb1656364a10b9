"""JAX vs PyTorch, layer by layer: where the time of one network window goes in each engine, on the same CPU.

Times every dense block's three stages (BN-ReLU-1x1x1-BN-ReLU, the 3x3x3 convolution, the concatenation), for
the same inputs, as jaxsr runs them (`conv3d(impl="auto")`, jitted with `jaxsr.runtime.compiler_options()`) and as the
PyTorch port runs them (benchmarks/torch_reference.py, channels-last, per-tap oneDNN `conv2d`, BN folded),
plus a 2048^2 matrix product in both as a reference for the machine's peak. Writes
experiments/results/torch_layers.md.

    pip install torch==2.13.0          # only for this script; torch is not a jaxsr dependency
    python benchmarks/compare_torch_layers.py [--tr 4] [--batch 1] [--rounds 7] [--threads 2]
                                              [--out experiments/results/torch_layers.md]

Timing: each stage is warmed up once, then `--rounds` rounds run every stage of both engines in turn (so a
slow spell of the host hits both alike) and the fastest round of each counts. GFLOP/s count the products
that reach an output (as `jaxsr.flops_per_frame`), not the extra ones of `conv3d_stacked`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

# compare_torch sets the process up as that comparison does (OMP_WAIT_POLICY, the cores as JAX devices) and
# holds the shared constants; import it before any JAX operation
import compare_torch as ct
import jax
import jax.numpy as jnp
import numpy as np

import jaxsr
from jaxsr.nn.layers import batch_norm, conv3d

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))  # experiments/: the shared harness
from harness.reports import header, markdown_table, write_atomic  # noqa: E402

LR_SHAPE = ct.LR_SHAPE


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tr", type=int, default=4, help="temporal radius of the network")
    parser.add_argument("--batch", type=int, default=1, help="windows per call")
    parser.add_argument("--rounds", type=int, default=7, help="timed rounds (the fastest counts)")
    parser.add_argument("--threads", type=int, default=ct.CORES, help="torch.set_num_threads (default: usable cores)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="experiments/results/torch_layers.md")
    args = parser.parse_args(argv)
    if args.tr < 0 or min(args.batch, args.rounds, args.threads) < 1:
        parser.error("--tr must be >= 0; --batch, --rounds and --threads >= 1")
    return args


def jax_timer(fn, *args):
    """(time one call, result) for fn jitted as `super_resolve` compiles."""
    compiled = jax.jit(fn, compiler_options=jaxsr.runtime.compiler_options())
    result = jax.block_until_ready(compiled(*args))

    def once():
        t = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        return time.perf_counter() - t

    return once, result


def torch_timer(torch, fn, *args):
    """(time one call, result) for fn under `torch.inference_mode()`."""
    with torch.inference_mode():
        result = fn(*args)

    def once():
        with torch.inference_mode():
            t = time.perf_counter()
            fn(*args)
            return time.perf_counter() - t

    return once, result


def block_stages(torch, model, net, x_np):
    """[(name, GFLOP, jax timer, torch timer)] of every dense block, fed the same activations."""
    cfg, params, state = model.config, model.params, model.state
    bn = {"train": False, "momentum": cfg.bn_momentum, "eps": cfg.bn_eps}
    pixels = x_np.shape[0] * LR_SHAPE[0] * LR_SHAPE[1]
    stages = []
    xj, xt = jnp.asarray(x_np), torch.from_numpy(x_np)
    for i, (p, s) in enumerate(zip(params["blocks"], state["blocks"])):
        blk, valid = net.blocks[i], i >= cfg.same_blocks
        f, t_in = xj.shape[-1], xj.shape[1]
        t_out = t_in - 2 if valid else t_in

        def pointwise(x, p=p, s=s):
            y, _ = batch_norm(p["bn1"], s["bn1"], x, **bn)
            y, _ = batch_norm(p["bn2"], s["bn2"], conv3d(jax.nn.relu(y), p["conv1"]["w"], p["conv1"]["b"]), **bn)
            return jax.nn.relu(y)

        def pointwise_torch(x, blk=blk):
            return torch.relu_(net._apply_pointwise(net._bn_relu(x, blk["bn1"]), blk["conv1"]))

        pad = ((0, 0) if valid else (1, 1), (1, 1), (1, 1))
        j1, yj = jax_timer(pointwise, xj)
        t1, yt = torch_timer(torch, pointwise_torch, xt)
        j2, zj = jax_timer(lambda y, p=p, pad=pad: conv3d(y, p["conv2"]["w"], p["conv2"]["b"], padding=pad), yj)
        t2, zt = torch_timer(torch, lambda y, blk=blk: net._apply_conv(y, blk["conv2"]), yt)
        j3, xj = jax_timer(lambda x, z, v=valid: jnp.concatenate([x[:, 1:-1] if v else x, z], -1), xj, zj)
        t3, xt = torch_timer(torch, lambda x, z, v=valid: torch.cat([x[:, 1:-1] if v else x, z], -1), xt, zt)
        # products that reach an output: 3x3 spatial taps x temporal taps inside the window
        taps = 3 * t_out if valid else 3 * t_in - 2
        gflop_3x3 = 2 * pixels * taps * 9 * f * cfg.growth / 1e9
        name = f"block {i} ({'valid' if valid else 'same'}, {f} ch, T {t_in}->{t_out})"
        stages += [(f"{name}: BN-ReLU-1x1x1-BN-ReLU", 2 * pixels * t_in * f * f / 1e9, j1, t1),
                   (f"{name}: 3x3x3 conv", gflop_3x3, j2, t2),
                   (f"{name}: concatenate", 0.0, j3, t3)]
    return stages


def main(argv=None):
    args = parse_args(argv)
    started = time.time()
    try:
        import torch
    except ImportError:
        sys.exit(ct.TORCH_MISSING)
    import torch_reference as tref

    torch.set_num_threads(args.threads)
    model = jax.tree_util.tree_map(jnp.asarray, tref.random_model(args.tr, seed=args.seed))
    net = tref.build_torch_net(model, layout="channels_last", conv="taps")
    rng = np.random.default_rng(args.seed)
    x = rng.uniform(0.0, 1.0, (args.batch, model.config.frames, *LR_SHAPE, model.config.base)).astype(np.float32)
    stages = block_stages(torch, model, net, x)

    a = rng.standard_normal((2048, 2048)).astype(np.float32)
    aj, at = jnp.asarray(a), torch.from_numpy(a)
    stages.append(("reference: 2048 x 2048 matrix product", 2 * 2048**3 / 1e9,
                   jax_timer(lambda m: m @ m, aj)[0], torch_timer(torch, lambda m: m @ m, at)[0]))

    best = {name: [np.inf, np.inf] for name, *_ in stages}
    for _ in range(args.rounds):  # interleaved
        for name, _, jt, tt in stages:
            best[name][0] = min(best[name][0], jt())
            best[name][1] = min(best[name][1], tt())

    def rate(gflop, s):
        return f"{gflop / s:.0f}" if gflop else ""

    rows, total = [], np.zeros(2)
    for name, gflop, *_ in stages:
        tj, tt = best[name]
        if not name.startswith("reference"):
            total += (tj, tt)
        rows.append([name, f"{1e3 * tj:.2f}", f"{1e3 * tt:.2f}", f"{tj / tt:.2f}", rate(gflop, tj), rate(gflop, tt)])
    rows.insert(-1, ["all blocks", f"{1e3 * total[0]:.1f}", f"{1e3 * total[1]:.1f}", f"{total[0] / total[1]:.2f}",
                     "", ""])
    notes = (
        f"TR{args.tr} network, random weights, batch {args.batch}, LR {LR_SHAPE[0]}x{LR_SHAPE[1]}, every dense "
        f"block fed the same activations in both engines. JAX: `conv3d(impl=\"auto\")`, jitted with "
        f"`jaxsr.runtime.compiler_options()` = {jaxsr.runtime.compiler_options()}, "
        f"{jax.local_device_count()} CPU devices (this "
        f"runs on the first). PyTorch {torch.__version__}: `benchmarks/torch_reference.py`, channels-last, "
        f"per-tap oneDNN `conv2d`, BN folded into the 1x1x1 convolution, `torch.set_num_threads({args.threads})`. "
        f"Fastest of {args.rounds} interleaved rounds. **JAX / torch** is the ratio of times (< 1: JAX faster). "
        "GFLOP/s count the products that reach an output. The head and the filter branch are not timed here.\n\n"
    )
    table = markdown_table(["stage", "JAX ms", "torch ms", "JAX / torch", "JAX GFLOP/s", "torch GFLOP/s"], rows)
    write_atomic(args.out, header("JAX vs PyTorch, layer by layer, on CPU", started) + notes + table)
    print(table + f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
