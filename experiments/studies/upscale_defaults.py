"""When the ambient-only test helps the paper's TR4 on photon input, and what a recording says about it beforehand:
the evidence for `jaxsr upscale --ambient-alpha auto`, its default on histograms and time tags.

    python experiments/studies/ambient_rule.py                    # SNR 0.1-5, 1-100 photons, 8 frames per scene
    python experiments/studies/ambient_rule.py --snr 0.2 0.5 --photons 3 --frames 4

`jaxsr.sensor.ambient_only` (3 x 3 LR pixels, 9 frames, false-alarm rate `AUTO_AMBIENT_ALPHA`) empties sky that a
model shows as depth, and it drops returns whose summed photons do not stand out from the ambient light: at SNR
1.3 it costs TR4 nothing, at SNR 0.1 1-1.7 dB (experiments/results/photon_regimes_ambient.md). A default has to
tell the two apart from the recording alone. This measures, per test scene and regime (signal photons per LR
pixel, frame SNR), the PSNR of TR4 with the test minus without it (the same noise; mean over the scored frames,
with a 95 % block-bootstrap interval), beside the frame SNR `jaxsr upscale` estimates from the recording
(`jaxsr.inference.head_frame_snr`: `frame_snr` of the first HEAD_FRAMES frames, drawn at the same regime). Then,
for thresholds on that estimate, the rule "test where the estimate is at least the threshold" is scored over all
scene-regimes: mean and worst change against never testing. What the test is for, sky and dark surfaces left
empty, PSNR on these scenes shows only in part (Scene 2's sky), so the rule is chosen not to cost PSNR: the
library's threshold (`AUTO_AMBIENT_MIN_SNR`) is the lowest here at which the rule's mean change over the grid is
not negative. Each row's loss beyond `TOLERANCE_DB` is counted beside it.

Scenes, frames, calibration, noise and scoring are the photon benchmark's (experiments/studies/photon_regimes.py,
its `evaluate`; scene's own sky included in the PSNR, no added no-return regions: what the test gains there is
in that benchmark's no-return tables). Writes experiments/results/ambient_rule.md (or --out) and a .json beside it.
"""

from __future__ import annotations

import argparse
import functools
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from photon_regimes import SEQUENCE_FRAMES, TEST_SCENES, _calibration, evaluate, frame_interval  # beside this script

import jaxsr
from jaxsr.config import SensorConfig
from jaxsr.eval.reports import header, markdown_table, write_atomic
from jaxsr.eval.scoring import SCENE_LABELS
from jaxsr.inference import AUTO_AMBIENT_ALPHA, AUTO_AMBIENT_MIN_SNR, head_frame_snr
from jaxsr.inference.recording import HEAD_FRAMES
from jaxsr.sensor import calibrated_rates, sample_poisson

SNRS = (0.1, 0.2, 0.3, 0.5, 0.8, 1.3, 5.0)
PHOTONS = (1.0, 3.0, 14.0, 100.0)
THRESHOLDS = (0.0, 0.2, 0.3, 0.4, 0.5, 0.7, 0.8, 1.0, 1.5, float("inf"))  # 0: always test; inf: never
TOLERANCE_DB = 0.3  # the loss to the test a scene-regime may show where the rule tests (the tolerance)
PLAIN, TESTED = "TR4", "TR4+ambient"


@functools.partial(jax.jit, static_argnames=("sensor",))
def _head_counts(key, depth, intensity, alpha, beta, sensor):
    return sample_poisson(key, calibrated_rates(depth, intensity, alpha, beta, sensor), method="fast")


def estimated_snr(seq, photons: float, snr: float, *, key, sensor=SensorConfig()) -> float:
    """`head_frame_snr` of a scene's first HEAD_FRAMES frames drawn at one regime (calibrated over the whole
    sequence, as the benchmark's regimes are): what `jaxsr upscale` would estimate from that recording."""
    alpha, beta = _calibration(jnp.asarray(seq.depth), jnp.asarray(seq.intensity), jnp.float32(snr),
                               jnp.float32(photons), sensor)
    counts = _head_counts(key, jnp.asarray(seq.depth[:HEAD_FRAMES]), jnp.asarray(seq.intensity[:HEAD_FRAMES]),
                          alpha, beta, sensor)
    return head_frame_snr(np.asarray(counts), sensor.bins)


def rows_of(results, estimates) -> list[dict]:
    """One row per scene and regime: photons, snr, scene, estimate, change (dB, TESTED - PLAIN) with its interval."""
    rows = []
    for k, regime in enumerate(results["regimes"]):
        plain, tested = regime["scores"][PLAIN]["psnr"], regime["scores"][TESTED]["psnr"]
        for i, scene in enumerate(results["scenes"]):
            mean, lo, hi = frame_interval(tested[i], plain[i], results["spacing"], seed=k)
            rows.append({"photons": regime["photons"], "snr": regime["snr"], "scene": scene,
                         "estimate": estimates[k][i], "change": float(mean), "interval": (float(lo), float(hi))})
    return rows


def rule_scores(rows, thresholds=THRESHOLDS) -> list[dict]:
    """For each threshold t, the rule "test where the estimate >= t" against never testing, over all rows: mean
    and worst change (dB), rows tested, rows that lose more than TOLERANCE_DB. An estimate of NaN (no return seen)
    is never tested."""
    change = np.array([r["change"] for r in rows])
    est = np.array([r["estimate"] for r in rows])
    out = []
    for t in thresholds:
        on = est >= t  # NaN compares False
        applied = np.where(on, change, 0.0)
        out.append({"threshold": t, "tested": int(on.sum()), "mean": float(applied.mean()),
                    "worst": float(applied.min()), "losing": int((applied < -TOLERANCE_DB).sum())})
    return out


def chosen_threshold(scores) -> float:
    """The lowest threshold at which the rule's mean change is not negative (inf, never test, if none)."""
    return min((s["threshold"] for s in scores if s["mean"] >= 0.0), default=float("inf"))


def _finite(x):
    """`x` with every non-finite float as None (strict JSON has no NaN or Infinity)."""
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return None if isinstance(x, float) and not np.isfinite(x) else x


def report(rows, scores, *, started, frames: int, seed: int) -> str:
    chosen = chosen_threshold(scores)
    agree = "equals it" if chosen == AUTO_AMBIENT_MIN_SNR else f"differs from it: the library has {AUTO_AMBIENT_MIN_SNR:g}"
    table = markdown_table(
        ["photons", "SNR", "scene", "estimated SNR", "test - none (dB) [95 %]", "tested at the library's rule"],
        [[f"{r['photons']:g}", f"{r['snr']:g}", SCENE_LABELS[r["scene"]], f"{r['estimate']:.3g}",
          f"{r['change']:+.2f} [{r['interval'][0]:+.2f}, {r['interval'][1]:+.2f}]",
          "yes" if r["estimate"] >= AUTO_AMBIENT_MIN_SNR else "no"] for r in rows])
    rules = markdown_table(
        ["test where the estimate >=", "scene-regimes tested", "mean change (dB)", "worst change (dB)",
         f"losing more than {TOLERANCE_DB:g} dB"],
        [["never" if s["threshold"] == float("inf") else ("always" if s["threshold"] == 0 else f"{s['threshold']:g}"),
          f"{s['tested']} / {len(rows)}", f"{s['mean']:+.4f}", f"{s['worst']:+.2f}", str(s["losing"])]
         for s in scores])
    return (header("When the ambient-only test helps TR4: the rule of --ambient-alpha auto", started)
            + "The paper's TR4 with and "
            f"without `jaxsr.sensor.ambient_only` (alpha {AUTO_AMBIENT_ALPHA:g}) on the photon benchmark's test "
            f"scenes, {frames} frames each spread over {SEQUENCE_FRAMES}, noise seed {seed} (the same noise for both); "
            f"estimated SNR: `jaxsr.inference.head_frame_snr` of each scene's first {HEAD_FRAMES} frames drawn at "
            "the regime, what `jaxsr upscale` reads before choosing. How it is made: the docstring of the script.\n\n"
            "## The rule, by threshold\n\n" + rules
            + "\n\nThe lowest threshold at which the rule costs no PSNR on average (mean change >= 0): "
            f"**{'never' if chosen == float('inf') else f'{chosen:g}'}**; the library's `AUTO_AMBIENT_MIN_SNR` "
            f"{agree}.\n\n## Per scene and regime\n\n" + table + "\n")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=8, help="frames scored per test scene (default 8)")
    parser.add_argument("--photons", type=float, nargs="+", default=list(PHOTONS),
                        help="signal photons per LR pixel (default 1 3 14 100)")
    parser.add_argument("--snr", type=float, nargs="+", default=list(SNRS), help="frame SNRs (default 0.1 .. 5)")
    parser.add_argument("--seed", type=int, default=0, help="noise seed")
    parser.add_argument("--out", default="experiments/results/ambient_rule.md", help="the results file (a .json beside it)")
    args = parser.parse_args(argv)
    started = time.time()
    tr4 = jaxsr.load_model("paper-tr4")
    seqs = jaxsr.scenes.test_sequences(n_frames=SEQUENCE_FRAMES, names=TEST_SCENES)
    results = evaluate({PLAIN: tr4, TESTED: tr4}, seqs, frames=args.frames, photons=args.photons, snrs=args.snr,
                       seed=args.seed, paper=False, no_return=False, ambient={TESTED: AUTO_AMBIENT_ALPHA})
    # the estimates, regime by regime in evaluate's order, with keys of their own
    estimates = [[estimated_snr(seq, r["photons"], r["snr"], key=jax.random.fold_in(jax.random.key(args.seed + 2),
                                                                                      100 * k + i))
                  for i, seq in enumerate(seqs.values())] for k, r in enumerate(results["regimes"])]
    rows = rows_of(results, estimates)
    scores = rule_scores(rows)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, report(rows, scores, started=started, frames=args.frames, seed=args.seed))
    raw = {"rows": rows, "rules": scores, "chosen": chosen_threshold(scores), "frames": args.frames,
           "seed": args.seed, "alpha": AUTO_AMBIENT_ALPHA, "library_threshold": AUTO_AMBIENT_MIN_SNR}
    write_atomic(out.with_suffix(".json"), json.dumps(_finite(raw), indent=1) + "\n")
    print(f"wrote {out} and {out.with_suffix('.json')}")


if __name__ == "__main__":
    main()
