"""Fit the confidence's coefficients (`jaxsr.inference.confidence`) on simulated clips and store them in the package.

    python experiments/studies/confidence_fit.py                       # tr4-ambient and the generic sets (~30 min, 2 cores)
    python experiments/studies/confidence_fit.py --draws 16 --out /tmp/c.json   # a quick look

Data: training-style clips of jaxsr's scene generator (`jaxsr.training.confidence.confidence_set`: static and moving,
dim and bright, 1-1000 signal photons per LR pixel, SNR 0.1-5, the training regime's dark counts, hot and dead
pixels, half the clips with added regions of no return), whole 32 x 64 LR frames, drawn from key CONFIDENCE_SEED: never the
test scenes, never held-out data. Per model: the return probability's logistic coefficients (`fit_logistic`) and the
depth std's (`fit_depth_std`), fitted on the even-numbered clips; the odd-numbered ones give the simulated
validation figures stored beside them. Entries: each bundled model named by --models, "head" (the generic set for
another model with a no-return head: tr4-ambient's) and "photons" (any model without one, fitted with tr4 reading
histograms, on 16 x 16 LR crops). Writes jaxsr/weights/confidence.json (or --out) with the command, machine and date.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

import jaxsr
from jaxsr.eval import auroc, expected_calibration_error, interval_coverage
from jaxsr.inference.confidence import HEAD_FEATURES, INTERVAL_Z, PHOTON_FEATURES, STD_FEATURES
from jaxsr.io.files import write_text_atomic
from jaxsr.training.confidence import confidence_set, fit_depth_std, fit_logistic, set_features

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import machine  # noqa: E402

OUT = Path(jaxsr.__file__).parent / "weights" / "confidence.json"


def drawn(name: str, draws: int, cache: Path, log, patch=None) -> dict:
    """The model's `confidence_set` of `draws` clips (whole frames, or LR crops of `patch`), cached as an .npz
    under `cache`."""
    path = cache / f"{name}-{draws}-{'full' if patch is None else 'x'.join(map(str, patch))}.npz"
    if path.is_file():
        z = np.load(path)
        data = {k: z[k] for k in ("depth", "gt", "photons", "snr", "static")}
        data["logit"] = z["logit"] if "logit" in z else None
        data["maps"] = {k[5:]: z[k] for k in z.files if k.startswith("maps_")}
        return data
    started = time.time()
    data = confidence_set(jaxsr.load_model(name), draws=draws, log=log, patch=patch)
    log(f"{name}: {draws} clips in {time.time() - started:.0f} s")
    cache.mkdir(parents=True, exist_ok=True)
    arrays = {k: data[k] for k in ("depth", "gt", "photons", "snr", "static")}
    arrays.update({f"maps_{k}": v for k, v in data["maps"].items()})
    if data["logit"] is not None:
        arrays["logit"] = data["logit"]
    tmp = path.with_suffix(".partial.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)
    return data


def fitted(data: dict) -> dict:
    """Coefficients fitted on the even clips, scored on the odd ones."""
    f = set_features(data)
    fit, val = f["clip"] % 2 == 0, f["clip"] % 2 == 1
    beta = fit_logistic(f["probability"][fit], f["returns"][fit])
    std = fit_depth_std(f["std"][fit], f["error_bins"][fit])
    p = 1.0 / (1.0 + np.exp(-(f["probability"][val] @ beta)))
    sigma = np.exp(f["std"][val] @ std)
    err = f["error_bins"][val]
    return {"probability": [round(float(b), 6) for b in beta], "std": [round(float(b), 6) for b in std],
            "validation": {"ece": expected_calibration_error(p, f["returns"][val]),
                           "auroc": auroc(p, f["returns"][val]),
                           "coverage_90": interval_coverage(err, np.zeros_like(err), sigma, INTERVAL_Z),
                           "pixels": int(val.sum()), "return_share": float(f["returns"][val].mean())},
            "fitted_pixels": int(fit.sum())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", nargs="+", default=["tr4-ambient"], help="bundled models with a no-return head")
    ap.add_argument("--draws", type=int, default=128, help="clips per model")
    ap.add_argument("--photons-draws", type=int, default=96, help="clips for the generic set without a head (tr4)")
    ap.add_argument("--photons-patch", type=int, nargs=2, default=(16, 16), metavar=("ROWS", "COLS"),
                    help="LR crops of the generic set's clips (default 16 x 16: less work for a set that no default "
                    "uses)")
    ap.add_argument("--patch", type=int, nargs=2, default=None, metavar=("ROWS", "COLS"),
                    help="LR crops of the clips (default: whole 32 x 64 frames, as recordings are read)")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/jaxsr-confidence"), help="where drawn sets are kept")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    started = time.time()
    log = lambda s: print(f"[{time.time() - started:6.0f} s] {s}", flush=True)  # noqa: E731
    models = {}
    for name in args.models:
        entry = fitted(drawn(name, args.draws, args.cache, log, args.patch))
        models[name] = {"head": True, "features": list(HEAD_FEATURES), **entry}
        log(f"{name}: {entry['validation']}")
    models["head"] = dict(models[args.models[0]], generic_of=args.models[0])
    entry = fitted(drawn("tr4", args.photons_draws, args.cache, log, tuple(args.photons_patch)))
    models["photons"] = {"head": False, "features": list(PHOTON_FEATURES), **entry, "fitted_with": "tr4"}
    log(f"photons (tr4): {entry['validation']}")
    command = "python " + " ".join([os.path.relpath(sys.argv[0])] + (sys.argv[1:] if argv is None else list(argv)))
    table = {"command": command, "machine": machine(), "date": datetime.date.today().isoformat(),
             "std_features": list(STD_FEATURES), "std_units": "log of the standard deviation in gate bins",
             "data": "jaxsr.training.confidence.confidence_set (CONFIDENCE_REGIME, key CONFIDENCE_SEED, "
                     + ("whole frames" if args.patch is None else f"{args.patch[0]} x {args.patch[1]} LR crops")
                     + f"; the generic set without a head: {args.photons_patch[0]} x {args.photons_patch[1]} LR crops"
                     + "); fitted on even clips, validation on odd", "models": models}
    write_text_atomic(args.out, json.dumps(table, indent=1) + "\n")
    log(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
