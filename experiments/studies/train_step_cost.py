"""The paper preset's train step split into its parts: scene rendering, photon simulation, network forward +
backward, Adam; XLA's cost analysis (FLOPs, bytes) of each part and of the whole step, and CPU timings.

    python experiments/studies/train_step_cost.py [--tr 0 4] [--time-batch 4] [--cost-batch 16 64] [--rows JSONL]
    python experiments/studies/train_step_cost.py --report JSONL [--out MD]   # the table of the rows gathered

Each part is jitted alone on the same inputs the step gives it (`jaxsr.training.data.scene_clips` split in two:
`training_clip` per example, then `_simulate_clip`), compiled for the default backend, and its compiled cost
analysis read: "flops" and "bytes accessed" after XLA's fusion, as the backend will run it (XLA:CPU counts the
convolutions' FLOPs; on a GPU they are cuDNN calls that the count leaves out), and the kernels a call launches
(`_kernels`: on a GPU each costs a few microseconds of launch however little it does). At `--time-batch` each part is
also timed: median of `--repeats` runs after one warm-up. The whole step (`make_train_step(...).jitted`, as `fit`
trains) is analysed and timed beside the parts. Prints a markdown table; `--rows` appends the rows to a JSON-lines
file (so that runs of one TR at a time add up), `--report` makes the table of such a file, `--out` writes it with the
machine and the date.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import platform
import re
import subprocess
import sys
import time

import jax
import jax.numpy as jnp

from jaxsr.config import PRESETS, ModelConfig, Sensor
from jaxsr.nn.duf import apply_model_train, init_model
from jaxsr.scenes import training_clip
from jaxsr.training import default_data, make_train_step
from jaxsr.training.data import _simulate_clip
from jaxsr.training.duf import model_loss
from jaxsr.training.optim import adam_init, adam_update

PARTS = ("render", "simulate", "network", "adam", "step")


# HLO instructions of the optimised module that move no data: the others count the kernels a GPU would launch
_FREE_OPS = frozenset({"parameter", "constant", "get-tuple-element", "tuple", "bitcast", "copy-start", "copy-done",
                       "after-all", "partition-id", "replica-id"})


def _kernels(hlo: str) -> int:
    """The instructions doing work that one call of an optimised HLO module runs: a fusion or a library call
    counts once (a GPU launches it as one kernel, a few microseconds however small), a while loop's body times its
    known trip count (once when XLA does not know it), a call's or conditional's body once."""
    comps, name, entry = {}, None, None
    for line in hlo.splitlines():
        if line.endswith("{") and not line.startswith(" "):
            name = line.split()[1 if line.startswith("ENTRY") else 0].lstrip("%")
            entry = name if line.startswith("ENTRY") else entry
            comps[name] = []
        elif line.startswith("  ") and name and " = " in line:
            comps[name].append(line)

    def count(comp: str) -> int:
        n = 0
        for line in comps.get(comp, []):
            m = _OP.search(line)
            op = m.group(1) if m else ""
            if op in ("while", "call", "conditional"):
                called = [c.strip("%") for key, names in _CALLED.findall(line) for c in names.strip("{}").split(",")]
                trips = _TRIPS.search(line)
                n += (int(trips.group(1)) if trips and op == "while" else 1) * sum(count(c.strip()) for c in called)
            else:
                n += op not in _FREE_OPS
        return n

    return count(entry)


_OP = re.compile(r" = (?:\(.*?\)|\S+) ([a-z][\w-]*)\(")  # the op after the result's type (a tuple's in brackets)
_CALLED = re.compile(r"(body|condition|to_apply|branch_computations)=(\{[^}]*\}|%?[\w.-]+)")
_TRIPS = re.compile(r'"known_trip_count":\{"n":"(\d+)"\}')


def _cost(compiled) -> dict:
    """{"flops", "bytes", "kernels"} of a compiled function: XLA's cost analysis (a list of one per device in
    older JAX) and `_kernels` of its optimised HLO."""
    cost = compiled.cost_analysis()
    if isinstance(cost, (list, tuple)):
        cost = cost[0] if cost else {}
    return {"flops": float(cost.get("flops", 0.0)), "bytes": float(cost.get("bytes accessed", 0.0)),
            "kernels": _kernels(compiled.as_text())}


def step_parts(tr: int, batch: int, sensor: Sensor = Sensor()):
    """The step's parts at the paper preset: {name: (function, example arguments)}, each function taking the
    outputs of the one before (render -> simulate -> network -> adam), and the whole step."""
    model_cfg = ModelConfig(tr=tr)
    train_cfg = dataclasses.replace(PRESETS["paper"], batch_size=batch)
    frames = 2 * tr + 1
    keys = jax.random.split(jax.random.key(0), batch)
    k_scene, k_rest = jax.vmap(jax.random.split, out_axes=1)(keys)  # as scene_clips splits each example's key

    def render(k):  # (B,) keys -> depth, intensity (B, 2tr+1, H, W)
        return jax.vmap(lambda kk: training_clip(kk, frames, sensor=sensor, shift_range=train_cfg.motion_range))(k)

    def simulate(k, depth, intensity):  # -> windows (B, 2tr+1, h, w), gt of the centre frames (B, H, W)
        clips, gt = jax.vmap(lambda *a: _simulate_clip(*a, train_cfg, sensor))(k, depth, intensity)
        return clips, gt[:, tr]

    def network(params, state, windows, gt):  # the loss and its gradients, BN in training mode
        def loss_fn(p):
            out, new_state = apply_model_train(p, state, windows, model_cfg, precision=train_cfg.precision)
            return model_loss(out, gt, model_cfg, train_cfg), new_state

        return jax.value_and_grad(loss_fn, has_aux=True)(params)

    def adam(grads, opt, params):
        return adam_update(grads, opt, params, lr=jnp.float32(train_cfg.lr))

    params, state = init_model(jax.random.key(1), model_cfg)
    opt = adam_init(params)
    depth, intensity = jax.eval_shape(render, k_scene)
    windows, gt = jax.eval_shape(simulate, k_rest, depth, intensity)
    step = make_train_step(model_cfg, train_cfg, default_data(model_cfg, train_cfg), mesh=None)
    return {
        "render": (render, (k_scene,)),
        "simulate": (simulate, (k_rest, depth, intensity)),
        "network": (network, (params, state, windows, gt)),
        "adam": (adam, (params, opt, params)),
        "step": (step.jitted, (params, state, opt, jax.random.key(2), jnp.float32(train_cfg.lr))),
    }


def _concrete(args):
    """Shape structs replaced by arrays of ones-like values (depth 10 m, intensity and windows 0.5)."""
    return jax.tree_util.tree_map(
        lambda a: jnp.full(a.shape, 0.5 if a.dtype == jnp.float32 else 0, a.dtype)
        if isinstance(a, jax.ShapeDtypeStruct) else a, args)


def measure(tr: int, batch: int, *, time_it: bool, repeats: int, rows_file=None) -> list[dict]:
    """One row per part: compile seconds, FLOPs, bytes, kernels and (with time_it) the median ms of a call, each
    also appended to `rows_file` (JSON lines) as soon as measured."""
    rows = []
    parts = step_parts(tr, batch)
    for name in PARTS:
        fn, args = parts[name]
        if name == "simulate":  # real scenes: the simulation's cost does not depend on them, its numbers do
            args = (args[0], *jax.jit(parts["render"][0])(*parts["render"][1]))
        args = _concrete(args)
        t0 = time.perf_counter()
        compiled = jax.jit(fn).lower(*args).compile()
        row = {"tr": tr, "batch": batch, "part": name, "compile_s": time.perf_counter() - t0, **_cost(compiled)}
        if time_it:
            jax.block_until_ready(compiled(*args))
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                jax.block_until_ready(compiled(*args))
                times.append(time.perf_counter() - t0)
            row["ms"] = 1e3 * sorted(times)[len(times) // 2]
        rows.append(row)
        print(row, file=sys.stderr, flush=True)
        if rows_file:
            with open(rows_file, "a") as f:
                f.write(json.dumps(row) + "\n")
    return rows


def table(rows: list[dict]) -> str:
    """The rows as a markdown table, with each part's share of the parts' FLOPs, bytes and time."""
    lines = ["| TR | batch | part | GFLOP | GB accessed | FLOP/byte | kernels | CPU ms | share of FLOPs | "
             "share of bytes | share of CPU ms | compile s |",
             "| ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for (tr, batch) in sorted({(r["tr"], r["batch"]) for r in rows}):
        group = [r for r in rows if (r["tr"], r["batch"]) == (tr, batch)]
        parts = [r for r in group if r["part"] != "step"]
        total = {k: sum(r.get(k, 0.0) for r in parts) for k in ("flops", "bytes", "ms")}

        def share(r, k):
            return f"{100 * r[k] / total[k]:.1f} %" if k in r and total[k] and r["part"] != "step" else ""

        for r in group:
            ms = f"{r['ms']:.1f}" if "ms" in r else ""
            intensity = f"{r['flops'] / r['bytes']:.1f}" if r["bytes"] else ""
            lines.append(f"| {tr} | {batch} | {r['part']} | {r['flops'] / 1e9:.2f} | {r['bytes'] / 1e9:.3f} | "
                         f"{intensity} | {r['kernels']} | {ms} | {share(r, 'flops')} | {share(r, 'bytes')} | "
                         f"{share(r, 'ms')} | "
                         f"{r['compile_s']:.0f} |")
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tr", type=int, nargs="+", default=[0, 4])
    ap.add_argument("--time-batch", type=int, nargs="*", default=[4], help="batches analysed and timed")
    ap.add_argument("--cost-batch", type=int, nargs="*", default=[16, 64], help="batches analysed only")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rows", help="append the measured rows (JSON lines) to this file")
    ap.add_argument("--report", help="no measurement: the table of the rows in this file")
    ap.add_argument("--out", help="also write the table (with the machine and date) here")
    args = ap.parse_args(argv)
    if args.report:
        with open(args.report) as f:
            rows = [json.loads(line) for line in f if line.strip()]
    else:
        rows = []
        for tr in args.tr:
            for batch in args.time_batch:
                rows += measure(tr, batch, time_it=True, repeats=args.repeats, rows_file=args.rows)
            for batch in args.cost_batch:
                rows += measure(tr, batch, time_it=False, repeats=0, rows_file=args.rows)
    text = table(rows)
    print(text)
    if args.out:
        cpu = subprocess.run("lscpu | grep 'Model name'", shell=True, capture_output=True, text=True).stdout.strip()
        head = (f"- machine: {cpu or platform.processor()}, {jax.device_count()} {jax.default_backend()} device(s), "
                f"JAX {jax.__version__}\n- date: {datetime.date.today()}\n\n")
        with open(args.out, "w") as f:
            f.write(head + text + "\n")


if __name__ == "__main__":
    main()
