"""Benchmark across photon regimes: PSNR and SSIM of bicubic, the TV
reconstruction, TR0, TR4 and any extra models at 1, 3, 14, 100 and 1000 signal photons per LR pixel and frame SNR
0.1, 1.3 and 5 on the three test scenes, the goals checked, and how models treat regions with no return.

    python experiments/studies/photon_regimes.py --frames 4 --tv                 # a small run (4 min on 2 cores)
    python experiments/studies/photon_regimes.py --frames 32 --tv --tv-frames 4  # the full benchmark (~20 min)
    python experiments/studies/photon_regimes.py --model TR4-photons=tr4-photons

Data: the test scenes (harness.scoring.TEST_SCENES), `--frames` frames per scene spread over each 500-frame
sequence (`scored_frames`, as experiments/sweep_tr.py scores). Each regime calibrates the laser and ambient over the
whole sequence (`jaxsr.sensor.calibrate`, as `simulate_histograms` does) and draws photons only for the frames the
models read (the scored frames and their temporal windows), so a regime costs a fraction of a full simulation.
Besides the grid, the paper's regime: 14 photons, each scene at its own SNR (1.3, 1.3, 3); a model's PSNR there is
compared with the bundled TR4's ("today"). Every method of a regime sees the same noise, so differences are paired:
intervals are 95 % block-bootstrap intervals over frames (`frame_interval`: `jaxsr.paired_interval` with blocks
as long as `harness.scoring.interval`'s in sequence frames, so frames spread far apart are resampled one by one).
TV (`--tv`, slow: seconds per frame on a CPU) runs on `--tv-frames` of the scored frames per scene and is compared
on those only.

No return: the test depth with `no_return_regions` (a `NO_RETURN_FRACTION` share of the HR pixels, sky
weight `NO_RETURN_SKY`, one mask per scene) at 3 photons and above, SNR 1.3. A pixel with no return (ground truth
1.0) counts as output as depth where the normalised output is below `NO_RETURN_AT` (0.99); a true return
(ground truth below 1) counts as dropped where the output is at or above it.

The benchmark itself (clips, decisions, scores, models) is _photon_benchmark.py, shared with the other photon
studies; this script runs it and writes the report: experiments/results/photon_regimes.md (or --out) and a .json
of the raw numbers beside it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import jaxsr

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import SCENE_LABELS, SEQUENCE_FRAMES, TEST_SCENES, format_interval  # noqa: E402
from harness.reports import header, markdown_table, write_atomic  # noqa: E402

from _photon_benchmark import (  # noqa: E402
    GOAL_100,
    GOAL_AS_DEPTH,
    GOAL_DROPPED,
    GOAL_LOW,
    GOAL_TODAY,
    MAJORITY,
    NO_RETURN_AT,
    NO_RETURN_FRACTION,
    NO_RETURN_SKY,
    PAPER,
    PHOTONS,
    SNRS,
    TV_TR,
    evaluate,
    frame_interval,
    load_models,
    regime_label,
)


# ---------------------------------------------------------------------------------------------------- the report

def _grid(results):
    """The regimes of the grid (not the paper's)."""
    return [r for r in results["regimes"] if r["snr"] is not None]


def _paper(results):
    return next((r for r in results["regimes"] if r["snr"] is None), None)


def _stacked(regimes, method, cols=None):
    """Per-frame PSNR of `method` over several regimes, as (regimes * scenes, T) rows (their mean: the mean of
    the regimes' scene means)."""
    rows = [r["scores"][method]["psnr"] for r in regimes]
    return np.concatenate([x if cols is None else x[:, cols] for x in rows])


def _goal(value, target, *, at_least=True, iv=None, fmt="{:+.2f}", unit=" dB"):
    """A goal's cell: value (its interval), and whether it is met (by the mean)."""
    if value is None:
        return {"value": None, "met": None, "cell": "not measured"}
    met = value >= target if at_least else value <= target
    text = format_interval(iv) if iv is not None else fmt.format(value)
    return {"value": float(value), "met": bool(met), "cell": f"{text}{unit} {'yes' if met else 'NO'}",
            **({} if iv is None else {"low": float(iv.low), "high": float(iv.high)})}


def goals(results, *, today: str = "TR4") -> dict:
    """Each network model's goals: {model: {goal: {"value", "met", "cell", ...}}}."""
    grid, paper = _grid(results), _paper(results)
    low = [r for r in grid if r["photons"] in (1.0, 3.0)]
    at100 = [r for r in grid if r["photons"] == 100.0]
    nets = [m for m in results["methods"] if m not in ("bicubic", "TV")]
    tv = "TV" in results["methods"]
    sp, tv_sp = results["spacing"], results["tv_spacing"]
    out = {}
    for m in nets:
        g = {}
        for name, regimes, target in (("low", low, GOAL_LOW), ("100", at100, GOAL_100)):
            if regimes:
                iv = frame_interval(_stacked(regimes, m), _stacked(regimes, "bicubic"), sp)
                g[name] = _goal(float(iv.mean), target, iv=iv)
            else:
                g[name] = _goal(None, target)
        if paper is not None and today in paper["scores"]:
            iv = frame_interval(paper["scores"][m]["psnr"], paper["scores"][today]["psnr"], sp)
            g["today"] = _goal(float(iv.mean), GOAL_TODAY, iv=iv)
        else:
            g["today"] = _goal(None, GOAL_TODAY)
        if tv and grid:
            cols = results["tv_idx"]
            ivs = [(r, frame_interval(r["scores"][m]["psnr"][:, cols], r["scores"]["TV"]["psnr"], tv_sp))
                   for r in grid]
            worst, iv = min(ivs, key=lambda x: float(x[1].mean))
            g["tv"] = _goal(float(iv.mean), 0.0, iv=iv)
            g["tv"]["cell"] += f" (worst: {regime_label(worst['photons'], worst['snr'])})"
            g["tv"]["met"] = bool(all(float(v.mean) > 0 for _, v in ivs))
        else:
            g["tv"] = _goal(None, 0.0)
        nr = results["no_return"]
        if nr:
            as_depth = max(e["rates"][m][0] for e in nr)
            dropped = max(e["rates"][m][1] for e in nr)
            g["as_depth"] = _goal(as_depth, GOAL_AS_DEPTH, at_least=False, fmt="{:.2f}", unit=" %")
            g["dropped"] = _goal(dropped, GOAL_DROPPED, at_least=False, fmt="{:.2f}", unit=" %")
        else:
            g["as_depth"] = _goal(None, GOAL_AS_DEPTH)
            g["dropped"] = _goal(None, GOAL_DROPPED)
        out[m] = g
    return out


GOAL_TEXT = {
    "low": f"PSNR - bicubic, mean over 1 and 3 photons (every SNR) >= +{GOAL_LOW:g} dB",
    "100": f"PSNR - bicubic at 100 photons (mean over SNRs) >= +{GOAL_100:g} dB",
    "today": f"PSNR - bundled TR4 at the paper's regime (14 photons, own SNR) >= {GOAL_TODAY:g} dB",
    "tv": "PSNR - TV > 0 in every regime of the grid (TV's frames; worst regime shown)",
    "as_depth": f"no-return pixels output as depth <= {GOAL_AS_DEPTH:g} % (worst photon level >= 3, SNR 1.3)",
    "dropped": f"true returns dropped <= {GOAL_DROPPED:g} % (worst photon level >= 3, SNR 1.3)",
}


def tables(results) -> str:
    methods = results["methods"]
    tv_note = " (TV: on its frames only)" if "TV" in methods else ""
    text = []
    for metric, fmt, title in (("psnr", "{:.2f}", "Mean PSNR (dB)"), ("ssim", "{:.3f}", "Mean SSIM")):
        rows = [[f"{r['photons']:g}", PAPER if r["snr"] is None else f"{r['snr']:g}"]
                + [fmt.format(r["scores"][m][metric].mean()) for m in methods] for r in results["regimes"]]
        text.append(f"### {title}, 3 scenes{tv_note}\n\n" + markdown_table(["photons", "SNR", *methods], rows))
    cols = results["tv_idx"]
    rows = []
    for r in results["regimes"]:
        bic = r["scores"]["bicubic"]["psnr"]
        cells = []
        for m in methods[1:]:
            a = r["scores"][m]["psnr"]
            cells.append(format_interval(frame_interval(a, bic[:, cols], results["tv_spacing"]) if m == "TV"
                                         else frame_interval(a, bic, results["spacing"])))
        rows.append([f"{r['photons']:g}", PAPER if r["snr"] is None else f"{r['snr']:g}", *cells])
    text.append("### PSNR - bicubic (dB, mean [95 % interval over frames, paired])" + tv_note + "\n\n"
                + markdown_table(["photons", "SNR", *methods[1:]], rows))
    g = goals(results)
    if g:
        nets = list(g)
        rows = [[GOAL_TEXT[k], *(g[m][k]["cell"] for m in nets)] for k in GOAL_TEXT]
        text.append("### Goals (met by the mean; intervals 95 %)\n\n" + markdown_table(["goal", *nets], rows))
    if results["no_return"]:
        nr_methods = list(results["no_return"][0]["rates"])
        rows = [[f"{e['photons']:g}", f"{e['snr']:g}", *(f"{e['rates'][m][0]:.2f} / {e['rates'][m][1]:.2f}"
                                                        for m in nr_methods)] for e in results["no_return"]]
        text.append(f"### No return: % of no-return HR pixels output as depth / % of true returns dropped\n\n"
                    f"Test depth with `no_return_regions` ({100 * NO_RETURN_FRACTION:g} % of the HR pixels, sky weight "
                    f"{NO_RETURN_SKY:g}), output read as no return at normalised >= {NO_RETURN_AT:g}. "
                    f"`{MAJORITY}`: one decision per LR block known from the truth, no return where at least half of "
                    "its HR pixels have none (`block_majority`): it minimises the two errors' total, not each, and "
                    "shows what the regions' ragged edges cost any decision made per LR pixel (the same at every "
                    "photon level); a network beats it only by placing edges inside blocks.\n\n"
                    + markdown_table(["photons", "SNR", *nr_methods], rows))
        share = results["no_return"][0]["interior_share"]
        rows = [[f"{e['photons']:g}", f"{e['snr']:g}", *(f"{e['interior'][m][0]:.2f} / {e['interior'][m][1]:.2f}"
                                                        for m in nr_methods)] for e in results["no_return"]]
        text.append("### No return inside the regions: the same, on HR pixels whose LR block and its 8 "
                    "neighbours are of one kind\n\n"
                    f"{100 * share:.0f} % of the HR pixels (`interior`): away from the edges, where no LR pixel next "
                    "to a pixel mixes the two kinds.\n\n"
                    + markdown_table(["photons", "SNR", *nr_methods], rows))
    return "\n".join(text)


def raw(results, models_info) -> dict:
    """The results as JSON-ready numbers (per-frame PSNR and SSIM (scenes, frames) per regime and method)."""
    def scores(s):
        return {m: {"psnr_mean": float(v["psnr"].mean()), "ssim_mean": float(v["ssim"].mean()),
                    "psnr": np.round(v["psnr"], 4).tolist(), "ssim": np.round(v["ssim"], 5).tolist()}
                for m, v in s.items()}
    return {"scenes": results["scenes"], "scored_frames": np.asarray(results["scored"]).tolist(),
            "tv_frames": np.asarray(results["scored"])[results["tv_idx"]].tolist(), "models": models_info,
            "regimes": [{"photons": r["photons"], "snr": r["snr"] if r["snr"] is not None else PAPER,
                         "scores": scores(r["scores"])} for r in results["regimes"]],
            "no_return": [{"photons": e["photons"], "snr": e["snr"],
                           "rates": {m: {"as_depth_pct": a, "dropped_pct": d} for m, (a, d) in e["rates"].items()},
                           "interior": {m: {"as_depth_pct": a, "dropped_pct": d}
                                        for m, (a, d) in e["interior"].items()},
                           "interior_share": e["interior_share"]}
                          for e in results["no_return"]],
            "goals": {m: {k: {kk: vv for kk, vv in v.items() if kk != "cell"} for k, v in g.items()}
                      for m, g in goals(results).items()},
            "settings": {"no_return_at": NO_RETURN_AT, "no_return_fraction": NO_RETURN_FRACTION,
                         "no_return_sky": NO_RETURN_SKY, "tv_tr": TV_TR}}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=8,
                        help=f"frames scored per test scene, spread over its {SEQUENCE_FRAMES} (default 8)")
    parser.add_argument("--photons", type=float, nargs="+", default=list(PHOTONS),
                        help="signal photons per LR pixel (default 1 3 14 100 1000)")
    parser.add_argument("--snr", type=float, nargs="+", default=list(SNRS), help="frame SNRs (default 0.1 1.3 5)")
    parser.add_argument("--tv", action="store_true", help="also the TV reconstruction (slow), on --tv-frames")
    parser.add_argument("--tv-frames", type=int, default=2, help="frames per scene TV runs on (default 2)")
    parser.add_argument("--model", action="append", default=[], metavar="NAME=PATH",
                        help="an extra model file to score (skipped with a line when absent); repeatable")
    parser.add_argument("--no-return-logit", action="append", default=[], metavar="NAME=LOGIT",
                        help="run --model NAME (one with a no-return head) at this decision threshold; repeatable")
    parser.add_argument("--ambient-alpha", action="append", default=[], metavar="NAME=ALPHA",
                        help="run --model NAME also marking no return where the photons around a pixel pass for "
                        "ambient light alone at this false-alarm rate (jaxsr.sensor.ambient_only); repeatable")
    parser.add_argument("--no-return-shares", action="append", default=[], metavar="NAME=ALPHA",
                        help="run --model NAME also marking no return where jaxsr.sensor.no_return_shares (the "
                        "ambient-only test grown to the regions' edges, at this false-alarm rate) say so; repeatable")
    parser.add_argument("--keep-returns", action="append", default=[], metavar="NAME=ALPHA",
                        help="run --model NAME (one with a no-return head) outputting depth wherever the LR pixel's "
                        "own photons over 9 frames show a return at this false-alarm rate, whatever the head says "
                        "(returns_kept); repeatable")
    parser.add_argument("--static", action="store_true",
                        help="score static scenes: each frame shows the scored frame nearest to it (nearest_scored)")
    parser.add_argument("--seed", type=int, default=0, help="noise seed")
    parser.add_argument("--out", default="experiments/results/photon_regimes.md",
                        help="the results file (a .json beside it)")
    args = parser.parse_args(argv)
    started = time.time()
    models, info, ambient = load_models(args.model, args.no_return_logit, args.ambient_alpha, args.no_return_shares,
                                        args.keep_returns)
    seqs = jaxsr.scenes.test_sequences(n_frames=SEQUENCE_FRAMES, names=TEST_SCENES)
    try:
        results = evaluate(models, seqs, frames=args.frames, photons=args.photons, snrs=args.snr,
                           tv_frames=args.tv_frames if args.tv else 0, seed=args.seed, ambient=ambient,
                           static=args.static)
    except ValueError as e:
        if not args.static:
            raise
        raise SystemExit(str(e)) from None  # scored frames too close for --static
    full = "python experiments/studies/photon_regimes.py --frames 32 --tv --tv-frames 4"
    small = args.frames < 32 or not args.tv or args.photons != list(PHOTONS) or args.snr != list(SNRS)
    scenes_text = ", ".join(SCENE_LABELS[n] for n in TEST_SCENES)
    text = (header("Benchmark across photon regimes", started)
            + (f"**A small run** ({args.frames} frames per scene{'' if args.tv else ', no TV'}): the differences "
               f"carry wide intervals. The full benchmark: `{full}`.\n\n" if small else "")
            + f"{scenes_text}: {args.frames} frames each, spread over the {SEQUENCE_FRAMES} "
            f"(frames {', '.join(map(str, results['scored']))})"
            + (", **static**: every frame shows the scored frame nearest to it, the calibration that of the moving "
               "sequence (`--static`, `nearest_scored`)"
               if args.static else "")
            + f"; noise seed {args.seed}, the same noise for every "
            f"method of a regime. Photons: mean signal photons per LR pixel with a return; SNR `{PAPER}`: the "
            "paper's regime, each scene at its own SNR (1.3, 1.3, 3). "
            + (f"TV (`tv_super_resolve`, tr {TV_TR}, its defaults) on {args.tv_frames} of them per scene (frames "
               f"{', '.join(map(str, np.asarray(results['scored'])[results['tv_idx']]))}). " if args.tv else
               "TV not run (`--tv`). ")
            + "Models: " + "; ".join(f"{k}: {v}" for k, v in info.items()) + ". Outputs clipped to [0, 1] for "
            "PSNR and SSIM (`harness.scoring.frame_scores`).\n\n"
            + tables(results))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, text)
    write_atomic(out.with_suffix(".json"), json.dumps(raw(results, info), indent=1) + "\n")
    print(f"wrote {out} and {out.with_suffix('.json')}")


if __name__ == "__main__":
    main()
