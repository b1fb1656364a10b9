"""Inference's temporal form and precision: the bundled windowed weights run in the sequence form, and bfloat16
against float32 convolutions, scored on the test sequences and timed on this machine.

    python experiments/studies/inference_forms.py [--trs 0 1 2 3 4] [--bf16-trs 0 4] [--rounds 3] [--note TEXT]

Accuracy: each bundled depth model tr0..tr4 on the three test scenes (`harness.scoring.test_clips(100,
spread=True)`: all 500 frames of each scene simulated at its SNR, noise seed 0, 100 frames spread over them
scored, as experiments/sweep_tr.py scores), PSNR (dB) of the clipped output against the normalised ground truth.
Window form: `super_resolve_frames` of the scored frames' edge-replicated windows. Sequence form: `super_resolve(
model, lr, form="sequence")` over the whole 500 frames (chunks of `DEFAULT_SEQUENCE_CHUNK` outputs), the scored
frames taken from it. Edge frames: the first and last R = 3 + TR frames of each scene, where the two forms pad
the sequence differently (R copies of the end frame against TR), scored on their own. Precision: the same with
precision="bfloat16" (bfloat16 operands, float32 sums) against "float32" for the TRs of --bf16-trs.

Speed: frames/s end to end from photon histograms (`super_resolve_histograms`: centre of mass and network) on the
first frames of Scene 1, --rounds rounds interleaved over every configuration after one warm-up call each:
window form (default batch: one frame per JAX CPU device) and sequence form (chunks of 32 outputs, and of 128
outputs on 128 frames), float32 and bfloat16. Against the machine's matrix-product ceilings: the GFLOP/s of a
2048 x 2048 float32 product and of the same in bfloat16 with float32 accumulation (`preferred_element_type`),
timed in the same rounds; the network's GFLOP/s from `flops_per_frame` (the sequence form's chunks compute 2R
frames more than they return, not counted).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxsr
from jaxsr.inference import DEFAULT_SEQUENCE_CHUNK, super_resolve, super_resolve_histograms
from jaxsr.nn import flops_per_frame, sequence_radius
from jaxsr.runtime import cpu_bfloat16_features

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import header, markdown_table, write_atomic  # noqa: E402
from harness.scoring import N_DEVICES, frame_scores, super_resolve_frames, test_clips, TEST_SCENES  # noqa: E402

PRECISIONS = ("float32", "bfloat16")
MATMUL = 2048


def _commit() -> str:
    """The git commit the run's code is at, and whether the library or this script differ from it."""
    import subprocess

    def git(*args):
        return subprocess.run(["git", *args], capture_output=True, text=True, check=False).stdout.strip()

    head = git("rev-parse", "--short", "HEAD") or "unknown"
    dirty = git("status", "--porcelain", "--", "jaxsr", "experiments/studies/inference_forms.py")
    return f"git {head}" + (" with uncommitted changes to jaxsr/ or this script" if dirty else "")


def _psnr(sr, gt) -> float:
    return float(frame_scores(sr, gt)[0].mean())


def accuracy(tr: int, clips: dict, precisions) -> dict:
    """{(form, precision): {"scored": mean PSNR over the scenes' scored frames, "edges": mean PSNR of the edge
    frames, "scenes": [per-scene scored PSNR]}} and the largest |bfloat16 - float32| per form."""
    model = jaxsr.load_model(f"tr{tr}")
    r = sequence_radius(model.config)
    out, diff = {}, {}
    for precision in precisions:
        per = {"window": ([], []), "sequence": ([], [])}
        for clip in clips.values():
            n = len(clip.lr)
            edges = np.r_[0:r, n - r:n]
            win_scored = super_resolve_frames(model, clip.lr, clip.scored, precision=precision, form="window")
            win_edges = super_resolve_frames(model, clip.lr, edges, precision=precision, form="window")
            seq = super_resolve(model, clip.lr, precision=precision, form="sequence")
            for form, scored, edge in (("window", win_scored, win_edges),
                                       ("sequence", seq[clip.scored], seq[edges])):
                per[form][0].append(_psnr(scored, clip.gt[clip.scored]))
                per[form][1].append(_psnr(edge, clip.gt[edges]))
                key = (form, clip.name)
                if precision == "float32":
                    diff[key] = scored
                else:
                    diff[key] = float(np.abs(scored - diff[key]).max())
        for form, (scored, edges) in per.items():
            out[form, precision] = {"scored": float(np.mean(scored)), "edges": float(np.mean(edges)),
                                    "scenes": scored}
        print(f"TR{tr} {precision}: " + ", ".join(f"{f} {v['scored']:.3f} (edges {v['edges']:.3f})"
                                                 for (f, p), v in out.items() if p == precision), flush=True)
    maxdiff = {form: max(v for (f, _), v in diff.items() if f == form and isinstance(v, float))
               for form in ("window", "sequence")} if "bfloat16" in precisions else {}
    return {"psnr": out, "bf16_max_abs": maxdiff}


def matmul_runners():
    a = jax.random.normal(jax.random.key(3), (MATMUL, MATMUL), jnp.float32)
    b = a.astype(jnp.bfloat16)
    f32 = jax.jit(lambda x: jnp.matmul(x, x, precision="highest"))
    bf16 = jax.jit(lambda x: jax.lax.dot(x, x, preferred_element_type=jnp.float32))
    return {"matmul float32": lambda: f32(a).block_until_ready(),
            "matmul bfloat16 (float32 sums)": lambda: bf16(b).block_until_ready()}


def speed(trs, bf16_trs, counts, rounds):
    """{config: [frames/s (or matmul GFLOP/s) of each round]}, {config: warm-up s}, {config: (tr, frames, form)},
    [load average after each round]."""
    runners, info = {}, {}
    for tr in trs:
        model = jaxsr.load_model(f"tr{tr}")
        for precision in (PRECISIONS if tr in bf16_trs else ("float32",)):
            for form, chunk, n in (("window", None, 32), ("sequence", DEFAULT_SEQUENCE_CHUNK, 32),
                                   ("sequence", 128, 128)):
                if chunk == 128 and tr not in bf16_trs:
                    continue
                c = counts[:n]
                label = f"TR{tr} {form}" + (f" chunk {chunk}" if chunk else "") + f" {precision}"
                runners[label] = (lambda model=model, c=c, form=form, chunk=chunk, precision=precision:
                                  super_resolve_histograms(model, c, batch_size=chunk, precision=precision,
                                                           form=form))
                info[label] = (tr, n, form)
    for label, fn in matmul_runners().items():
        runners[label] = fn
        info[label] = (None, None, None)
    warm = {}
    for label, fn in runners.items():
        t0 = time.perf_counter()
        fn()
        warm[label] = time.perf_counter() - t0
        print(f"{label}: warm-up {warm[label]:.1f} s", flush=True)
    rates, loads = {label: [] for label in runners}, []
    for _ in range(rounds):
        for label, fn in runners.items():
            reps = 5 if info[label][0] is None else 1
            t0 = time.perf_counter()
            for _ in range(reps):
                fn()
            dt = (time.perf_counter() - t0) / reps
            tr, n, _ = info[label]
            rate = 2 * MATMUL**3 / dt / 1e9 if tr is None else n / dt
            rates[label].append(rate)
        loads.append(os.getloadavg()[0])
        print(f"round: {time.strftime('%H:%M:%S')}, load {loads[-1]:.1f}", flush=True)
    return rates, warm, info, loads


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trs", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--bf16-trs", type=int, nargs="+", default=[0, 4], help="TRs also run in bfloat16")
    parser.add_argument("--scored", type=int, default=100, help="frames scored per scene, spread over its 500")
    parser.add_argument("--rounds", type=int, default=6, help="timed rounds, interleaved over configurations")
    parser.add_argument("--skip-accuracy", action="store_true", help="speed only (a quick look)")
    parser.add_argument("--note", default="", help="a sentence on the machine's load, written into the results")
    parser.add_argument("--out", default="experiments/results/inference_forms.md")
    args = parser.parse_args()
    started = time.time()
    load_start = os.getloadavg()
    clips = test_clips(args.scored, spread=True)

    acc = {}
    if not args.skip_accuracy:
        for tr in args.trs:
            acc[tr] = accuracy(tr, clips, PRECISIONS if tr in args.bf16_trs else ("float32",))
    rates, warm, info, loads = speed(args.trs, args.bf16_trs, clips["scene1_street"].counts, args.rounds)
    best = {label: max(r) for label, r in rates.items()}
    median = {label: float(np.median(r)) for label, r in rates.items()}

    text = header("Inference: the windowed weights in the sequence form, and bfloat16 convolutions", started)
    text = text.rstrip("\n") + "\n"  # the lines below continue the header's list
    text += (f"- code: {_commit()}\n"
             f"- load average at the start (1, 5, 15 min): {', '.join(f'{v:.1f}' for v in load_start)}; after each "
             f"timed round (1 min): {', '.join(f'{v:.1f}' for v in loads)}\n"
             f"- CPU bfloat16 features (/proc/cpuinfo, `jaxsr.runtime.cpu_bfloat16_features`): "
             f"{', '.join(cpu_bfloat16_features()) or 'none'}; JAX CPU devices: {N_DEVICES}\n")
    if args.note:
        text += f"- note: {args.note}\n"
    text += "\n" + __doc__.split("\n\n", 2)[2].strip() + "\n\n"
    if acc:
        text += ("## Window against sequence form (float32)\n\nPSNR in dB, mean over the three scenes' scored "
                 "frames (per scene in the last columns: window / sequence); edges: the first and last R frames of "
                 "each scene.\n\n")
        rows = []
        for tr, a in acc.items():
            w, s = a["psnr"]["window", "float32"], a["psnr"]["sequence", "float32"]
            rows.append([f"TR{tr}", f"{w['scored']:.3f}", f"{s['scored']:.3f}", f"{s['scored'] - w['scored']:+.3f}",
                         f"{w['edges']:.3f}", f"{s['edges']:.3f}", f"{s['edges'] - w['edges']:+.3f}",
                         *(f"{a_:.2f} / {b_:.2f}" for a_, b_ in zip(w["scenes"], s["scenes"]))])
        text += markdown_table(["model", "window", "sequence", "delta", "edges window", "edges sequence",
                                "edges delta", *(f"{n}" for n in TEST_SCENES)], rows)
        text += ("\n## bfloat16 against float32\n\nPSNR in dB as above; max abs: the largest |bfloat16 - float32| "
                 "of the network's normalised output over the scored frames.\n\n")
        rows = []
        for tr, a in acc.items():
            if ("window", "bfloat16") not in a["psnr"]:
                continue
            for form in ("window", "sequence"):
                f, b = a["psnr"][form, "float32"], a["psnr"][form, "bfloat16"]
                rows.append([f"TR{tr}", form, f"{f['scored']:.3f}", f"{b['scored']:.3f}",
                             f"{b['scored'] - f['scored']:+.3f}", f"{b['edges'] - f['edges']:+.3f}",
                             f"{a['bf16_max_abs'][form]:.1e}"])
        text += markdown_table(["model", "form", "float32", "bfloat16", "delta", "edges delta", "max abs"], rows)
    text += "\n## Speed\n\n"
    peak32 = best["matmul float32"]
    peak16 = best["matmul bfloat16 (float32 sums)"]
    text += (f"Matrix-product ceilings ({MATMUL} x {MATMUL}, best of the rounds): float32 {peak32:.0f} GFLOP/s, "
             f"bfloat16 with float32 sums {peak16:.0f} GFLOP/s ({peak16 / peak32:.2f}x); medians "
             f"{median['matmul float32']:.0f} and {median['matmul bfloat16 (float32 sums)']:.0f}.\n\n"
             f"frames/s: best and median of the {args.rounds} rounds; bfloat16 / float32: the median over the rounds "
             "of each round's ratio (both ran within seconds of each other in a round, so its load mostly cancels); "
             "GFLOP/s "
             "and the share of the matrix-product ceiling of its precision from the best round.\n\n")
    rows = []
    for label, rate in best.items():
        tr, n, form = info[label]
        if tr is None:
            continue
        cfg = jaxsr.ModelConfig(tr=tr, temporal=form)
        gflops = rate * flops_per_frame(cfg) / 1e9
        peak = peak16 if label.endswith("bfloat16") else peak32
        pair = label.replace("bfloat16", "float32")
        ratio = ""
        if label.endswith("bfloat16") and pair in rates:
            ratio = f"{np.median(np.asarray(rates[label]) / np.asarray(rates[pair])):.2f}"
        rows.append([label, str(n), f"{rate:.1f}", f"{median[label]:.1f}", ratio, f"{gflops:.0f}",
                     f"{100 * gflops / peak:.0f} %", f"{warm[label]:.1f}"])
    text += markdown_table(["configuration", "frames", "frames/s best", "median", "bfloat16 / float32",
                            "network GFLOP/s", "of its matmul ceiling", "warm-up s"], rows)
    write_atomic(args.out, text)
    json_out = os.path.splitext(args.out)[0] + ".json"
    write_atomic(json_out, json.dumps({
        "accuracy": {str(tr): {f"{f} {p}": v for (f, p), v in a["psnr"].items()} | {"bf16_max_abs": a["bf16_max_abs"]}
                     for tr, a in acc.items()},
        "speed_rounds": rates, "round_loads": loads, "warm_up_s": warm}, indent=1) + "\n")
    print(text)


if __name__ == "__main__":
    main()
