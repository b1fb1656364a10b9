"""`jaxsr upscale --model auto` on photon histograms, measured: every bundled model that reads them, scored on
simulated clips at three photon levels and three kinds of motion; the table `choose_photon_model` reads; and the
choice it makes on other clips against the default and the best bundled model there.

    python experiments/studies/model_auto.py --write-table          # the table, then the check on other clips
    python experiments/studies/model_auto.py --frames 6 --clips 1 1  # a quick look (no table written)

Clips: the scene generator's scenes (not the test scenes), three kinds of motion: a static camera (a courtyard;
people in it may move), a street seen from a camera moving sideways at 25 frames/s and the same at 10 frames/s
(faster); signal photons per LR pixel 3, 14 and 100 at frame SNR 1.3, the paper's 16 bins over 35 m. Each clip runs
through `prepare_upscale` with every candidate model as the command runs it (its photon rules' defaults). Score:
PSNR of the normalised depth over all HR pixels, no return included (1.0), mean over frames.

The table (`jaxsr/weights/model_auto_study.json`): clips of the calibration seeds (`--clips`, the first number, per
motion class, photon level and scene); per photon level (row: the median signal photons `jaxsr.app.photon_levels`
measured there) and motion class (column: the median motion `jaxsr.inference.estimate_motion` measured there, the
columns sorted by it), each model's mean PSNR and the standard error of its lead over the default across the
cell's clips (paired: every model reads the same photons), which `choose_photon_model` needs a lead to exceed
`LEAD_Z` times before it leaves the default (one clip: no lead is established); each model's
frames/s is the frame-rate study's for its temporal radius (the photon models run the same network on 3 more
input channels). The check: clips of other seeds, where `choose_photon_model` chooses from each clip's own
measured photons and motion, against the default (`DEFAULT_MODELS["histograms"]`) and the best model on that clip
(`--clips`, the second number, per class, level and scene).
Also the motion each clip reads, static cameras among them. Writes experiments/results/model_auto.md (or --out)
and a .json beside it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

import jaxsr
from jaxsr.app import prepare_upscale
from jaxsr.app.models import DEFAULT_MODELS
from jaxsr.app.photons import photon_levels
from jaxsr.config import DepthScale, Optics, Sensor
from jaxsr.inference.adaptive import (LEAD_Z, MODEL_TABLE, choose_photon_model, estimate_motion, lead_holds,
                                      load_study)
from jaxsr.runtime import enable_compilation_cache
from jaxsr.scenes import sequence
from jaxsr.sensor.gates import to_network_depth

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import header, markdown_table, write_atomic  # noqa: E402

MODELS = ("tr0", "tr1", "tr2", "tr3", "tr4", "tr4-ambient", "tr0-ambient", "tr4-photons", "tr0-photons")
LEVELS = (3.0, 14.0, 100.0)
SNR = 1.3
# motion class -> clips (kind, camera, frames/s); the calibration and the check draw other seeds
CLASSES = {"static camera": (("courtyard", "static", 25.0),),
           "moving, 25 fps": (("street", "moving", 25.0),),
           "moving, 10 fps": (("street", "moving", 10.0),)}
SPLITS = {"calibration": 100, "check": 200}  # seed offsets; a clip's seed: offset + 10 class + scene + 1000 repeat
CLIPS = (3, 2)  # clips per class, level and scene: calibration, check


def score(out, truth) -> float:
    """Mean PSNR over frames of normalised depth, peak 1, output clipped to [0, 1]."""
    return float(np.mean(np.asarray(jaxsr.psnr(np.clip(out, 0, 1), truth))))


def run_clips(args):
    sensor = Sensor(optics=Optics.of_hr(tuple(args.hr)))
    clips = []
    for (split, offset), repeats in zip(SPLITS.items(), args.clips):
        for rep, (cls, members) in ((rep, c) for rep in range(repeats) for c in CLASSES.items()):
            for j, (kind, camera, fps) in enumerate(members):
                seed = offset + 10 * list(CLASSES).index(cls) + j + 1000 * rep
                depth, intensity = sequence(jax.random.key(seed), args.frames, fps, kind=kind, sensor=sensor,
                                            camera=camera)
                truth = np.asarray(to_network_depth(depth, DepthScale()), np.float32)
                for photons in args.levels:
                    counts = np.asarray(jaxsr.simulate_histograms(jax.random.key(seed * 1000 + int(photons)), depth,
                                                                  intensity, sensor, snr=SNR, mean_signal=photons))
                    levels = photon_levels(counts, sensor.bins)
                    lr = np.asarray(jaxsr.centre_of_mass(counts, sensor), np.float32)  # as --model auto reads it
                    est = estimate_motion(lr)
                    scores = {}
                    for m in args.models:
                        job = prepare_upscale(counts, model=m)
                        metres = np.stack(list(job.iter_frames(units="m")))  # on the 35 m scale of the truth
                        scores[m] = score(np.asarray(to_network_depth(metres, DepthScale()), np.float32), truth)
                    clips.append({"split": split, "class": cls, "scene": f"{kind} ({camera}, {fps:g} fps)",
                                  "seed": seed, "photons": photons, "signal": levels.signal, "snr": levels.snr,
                                  "motion": est.motion, "saturated": est.saturated, "scores": scores, "lr": lr})
                    print(split, cls, kind, photons, f"motion {est.motion:.2f}",
                          {m: round(v, 2) for m, v in scores.items()}, file=sys.stderr, flush=True)
    return clips


def build_table(clips, models) -> dict:
    cal = [c for c in clips if c["split"] == "calibration"]
    levels = sorted({c["photons"] for c in cal})
    # motion columns: the classes by their median measured motion, classes that read alike (within 0.1 px/frame)
    # pooled into one column
    by_motion = sorted(CLASSES, key=lambda k: np.median([c["motion"] for c in cal if c["class"] == k]))
    groups = []
    for k in by_motion:
        m = float(np.median([c["motion"] for c in cal if c["class"] == k]))
        if groups and m - groups[-1][0] < 0.1:
            groups[-1][1].append(k)
        else:
            groups.append((m, [k]))
    classes = [" + ".join(g) for _, g in groups]
    motion = [float(np.median([c["motion"] for c in cal if c["class"] in g])) for _, g in groups]
    signal = [float(np.median([c["signal"] for c in cal if c["photons"] == p])) for p in levels]
    default = DEFAULT_MODELS["histograms"]

    def cell(p, g):
        return [c for c in cal if c["photons"] == p and c["class"] in g]

    def lead_se(m, p, g):  # of the paired lead over the default; inf from one clip (no spread to measure)
        leads = [c["scores"][m] - c["scores"][default] for c in cell(p, g)]
        return float(np.std(leads, ddof=1) / np.sqrt(len(leads))) if len(leads) > 1 else float("inf")

    psnr = {m: [[float(np.mean([c["scores"][m] for c in cell(p, g)])) for _, g in groups] for p in levels]
            for m in models}
    se = {m: [[lead_se(m, p, g) for _, g in groups] for p in levels] for m in models}
    study = load_study()
    fps = {m: float(study["fps"][m[2]]) for m in models}  # trK...: the frame-rate study's TR K
    return {"signal": signal, "motion": motion, "classes": classes, "psnr": psnr, "lead_se": se,
            "default": default, "clips": min(len(cell(p, g)) for p in levels for _, g in groups), "fps": fps,
            "source": f"experiments/studies/model_auto.py {' '.join(sys.argv[1:])}, {time.strftime('%Y-%m-%d')}; "
                      f"signal photons and motion as jaxsr measures them, SNR {SNR:g}; frames/s of the frame-rate "
                      "study's TR"}


def check(clips, table) -> list[dict]:
    default = DEFAULT_MODELS["histograms"]
    rows = []
    for c in clips:
        if c["split"] != "check":
            continue
        pick = choose_photon_model(c["lr"], c["signal"], table=table)
        best = max(c["scores"], key=c["scores"].get)
        rows.append({"class": c["class"], "scene": c["scene"], "photons": c["photons"], "motion": c["motion"],
                     "signal": c["signal"], "auto": pick.model, "auto_psnr": c["scores"][pick.model],
                     "default_psnr": c["scores"][default], "best": best, "best_psnr": c["scores"][best]})
    return rows


def report(clips, table, rows, args, started) -> str:
    cols = table["classes"]
    default = table["default"]

    def best_cell(i, j):
        best = max(table["psnr"], key=lambda m: table["psnr"][m][i][j])
        lead = table["psnr"][best][i][j] - table["psnr"][default][i][j]
        se = table["lead_se"][best][i][j]
        held = best == default or lead_holds(lead, se)
        return (f"{best} {table['psnr'][best][i][j]:.2f}" + ("" if best == default else f", {lead:+.2f} +- {se:.2f}")
                + f"; auto: {best if held else default}")

    tab = markdown_table(
        ["photons"] + [f"{k} (motion {m:.2f})" for k, m in zip(cols, table["motion"])],
        [[f"{p:g} (signal {s:.3g})"] + [best_cell(i, j) for j in range(len(cols))]
         for i, (p, s) in enumerate(zip(args.levels, table["signal"]))])
    full = markdown_table(["model"] + [f"{p:g} ph, {k}" for p in args.levels for k in cols],
                          [[m] + [f"{v[i][j]:.2f}" for i in range(len(args.levels)) for j in range(len(cols))]
                           for m, v in table["psnr"].items()])
    chk = markdown_table(
        ["motion class", "scene", "photons", "motion read", "auto's model", "auto", "default", "best model", "best"],
        [[r["class"], r["scene"], f"{r['photons']:g}", f"{r['motion']:.2f}", r["auto"], f"{r['auto_psnr']:.2f}",
          f"{r['default_psnr']:.2f}", r["best"], f"{r['best_psnr']:.2f}"] for r in rows])
    mean = {k: float(np.mean([r[k] for r in rows])) for k in ("auto_psnr", "default_psnr", "best_psnr")}
    static = [c["motion"] for c in clips if c["class"] == "static camera"]
    return (header("--model auto on photon histograms", started)
            + f"{args.frames} frames of {args.hr[0]} x {args.hr[1]} HR px per clip, SNR {SNR:g}, 16 bins over 35 m. "
              f"Models: {', '.join(args.models)}.\n\n"
            + f"## The table (calibration seeds, at least {table['clips']} clips a cell): the best model per cell, "
              f"mean PSNR dB, its lead over the default ({default}) +- the lead's standard error across the cell's "
              "clips, and "
              f"what auto chooses there (the default unless the lead exceeds {LEAD_Z:g} standard errors)\n\n" + tab
            + "\n### Every model\n\n" + full
            + "\n## The check (other seeds): auto's choice against the default and the best model, PSNR dB\n\n" + chk
            + f"\nMean over the check's clips: auto {mean['auto_psnr']:.2f}, default {mean['default_psnr']:.2f}, "
              f"best per clip {mean['best_psnr']:.2f} dB.\n\n"
            + f"Static cameras' clips read {', '.join(f'{m:.2f}' for m in static)} LR px/frame (people walking in "
              "the walkers' and courtyard's view move).\n")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=12)
    p.add_argument("--hr", type=int, nargs=2, default=(64, 128))
    p.add_argument("--levels", type=float, nargs="+", default=list(LEVELS))
    p.add_argument("--models", nargs="+", default=list(MODELS))
    p.add_argument("--clips", type=int, nargs=2, default=list(CLIPS), metavar=("CALIBRATION", "CHECK"),
                   help="clips per motion class, photon level and scene for the table and for the check")
    p.add_argument("--write-table", action="store_true", help=f"store the table as {MODEL_TABLE}")
    p.add_argument("--out", default="experiments/results/model_auto.md")
    args = p.parse_args(argv)
    started = time.time()
    enable_compilation_cache()
    clips = run_clips(args)
    table = build_table(clips, args.models)
    if args.write_table:
        write_atomic(str(MODEL_TABLE), json.dumps(table, indent=1) + "\n")
    rows = check(clips, table)
    text = report(clips, table, rows, args, started)
    write_atomic(args.out, text)
    write_atomic(str(Path(args.out).with_suffix(".json")), json.dumps(
        {"table": table, "check": rows, "clips": [{k: v for k, v in c.items() if k != "lr"} for c in clips]},
        indent=1) + "\n")
    print(text)


if __name__ == "__main__":
    main()
