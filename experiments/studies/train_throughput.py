"""Training throughput of the paper preset's step over TRs, batch sizes and convolution precisions, on an accelerator.

    python experiments/studies/train_throughput.py --sweep OUT [--tr 0 4] [--batch 4 16 64] [--precision ...]
    python experiments/studies/train_throughput.py --report OUT/throughput.jsonl   # the table, as markdown

`--sweep` starts one process per configuration (TR, batch, `TrainConfig.precision`): they compile side by side
(compilation, with XLA's autotuning, is most of a configuration's cost: about a minute each on an H100, one CPU
core each), then take turns on the device, one at a time, so that every time is measured alone. Each turn times
the compiled step (the scene rendering and sensor simulation inside it, as `fit` trains) over repeats of enough
steps for half a second, after warm-up, and reads the step's FLOPs from XLA's cost analysis. The first turn
measures the device's ceilings: large matrix products in float32, at the backend's default precision and in
bfloat16 (float32 accumulation), and each precision's relative error against float64 (which names what "default"
is on the device: TF32 on NVIDIA GPUs since Ampere). Results go to OUT/throughput.jsonl, a line per turn.
Compilation needs a core per configuration: on 2026-11-26's H200 (16 cores) eight compiled in 145-201 s, while 18
beside two training processes compiled none within 159 s, so sweep a few configurations at a time.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path

STEP_REPEATS = 3  # timed repeats of each configuration's steps; the median is reported
REPEAT_S = 0.5  # seconds of steps per repeat (at least 5 steps)


def _flops(compiled) -> float | None:
    """The compiled step's FLOPs from XLA's cost analysis (a dict, or a list of one per device in older JAX)."""
    cost = compiled.cost_analysis()
    if isinstance(cost, (list, tuple)):
        cost = cost[0] if cost else {}
    return float(cost["flops"]) if cost and "flops" in cost else None


def compile_step(tr: int, batch: int, precision: str):
    """The paper preset's train step at this TR, batch and precision, compiled for one device, with its carry."""
    import jax

    import jaxsr
    from jaxsr.config import PRESETS
    from jaxsr.nn import init_model
    from jaxsr.training import default_data, make_train_step
    from jaxsr.training.optim import adam_init

    model_cfg = jaxsr.ModelConfig(tr=tr)
    train_cfg = dataclasses.replace(PRESETS["paper"], batch_size=batch, precision=precision)
    params, state = init_model(jax.random.key(0), model_cfg)
    step = make_train_step(model_cfg, train_cfg, default_data(model_cfg, train_cfg), mesh=None)
    carry = [params, state, adam_init(params)]
    compiled = step.jitted.lower(*carry, jax.random.key(0), jax.numpy.float32(train_cfg.lr)).compile()
    return compiled, carry


def time_steps(compiled, carry: list) -> dict:
    """Median seconds per step of `compiled` over STEP_REPEATS repeats, after warm-up, and the last loss."""
    import jax
    import jax.numpy as jnp

    i = 0

    def run(n: int) -> float:
        nonlocal i
        t0 = time.perf_counter()
        for _ in range(n):
            *carry[:], metrics = compiled(*carry, jax.random.key(i), jnp.float32(1e-3))  # the paper's rate
            i += 1
        jax.block_until_ready(metrics)
        run.loss = float(metrics["loss"])
        return (time.perf_counter() - t0) / n

    per_step = run(3)  # warm-up: the first calls load the executable
    per_step = run(3)
    n = max(5, int(REPEAT_S / per_step))
    times = sorted(run(n) for _ in range(STEP_REPEATS))
    return {"step_s": times[len(times) // 2], "step_s_spread": [times[0], times[-1]], "steps": n, "loss": run.loss}


def ceilings(size: int | None = None) -> dict:
    """Matrix-product rates (TFLOP/s) at each precision on the device (size x size products, default 4096 on an
    accelerator, 1024 on a CPU), and each one's relative error against float64 on a 1024 x 1024 product (which
    says what the backend's default precision is)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    size = size or (1024 if jax.default_backend() == "cpu" else 4096)
    a, b = (jax.random.normal(k, (size, size), jnp.float32) for k in jax.random.split(jax.random.key(1)))
    products = {
        "float32": jax.jit(lambda x, y: jnp.matmul(x, y, precision=jax.lax.Precision.HIGHEST)),
        "default": jax.jit(lambda x, y: jnp.matmul(x, y)),
        "bfloat16": jax.jit(lambda x, y: jnp.matmul(x.astype(jnp.bfloat16), y.astype(jnp.bfloat16),
                                                    preferred_element_type=jnp.float32)),
    }
    small = np.random.default_rng(0).standard_normal((2, 1024, 1024))
    ref = small[0] @ small[1]
    out = {"device": jax.devices()[0].device_kind, "backend": jax.default_backend(), "jax": jax.__version__,
           "size": size}
    for name, f in products.items():
        f(a, b).block_until_ready()
        reps = 10
        t0 = time.perf_counter()
        for _ in range(reps):
            y = f(a, b)
        y.block_until_ready()
        tflops = 2 * size**3 * reps / (time.perf_counter() - t0) / 1e12
        # after the clock: another shape compiles anew (on 2026-11-26's H200 run that compilation was timed too)
        err = np.asarray(f(jnp.float32(small[0]), jnp.float32(small[1])), np.float64) - ref
        out[name] = {"tflops": tflops, "rel_error": float(np.linalg.norm(err) / np.linalg.norm(ref))}
    return out


def worker(config: str, sync: Path, results: Path) -> None:
    """One configuration: compile, say so, wait for its turn, time, write a line, say it is done."""
    name = config.replace(",", "-")
    record: dict = {"config": name}
    try:
        if config == "ceilings":
            (sync / f"ready-{name}").touch()
            _wait(sync / f"go-{name}")
            record.update(ceilings())
        else:
            tr, batch, precision = config.split(",")
            record.update(tr=int(tr), batch=int(batch), precision=precision)
            t0 = time.perf_counter()
            compiled, carry = compile_step(int(tr), int(batch), precision)
            record.update(compile_s=time.perf_counter() - t0, flops=_flops(compiled))
            (sync / f"ready-{name}").touch()
            _wait(sync / f"go-{name}")
            record.update(time_steps(compiled, carry))
            record["frames_per_s"] = record["batch"] / record["step_s"]
            if record["flops"]:
                record["tflops"] = record["flops"] / record["step_s"] / 1e12
    except Exception as e:  # noqa: BLE001 - the sweep records a configuration's failure and goes on
        record["error"] = f"{type(e).__name__}: {e}"[:500]
        (sync / f"ready-{name}").touch()
    with open(results, "a") as f:
        f.write(json.dumps(record) + "\n")
    (sync / f"done-{name}").touch()


def _wait(path: Path, timeout_s: float | None = None) -> bool:
    t0 = time.perf_counter()
    while not path.exists():
        if timeout_s is not None and time.perf_counter() - t0 > timeout_s:
            return False
        time.sleep(0.05)
    return True


class Session:
    """The sweep's processes, started at once, compiled side by side and timed one at a time (nothing else should
    use the device meanwhile)."""

    def __init__(self, out: Path, configs: list[str], *, log=None):
        self.out, self.sync = out, out / "sync"
        self.sync.mkdir(parents=True, exist_ok=True)
        self.results = out / "throughput.jsonl"
        env = dict(os.environ, XLA_PYTHON_CLIENT_PREALLOCATE="false")
        self.procs = {c.replace(",", "-"): subprocess.Popen(
            [sys.executable, __file__, "--one", c, "--sync", str(self.sync), "--results", str(self.results)],
            env=env, stdout=log, stderr=subprocess.STDOUT) for c in ["ceilings", *configs]}

    def run(self, *, compile_timeout_s: float, turn_timeout_s: float = 60.0) -> None:
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < compile_timeout_s and not all(
                (self.sync / f"ready-{n}").exists() or p.poll() is not None for n, p in self.procs.items()):
            time.sleep(0.5)
        for name, p in self.procs.items():
            if not (self.sync / f"ready-{name}").exists():
                p.kill()
                with open(self.results, "a") as f:
                    f.write(json.dumps({"config": name, "error": f"not compiled within {compile_timeout_s:.0f} s"})
                            + "\n")
                continue
            (self.sync / f"go-{name}").touch()
            if not _wait(self.sync / f"done-{name}", turn_timeout_s):
                p.kill()
                with open(self.results, "a") as f:
                    f.write(json.dumps({"config": name, "error": f"turn longer than {turn_timeout_s:.0f} s"}) + "\n")
            p.wait()


def network_flops(tr: int) -> float:
    """The network's training FLOPs per example: 3x its forward pass on a 32 x 64 frame (forward, and the
    backward's two products per layer). XLA's own count (`flops` in the results) leaves out what runs as a library
    call (cuDNN's convolutions on a GPU), so it is kept as a record, not reported as a rate."""
    import jaxsr
    from jaxsr.nn import flops_per_frame

    return 3.0 * flops_per_frame(jaxsr.ModelConfig(tr=tr))


def report(results: Path) -> str:
    """The sweep's lines as a markdown table: one row per configuration, ceilings first."""
    lines = [json.loads(s) for s in results.read_text().splitlines() if s.strip()]
    ceil = next((r for r in lines if r.get("config") == "ceilings" and "error" not in r), None)
    out = []
    if ceil:
        out += [f"Device: {ceil['device']} ({ceil['backend']}, JAX {ceil['jax']}). Matrix products of "
                f"{ceil['size']} x {ceil['size']}, measured in the same run:", "",
                "| precision | TFLOP/s | relative error against float64 |", "| --- | ---: | ---: |"]
        out += [f"| {p} | {ceil[p]['tflops']:.0f} | {ceil[p]['rel_error']:.1e} |"
                for p in ("float32", "default", "bfloat16") if p in ceil]
        out.append("")
    out += ["| TR | batch | precision | compile s | step ms | frames/s | network TFLOP/s | loss after timing |",
            "| ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: |"]
    rows = sorted((r for r in lines if r.get("config") != "ceilings"),
                  key=lambda r: (r.get("tr", 99), r.get("batch", 0), r.get("precision", "")))
    for r in rows:
        if "step_s" not in r:
            out.append(f"| {r.get('tr', '')} | {r.get('batch', '')} | {r.get('precision', r['config'])} | "
                       f"{r.get('error', 'no result')} | | | | |")
            continue
        out.append(f"| {r['tr']} | {r['batch']} | {r['precision']} | {r['compile_s']:.0f} | {1e3 * r['step_s']:.2f} | "
                   f"{r['frames_per_s']:.0f} | {network_flops(r['tr']) * r['frames_per_s'] / 1e12:.1f} | "
                   f"{r['loss']:.4f} |")
    return "\n".join(out) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sweep", type=Path, help="run the sweep, results into this folder")
    ap.add_argument("--report", type=Path, help="print the table of a throughput.jsonl")
    ap.add_argument("--tr", type=int, nargs="+", default=[0, 4])
    ap.add_argument("--batch", type=int, nargs="+", default=[4, 16, 64])
    ap.add_argument("--precision", nargs="+", default=["float32", "default", "bfloat16"])
    ap.add_argument("--compile-timeout", type=float, default=400.0)
    ap.add_argument("--one", help=argparse.SUPPRESS)  # "tr,batch,precision" or "ceilings": one worker
    ap.add_argument("--sync", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--results", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        worker(args.one, args.sync, args.results)
    elif args.report:
        print(report(args.report), end="")
    elif args.sweep:
        configs = [f"{t},{b},{p}" for t in args.tr for b in args.batch for p in args.precision]
        Session(args.sweep, configs).run(compile_timeout_s=args.compile_timeout)
        print(report(args.sweep / "throughput.jsonl"), end="")
    else:
        ap.error("one of --sweep or --report")


if __name__ == "__main__":
    main()
