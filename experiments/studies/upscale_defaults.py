"""The defaults of `jaxsr upscale` on photon histograms and time tags, measured: which model runs and whether the
ambient-only test empties what it outputs, both chosen from what the recording says about itself before the work.

    python experiments/studies/upscale_defaults.py                 # 1-100 photons, SNR 0.1-5, 8 frames per scene
    python experiments/studies/upscale_defaults.py --snr 0.2 1.3 --photons 3 --frames 2   # a quick look

What a recording says: `jaxsr.app.photon_levels` of its first HEAD_FRAMES frames, its frame SNR
(`jaxsr.sensor.frame_snr`) and its signal photons per LR pixel with a return and frame
(`jaxsr.sensor.signal_photons`), here drawn at each regime as `jaxsr upscale` would read them.

The two choices:
- The ambient-only test (`jaxsr.sensor.ambient_only`, 3 x 3 LR pixels, 9 frames, false-alarm rate
  `AUTO_AMBIENT_ALPHA`) empties sky that a model shows as depth, and drops returns whose summed photons do not
  stand out from the ambient light. Rule: test where the estimated SNR is at least t. What the test is for, sky and
  dark surfaces left empty, PSNR on these scenes shows only in part (Scene 2's sky), so t is chosen not to cost
  PSNR: the lowest t here at which the rule's mean change (TR4 with the test where it applies, against TR4 alone)
  is not negative. The library's `AUTO_AMBIENT_MIN_SNR` is compared with it. Then the library's rule, which also
  tests where the estimated signal photons times the SNR (signal^2 / ambient photons per pixel and frame) reach c:
  the SNR alone leaves the test off at many photons and low SNR, where a return stands out all the same; c over
  a grid, the library's `AUTO_AMBIENT_MIN_SIGNAL_SNR` among them. The report names the lowest c with the highest
  mean change among those that lose no more scene-regimes than the SNR alone, and compares the library's.
- The model: the paper's TR4 reads the centre of mass only and falls below bicubic at 1 photon per pixel; the
  bundled tr4-photons also reads the photons behind it. Rule: tr4-photons where the estimated signal photons are
  below P, the paper's TR4 from P up, each with the test by the library's rule or (for tr4-photons) without it. The
  report names the rule with the highest mean PSNR over the grid and the best that loses no scene-regime more than
  `TOLERANCE_DB`. It informs, and does not set, `jaxsr upscale`'s default for photons (tr4-ambient since
  2026-11-27, chosen on the simulated regimes and the real recordings: docs/results/photon-regimes.md).

Per scene and regime: the PSNR of TR4, TR4 + test, tr4-photons and tr4-photons + test on the same noise (mean over
the scored frames), and the estimates. Scenes, frames, calibration, noise and scoring are the photon benchmark's
(experiments/studies/photon_regimes.py, its `evaluate`: the scenes' own sky is in the PSNR, no added no-return
regions; what the test does inside those regions is in that benchmark's no-return tables). Writes
experiments/results/upscale_defaults.md (or --out) and a .json beside it.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _photon_benchmark import calibration, evaluate  # beside this script

import jaxsr
from jaxsr.config import Sensor
from jaxsr.app import (AUTO_AMBIENT_ALPHA, AUTO_AMBIENT_MIN_SIGNAL_SNR, AUTO_AMBIENT_MIN_SNR, FEW_PHOTONS, HEAD_FRAMES,
                       auto_ambient_alpha, photon_levels)
from jaxsr.sensor import calibrated_rates, sample_poisson

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import header, markdown_table, write_atomic  # noqa: E402
from harness.scoring import SCENE_LABELS, SEQUENCE_FRAMES, TEST_SCENES  # noqa: E402

SNRS = (0.1, 0.2, 0.3, 0.5, 0.8, 1.3, 5.0)
PHOTONS = (1.0, 3.0, 14.0, 100.0)
SNR_THRESHOLDS = (0.0, 0.2, 0.3, 0.4, 0.5, 0.7, 0.8, 1.0, 1.5, float("inf"))  # 0: always test; inf: never
# c of "the test where the SNR >= AUTO_AMBIENT_MIN_SNR or signal x SNR >= c" (inf: the SNR alone)
SIGNAL_SNR_THRESHOLDS = tuple(sorted({1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 20.0, AUTO_AMBIENT_MIN_SIGNAL_SNR,
                                       float("inf")}))
PHOTON_THRESHOLDS = (0.0, 2.0, 3.0, 4.0, 6.0, 8.0)  # 0: never tr4-photons
TOLERANCE_DB = 0.3  # a row losing more than this to the old default is counted (the tolerance for switching a default)
TR4, TR4_TEST, PHOTON, PHOTON_TEST = "TR4", "TR4+test", "TR4-photons", "TR4-photons+test"
METHODS = (TR4, TR4_TEST, PHOTON, PHOTON_TEST)


@functools.partial(jax.jit, static_argnames=("sensor",))
def _head_counts(key, depth, intensity, alpha, beta, sensor):
    return sample_poisson(key, calibrated_rates(depth, intensity, alpha, beta, sensor), method="fast")


def estimated_levels(seq, photons: float, snr: float, *, key, sensor=Sensor()) -> tuple[float, float]:
    """`photon_levels` (SNR, signal photons) of a scene's first HEAD_FRAMES frames drawn at one regime (calibrated
    over the whole sequence, as the benchmark's regimes are): what `jaxsr upscale` would read from it."""
    alpha, beta = calibration(jnp.asarray(seq.depth), jnp.asarray(seq.intensity), jnp.float32(snr),
                               jnp.float32(photons), sensor)
    counts = _head_counts(key, jnp.asarray(seq.depth[:HEAD_FRAMES]), jnp.asarray(seq.intensity[:HEAD_FRAMES]),
                          alpha, beta, sensor)
    return tuple(photon_levels(np.asarray(counts), sensor.bins))


def rows_of(results, estimates) -> list[dict]:
    """One row per scene and regime: photons, snr, scene, the estimates (snr_est, photons_est) and each method's
    mean PSNR over the scored frames."""
    rows = []
    for k, regime in enumerate(results["regimes"]):
        for i, scene in enumerate(results["scenes"]):
            snr_est, photons_est = estimates[k][i]
            rows.append({"photons": regime["photons"], "snr": regime["snr"], "scene": scene, "snr_est": snr_est,
                         "photons_est": photons_est,
                         "psnr": {m: float(np.mean(regime["scores"][m]["psnr"][i])) for m in METHODS}})
    return rows


def ambient_rule(t: float, plain: str = TR4, tested: str = TR4_TEST):
    """The ambient-only test's rule: the model with the test where the estimated SNR >= t (NaN: never)."""
    return combined_rule(float("inf"), plain, tested, t=t)


def combined_rule(c: float, plain: str = TR4, tested: str = TR4_TEST, t: float = AUTO_AMBIENT_MIN_SNR):
    """The test where the estimated SNR >= t or the estimated signal photons x SNR >= c (`auto_ambient_alpha`
    with those thresholds)."""
    def pick(row):
        alpha = auto_ambient_alpha(row["snr_est"], row["photons_est"], min_snr=t, min_signal_snr=c)
        return plain if alpha is None else tested
    return pick


def library_rule(plain: str = TR4, tested: str = TR4_TEST):
    """What `jaxsr upscale --ambient-alpha auto` picks from the estimates (`auto_ambient_alpha`'s thresholds)."""
    return combined_rule(AUTO_AMBIENT_MIN_SIGNAL_SNR, plain, tested)


def model_rule(p: float, *, test_photon_model: bool):
    """tr4-photons where the estimated signal photons are below p (with the test by the library's rule, or never),
    else the paper's TR4 with the test by the library's rule."""
    def pick(row):
        tested = library_rule()(row) == TR4_TEST
        if row["photons_est"] < p:
            return PHOTON_TEST if tested and test_photon_model else PHOTON
        return TR4_TEST if tested else TR4
    return pick


def policy_score(rows, pick, base: str = TR4) -> dict:
    """A rule against `base` (default the old default, TR4 alone) over all rows: mean and worst change (dB), rows
    that lose more than TOLERANCE_DB, and the methods it picked."""
    change = np.array([r["psnr"][pick(r)] - r["psnr"][base] for r in rows])
    picked = [pick(r) for r in rows]
    return {"mean": float(change.mean()), "worst": float(change.min()), "losing": int((change < -TOLERANCE_DB).sum()),
            "picked": {m: picked.count(m) for m in METHODS if m in picked}}


def ambient_rules(rows, thresholds=SNR_THRESHOLDS) -> list[dict]:
    return [{"threshold": t, **policy_score(rows, ambient_rule(t))} for t in thresholds]


def combined_rules(rows, thresholds=SIGNAL_SNR_THRESHOLDS) -> list[dict]:
    return [{"threshold": c, **policy_score(rows, combined_rule(c))} for c in thresholds]


def model_rules(rows, thresholds=PHOTON_THRESHOLDS) -> list[dict]:
    return [{"threshold": p, "test_photon_model": tp, **policy_score(rows, model_rule(p, test_photon_model=tp))}
            for p in thresholds for tp in ((False,) if p == 0 else (False, True))]


def photon_model_tested(rows) -> dict:
    """tr4-photons with the test by the library's rule, against tr4-photons alone."""
    return policy_score(rows, library_rule(PHOTON, PHOTON_TEST), base=PHOTON)


def raw_results(rows, tests, models, *, frames: int, seed: int) -> dict:
    """What the .json beside the report holds (non-finite numbers as None)."""
    combined = combined_rules(rows)
    return _finite({"rows": rows, "ambient_rules": tests, "combined_rules": combined,
                    "chosen_signal_snr": chosen_signal_snr_threshold(
                        combined, policy_score(rows, ambient_rule(AUTO_AMBIENT_MIN_SNR))),
                    "library_rule": policy_score(rows, library_rule()), "model_rules": models,
                    "chosen_snr": chosen_snr_threshold(tests), "photon_model_tested": photon_model_tested(rows),
                    "best_model_rule": chosen_model_rule(models), "safe_model_rule": chosen_model_rule(models, safe=True),
                    "frames": frames, "seed": seed, "alpha": AUTO_AMBIENT_ALPHA,
                    "library": {"snr": AUTO_AMBIENT_MIN_SNR, "signal_snr": AUTO_AMBIENT_MIN_SIGNAL_SNR,
                                "few_photons": FEW_PHOTONS}})


def chosen_snr_threshold(scores) -> float:
    """The lowest threshold at which the test's rule costs no PSNR on average (inf, never test, if none)."""
    return min((s["threshold"] for s in scores if s["mean"] >= 0.0), default=float("inf"))


def chosen_signal_snr_threshold(scores, snr_only: dict) -> float:
    """The lowest c with the highest mean change among the combined rules that lose no more rows than the SNR
    alone (`snr_only`, its score; inf, the SNR alone, if none beats it)."""
    fair = [s for s in scores if s["losing"] <= snr_only["losing"]]
    best = max((s["mean"] for s in fair), default=snr_only["mean"])
    return min((s["threshold"] for s in fair if s["mean"] == best), default=float("inf"))


def chosen_model_rule(scores, *, safe: bool = False) -> dict:
    """The model rule with the highest mean change (the first of equals: the lower threshold, untested); safe:
    among those that lose no row more than TOLERANCE_DB."""
    return max((s for s in scores if s["losing"] == 0 or not safe), key=lambda s: s["mean"])


def _finite(x):
    """`x` with every non-finite float as None (strict JSON has no NaN or Infinity)."""
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return None if isinstance(x, float) and not np.isfinite(x) else x


def _threshold(t) -> str:
    return "never" if t == float("inf") else ("always" if t == 0 else f"{t:g}")


def _model_rule_text(s) -> str:
    if s["threshold"] == 0:
        return "**never** tr4-photons"
    return (f"tr4-photons below **{s['threshold']:g}** estimated photons, "
            f"{'tested' if s['test_photon_model'] else 'untested'} ({s['mean']:+.2f} dB)")


def _picked(s) -> str:
    return ", ".join(f"{m} {n}" for m, n in s["picked"].items())


def report(rows, tests, models, *, started, frames: int, seed: int) -> str:
    snr_t, model, safe = chosen_snr_threshold(tests), chosen_model_rule(models), chosen_model_rule(models, safe=True)
    photon = photon_model_tested(rows)
    snr_agree = ("equals it" if snr_t == AUTO_AMBIENT_MIN_SNR
                 else f"differs from it: the library has {AUTO_AMBIENT_MIN_SNR:g}")
    cols = ["mean change (dB)", "worst change (dB)", f"rows losing > {TOLERANCE_DB:g} dB", "picked"]
    test_table = markdown_table(
        ["TR4, the test where the estimated SNR >="] + cols,
        [[_threshold(s["threshold"]), f"{s['mean']:+.4f}", f"{s['worst']:+.2f}", str(s["losing"]), _picked(s)]
         for s in tests])
    combined = combined_rules(rows)
    lib, snr_only = policy_score(rows, library_rule()), policy_score(rows, ambient_rule(AUTO_AMBIENT_MIN_SNR))
    c = chosen_signal_snr_threshold(combined, snr_only)
    c_agree = ("equals it" if c == AUTO_AMBIENT_MIN_SIGNAL_SNR
               else f"differs from it: the library has {AUTO_AMBIENT_MIN_SIGNAL_SNR:g}")
    combined_table = markdown_table(
        [f"TR4, the test where the estimated SNR >= {AUTO_AMBIENT_MIN_SNR:g} or signal x SNR >="] + cols,
        [[_threshold(s["threshold"]), f"{s['mean']:+.4f}", f"{s['worst']:+.2f}", str(s["losing"]), _picked(s)]
         for s in combined])
    model_table = markdown_table(
        ["tr4-photons where the estimated photons <", "tr4-photons tested"] + cols,
        [["never" if s["threshold"] == 0 else f"{s['threshold']:g}", "yes" if s["test_photon_model"] else "no",
          f"{s['mean']:+.3f}", f"{s['worst']:+.2f}", str(s["losing"]), _picked(s)] for s in models])
    detail = markdown_table(
        ["photons", "SNR", "scene", "estimated SNR", "estimated photons"] + [f"{m} (dB)" for m in METHODS],
        [[f"{r['photons']:g}", f"{r['snr']:g}", SCENE_LABELS[r["scene"]], f"{r['snr_est']:.3g}",
          f"{r['photons_est']:.3g}"] + [f"{r['psnr'][m]:.2f}" for m in METHODS] for r in rows])
    return (header("The defaults of jaxsr upscale on photon input", started)
            + f"The test scenes of the photon benchmark, {frames} frames each spread over {SEQUENCE_FRAMES}, noise "
            f"seed {seed} (the same noise for every method); the test: `jaxsr.sensor.ambient_only` at alpha "
            f"{AUTO_AMBIENT_ALPHA:g}; estimates: `jaxsr.app.photon_levels` of each scene's first "
            f"{HEAD_FRAMES} frames drawn at the regime. Changes are PSNR against the paper's TR4 alone (the old "
            f"default), over the {len(rows)} scene-regimes (mean of each scene's frames). How it is made: the "
            "docstring of the script.\n\n"
            "## The ambient-only test, by SNR threshold\n\n" + test_table
            + "\n\nThe lowest threshold at which the test's mean change is not negative: "
            f"**{_threshold(snr_t)}**; the library's `AUTO_AMBIENT_MIN_SNR` {snr_agree}. Chosen on these rows, and "
            "level rather than a gain there: a mean this close to 0 has no established sign, and a higher threshold "
            "can lose less PSNR by testing fewer regimes, where the test's purpose (sky left empty) is not in the "
            "PSNR. tr4-photons, whose own head marks no return, with the test by the library's rule (below) against "
            f"tr4-photons alone: mean {photon['mean']:+.3f} dB, worst {photon['worst']:+.2f} dB, "
            f"{photon['losing']} rows losing more than {TOLERANCE_DB:g} dB (`jaxsr upscale` leaves the test off for "
            "models with a no-return head).\n\n"
            "## The library's rule: the SNR, or the signal photons times the SNR\n\n"
            "Signal photons x SNR = signal^2 / ambient photons per pixel and frame: how far one pixel's return "
            "stands out of its ambient light, which the SNR alone does not say (100 photons at SNR 0.1 stand out "
            "more than 3 at SNR 1.3).\n\n" + combined_table
            + f"\n\nThe library (`AUTO_AMBIENT_MIN_SIGNAL_SNR` = {AUTO_AMBIENT_MIN_SIGNAL_SNR:g}, "
            f"`auto_ambient_alpha`): mean {lib['mean']:+.4f} dB, worst {lib['worst']:+.2f} dB, rows losing more "
            f"than {TOLERANCE_DB:g} dB: {lib['losing']}, tested: {lib['picked'].get(TR4_TEST, 0)} of {len(rows)}; "
            f"the SNR alone (>= {AUTO_AMBIENT_MIN_SNR:g}): mean {snr_only['mean']:+.4f} dB, worst "
            f"{snr_only['worst']:+.2f} dB, losing: {snr_only['losing']}, tested: "
            f"{snr_only['picked'].get(TR4_TEST, 0)}. The lowest c with the highest mean change among those losing no "
            f"more rows than the SNR alone: **{_threshold(c)}**; the library's `AUTO_AMBIENT_MIN_SIGNAL_SNR` "
            f"{c_agree}. Chosen on these rows too.\n\n"
            "## The model, by photon threshold (the test by the library's rule)\n\n" + model_table
            + f"\n\nThe rule with the highest mean: {_model_rule_text(model)}; the best that loses no scene-regime "
            f"more than {TOLERANCE_DB:g} dB: {_model_rule_text(safe)}. `jaxsr upscale`'s default for photons is "
            "chosen on the simulated regimes and the real recordings, not by this rule "
            "(docs/results/photon-regimes.md); a depth model gets a hint below "
            f"{FEW_PHOTONS:g} estimated photons.\n\n## Per scene and regime\n\n" + detail + "\n")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=8, help="frames scored per test scene (default 8)")
    parser.add_argument("--photons", type=float, nargs="+", default=list(PHOTONS),
                        help="signal photons per LR pixel (default 1 3 14 100)")
    parser.add_argument("--snr", type=float, nargs="+", default=list(SNRS), help="frame SNRs (default 0.1 .. 5)")
    parser.add_argument("--seed", type=int, default=0, help="noise seed")
    parser.add_argument("--out", default="experiments/results/upscale_defaults.md",
                        help="the results file (a .json beside it)")
    args = parser.parse_args(argv)
    started = time.time()
    tr4, photon_model = jaxsr.load_model("paper-tr4"), jaxsr.load_model("tr4-photons")
    seqs = jaxsr.scenes.test_sequences(n_frames=SEQUENCE_FRAMES, names=TEST_SCENES)
    results = evaluate({TR4: tr4, TR4_TEST: tr4, PHOTON: photon_model, PHOTON_TEST: photon_model}, seqs,
                       frames=args.frames, photons=args.photons, snrs=args.snr, seed=args.seed, paper=False,
                       no_return=False, ambient={TR4_TEST: AUTO_AMBIENT_ALPHA, PHOTON_TEST: AUTO_AMBIENT_ALPHA})
    # the estimates, regime by regime in evaluate's order, with keys of their own
    estimates = [[estimated_levels(seq, r["photons"], r["snr"],
                                   key=jax.random.fold_in(jax.random.key(args.seed + 2), 100 * k + i))
                  for i, seq in enumerate(seqs.values())] for k, r in enumerate(results["regimes"])]
    rows = rows_of(results, estimates)
    tests, models = ambient_rules(rows), model_rules(rows)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, report(rows, tests, models, started=started, frames=args.frames, seed=args.seed))
    raw = raw_results(rows, tests, models, frames=args.frames, seed=args.seed)
    write_atomic(out.with_suffix(".json"), json.dumps(raw, indent=1) + "\n")
    print(f"wrote {out} and {out.with_suffix('.json')}")


if __name__ == "__main__":
    main()
