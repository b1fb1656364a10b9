"""Calibrate a photon model's no-return decision (`ModelConfig.no_return_logit`) and save the calibrated copy.

    python experiments/studies/no_return_threshold.py --model tr4-photons
    python experiments/studies/no_return_threshold.py --model tr4-photons --write runs/calibrated/tr4-photons.npz

A model with a no-return head outputs "no return" (1.0) where its logit is above `no_return_logit`, 0.0 unless
calibrated. This draws `--draws` windows (whole frames) from the wide photon regime (`jaxsr.config.PhotonRegime`)
with regions of no return on every clip, the photon level log-uniform in `--photons` (3-1000) and the SNR in `--snr`
(the regime's 0.05-20), with keys of their own (`jaxsr.training.CALIBRATION_SEED`: apart from those of the benchmark,
experiments/studies/photon_regimes.py, and of the training runs' validation, so that both stay fair tests); runs
the model once; and sweeps the threshold over the logits (`jaxsr.training.calibrate_no_return`). It prints, for
each threshold, the share of no-return pixels output as depth and of true returns dropped, in each band of photon
levels, and the rule's choice: the smallest worst-band share "as depth" among the thresholds that keep the
worst-band share "dropped" at or below `--target` (2 %), over the bands from `--min-photons` (3) up. Pixels are
read as the benchmark reads them: an output at or above 0.99 (normalised) is "no return".

`--write OUT.npz` saves the model with the chosen threshold in its config (float16, as the bundled weights) and its
card plus a "no_return_calibration" entry (draws, seed, target, the table); an existing file is kept unless
`--force`.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import sys
import time
from pathlib import Path

import jax
import numpy as np

import jaxsr
from jaxsr.config import Optics, PhotonRegime, Sensor
from jaxsr.io.checkpoint import resolve_model_path
from jaxsr.training import CALIBRATION_SEED, calibrate_no_return, no_return_set
from jaxsr.training.no_return import (DEFAULT_THRESHOLDS, MIN_PHOTONS, NO_RETURN_AT, PHOTON_EDGES,
                                      TARGET_DROPPED)

SCRIPT = "experiments/studies/no_return_threshold.py"
DRAWS = 192  # windows (whole frames); TR4: about 4 minutes on 2 CPU cores, drawing included


def band_label(lo: float, hi: float) -> str:
    return f"{lo:g}-{hi:g}"


def table_text(result: dict, *, every: float = 0.5) -> str:
    """The sweep as text: one row per threshold that is a multiple of `every` (and the chosen one), the worst
    counted bands' shares, then each band's "as depth / dropped" (%)."""
    table, choice, current = result["table"], result["choice"], result["current"]
    bands = table["bands"]
    counted = bands[:, 0] >= choice["min_photons"]
    head = ["logit", "worst as depth %", "worst dropped %"] + [f"{band_label(*b)} ph" + ("" if c else " (not counted)")
                                                               for b, c in zip(bands, counted)]
    rows = []
    for k, t in enumerate(table["thresholds"]):
        chosen = t == choice["no_return_logit"]
        if not (chosen or abs(t / every - round(t / every)) < 1e-9):
            continue
        a, d = table["as_depth"][:, k], table["dropped"][:, k]
        mark = " <- chosen" if chosen else ""
        mark += " <- uncalibrated" if t == 0.0 and current["no_return_logit"] == 0.0 else ""
        rows.append([f"{t:+.2f}", f"{np.nanmax(a[counted]):.2f}", f"{np.nanmax(d[counted]):.2f}"]
                    + [f"{x:.2f} / {y:.2f}" for x, y in zip(a, d)] + [mark])
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]
    lines = ["  ".join(h.rjust(w) for h, w in zip(head, widths))]
    lines += ["  ".join(c.rjust(w) for c, w in zip(r, widths)) + r[-1] for r in rows]
    windows = ", ".join(f"{band_label(*b)}: {n}" for b, n in zip(bands, table["windows"]))
    return "\n".join(lines) + f"\n(windows per band of photons: {windows})"


def calibration_card(result: dict, args, previous: float) -> dict:
    """The card entry that says how the threshold was calibrated."""
    table, choice = result["table"], result["choice"]
    return {
        "no_return_logit": choice["no_return_logit"],
        "previous_no_return_logit": previous,
        "calibrated_from": args.model,  # as given: a bundled name, or the path it was called with
        "rule": (f"smallest worst-band % of no-return pixels output as depth among thresholds keeping the worst-band % "
                 f"of true returns dropped <= {choice['target_dropped']:g}, bands of photon levels from "
                 f"{choice['min_photons']:g} up; output >= {NO_RETURN_AT:g} reads as no return"),
        "target_dropped_pct": choice["target_dropped"],
        "min_photons": choice["min_photons"],
        "met": choice["met"],
        "worst_as_depth_pct": choice["as_depth"],
        "worst_dropped_pct": choice["dropped"],
        "uncalibrated": result["current"],
        "draws": args.draws,
        "seed": args.seed,
        "keys": "batch j of the draws from jax.random.fold_in(jax.random.key(seed), j) (jaxsr.training.no_return_set)",
        "data": {"regime": "jaxsr.config.PhotonRegime() with no_return_prob 1, paper_prob 0",
                 "photon_range": list(args.photons), "snr_range": list(args.snr), "hr_shape": list(args.frame)},
        "table": {"thresholds": table["thresholds"].tolist(), "bands": table["bands"].tolist(),
                  "windows": table["windows"].tolist(),
                  "as_depth_pct": np.round(table["as_depth"], 3).tolist(),
                  "dropped_pct": np.round(table["dropped"], 3).tolist()},
        "script": SCRIPT,
        "date": datetime.date.today().isoformat(),
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="tr4-photons", help="the model (a file, a run folder or bundled weights)")
    parser.add_argument("--draws", type=int, default=DRAWS, help=f"windows to calibrate on (default {DRAWS})")
    parser.add_argument("--batch", type=int, default=8, help="windows per forward pass (default 8)")
    parser.add_argument("--photons", type=float, nargs=2, default=(3.0, 1000.0), metavar=("LO", "HI"),
                        help="photon levels drawn log-uniform (default 3 1000)")
    parser.add_argument("--snr", type=float, nargs=2, default=PhotonRegime().snr_range, metavar=("LO", "HI"),
                        help="SNR drawn log-uniform (default the regime's 0.05 20)")
    parser.add_argument("--target", type=float, default=TARGET_DROPPED,
                        help=f"%% of true returns dropped, at most, in every counted band (default {TARGET_DROPPED:g})")
    parser.add_argument("--min-photons", type=float, default=MIN_PHOTONS,
                        help=f"count the bands of photon levels from this one up (default {MIN_PHOTONS:g})")
    parser.add_argument("--seed", type=int, default=CALIBRATION_SEED,
                        help="the draws' key, jax.random.key(SEED) (default jaxsr.training.CALIBRATION_SEED)")
    parser.add_argument("--frame", type=int, nargs=2, default=Sensor().hr_shape, metavar=("ROWS", "COLS"),
                        help="HR frame size of the draws (default the sensor's 128 256)")
    parser.add_argument("--write", default=None, metavar="OUT.npz", help="save the calibrated model there")
    parser.add_argument("--force", action="store_true", help="let --write replace an existing file")
    args = parser.parse_args(argv)
    if args.write is not None and Path(args.write).exists() and not args.force:
        sys.exit(f"{args.write} exists; --force to replace it")
    started = time.time()
    source = str(resolve_model_path(args.model))
    model = jaxsr.load_model(args.model)
    if not getattr(model.config, "no_return_head", False):
        sys.exit(f"{args.model}: a model without a no-return head (ModelConfig.no_return_head); nothing to calibrate")
    sensor = Sensor(optics=Optics.of_hr(tuple(args.frame)))
    validation = no_return_set(model.config.tr, draws=args.draws, photon_range=args.photons, snr_range=args.snr,
                               sensor=sensor, inputs=model.config.inputs, key=jax.random.key(args.seed),
                               batch=args.batch)
    drawn = time.time()
    result = calibrate_no_return(model, validation, DEFAULT_THRESHOLDS, target_dropped=args.target,
                                 min_photons=args.min_photons, edges=PHOTON_EDGES, batch=args.batch)
    choice, current = result["choice"], result["current"]
    print(f"{args.model}: {args.draws} windows of {args.frame[0]} x {args.frame[1]}, photons "
          f"{args.photons[0]:g}-{args.photons[1]:g}, SNR {args.snr[0]:g}-{args.snr[1]:g}, seed {args.seed} (drawn in "
          f"{drawn - started:.0f} s, model and sweep {time.time() - drawn:.0f} s)")
    print("shares in % per band of photons: no-return pixels output as depth / true returns dropped")
    print(table_text(result))
    print(f"current threshold {current['no_return_logit']:+.2f}: worst {current['as_depth']:.2f} % as depth, "
          f"{current['dropped']:.2f} % dropped")
    print(f"chosen threshold {choice['no_return_logit']:+.2f}: worst {choice['as_depth']:.2f} % as depth, "
          f"{choice['dropped']:.2f} % dropped "
          + ("(target met)" if choice["met"] else f"(NO threshold keeps dropped <= {args.target:g} %: the least)"))
    if args.write is not None:
        cfg = dataclasses.replace(model.config, no_return_logit=choice["no_return_logit"])
        card = dict(jaxsr.read_metadata(source).get("card", {}))
        card["no_return_calibration"] = calibration_card(result, args, model.config.no_return_logit)
        if Path(args.write).exists() and not args.force:  # appeared while this ran
            sys.exit(f"{args.write} exists; --force to replace it")
        path = jaxsr.save_model(args.write, dataclasses.replace(model, config=cfg), card=card,
                                storage_dtype="float16")
        print(f"wrote {path} (no_return_logit {cfg.no_return_logit:+.2f})")


if __name__ == "__main__":
    main()
