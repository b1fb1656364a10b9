"""How far local photon evidence can tell "no return" from a return, against what a photon model does with it.

    python experiments/studies/no_return_evidence.py                   # 3, 14 and 100 photons, tr4-photons
    python experiments/studies/no_return_evidence.py --photons 1 3 --frames 8

The goal is that at most 5 % of the pixels inside a no-return region come out as depth while at most
2 % of true returns are dropped, from 3 signal photons per LR pixel up (SNR 1.3). This measures how much of that
the photons around a pixel allow, before any network: on the benchmark's scenes with no-return regions
(experiments/studies/photon_regimes.py: the same scenes, regions, photon levels and SNR; noise keys of its own),
each LR pixel's histograms are summed over a square of s x s LR pixels centred on it and over the 2R + 1 frames of
a TR4 window (R = 4), and a detector thresholds one number of the sum. The pixels counted are those of the
benchmark's "interior" (an LR block whose 3 x 3 neighbourhood is all of one kind), where every HR pixel of a block
shares its label, so shares per LR pixel are shares per HR pixel.

For each pooling, the threshold is set where the detector drops as many true returns as the model does on the same
pixels (`--model`, default tr4-photons at its own no-return threshold), and the table gives the share of no-return
pixels it reads as a return there, beside the model's: where the detector is no better than the model, the model
uses what that pooling holds, and a lower share needs evidence from farther away. Detector statistics (higher =
more like a return), from the summed histogram's window of 2w + 1 bins around its largest bin (w the centre of
mass's): "excess" = photons in the window minus the window's share of those outside it (no median: it does not
collapse to zero at a few photons per histogram); "signal" = the photon models' own signal channel
(`jaxsr.sensor.peak_evidence`: above the median bin).
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
from photon_regimes import (  # beside this script
    NO_RETURN_AT,
    NO_RETURN_SNR,
    SEQUENCE_FRAMES,
    TEST_SCENES,
    _calibration,
    needed_frames,
    no_return_rates,
    with_no_return,
)
from scipy import ndimage

import jaxsr
from jaxsr.config import SensorConfig
from jaxsr.nn import network_inputs
from jaxsr.nn.duf import apply_model_raw
from jaxsr.sensor import ambient_only, calibrated_rates, default_window, normalise_depth, peak_evidence, sample_poisson

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import header, markdown_table, write_atomic  # noqa: E402
from harness.scoring import scored_frames  # noqa: E402

SCRIPT = "experiments/studies/no_return_evidence.py"
POOLS = (1, 3, 5, 7)  # LR pixels on a side of the square summed
PHOTONS = (3.0, 14.0, 100.0)
R = 4  # frames on either side of the scored one: a TR4 window reads 2R + 1
STATISTICS = ("excess", "signal")
# A decision without the truth, for comparison: no return also where `jaxsr.sensor.ambient_only` (GATE: LR pixels
# on a side, frames) finds ambient light alone at false-alarm rate alpha, and the model's logit is above a level
# (GATES)
GATE = (3, 2 * R + 1)
ALPHAS = (1e-3, 1e-6)
# (alpha, logit): the gate acts only where the model's no-return logit is above this (not sure of a return)
GATES = ((1e-3, -np.inf), (1e-6, -np.inf), (1e-3, -4.0), (1e-3, -2.0))


def statistics(counts, sensor: SensorConfig) -> dict:
    """(..., K) summed counts -> {name: (...)} detector statistics, higher = more like a return."""
    k = jnp.arange(counts.shape[-1])
    window = jnp.abs(k - jnp.argmax(counts, axis=-1)[..., None]) <= default_window(sensor)
    inside = jnp.sum(jnp.where(window, counts, 0.0), axis=-1)
    width = jnp.sum(window, axis=-1)
    outside_per_bin = (jnp.sum(counts, axis=-1) - inside) / jnp.maximum(counts.shape[-1] - width, 1)
    return {"excess": inside - width * outside_per_bin, "signal": peak_evidence(counts, sensor)[0]}


@functools.partial(jax.jit, static_argnames=("size",))
def box_sum(counts, size: int):
    """(T, h, w, K) -> the sum over size x size LR pixels centred on each (cut at the edges, as
    `jaxsr.sensor.ambient_only` sums)."""
    pad = size // 2
    padded = jnp.pad(counts, ((0, 0), (pad, pad), (pad, pad), (0, 0)))
    h, w = counts.shape[1:3]
    return sum(padded[:, dy:dy + h, dx:dx + w] for dy in range(size) for dx in range(size))


def lr_interior(share) -> np.ndarray:
    """(T, h, w) share of each LR block's HR pixels without a return -> True where the block and its 8
    neighbours are all of one kind (the benchmark's `interior`, per LR pixel)."""
    pure = [ndimage.minimum_filter((share == v).astype(np.uint8), size=(1, 3, 3), mode="nearest") for v in (0.0, 1.0)]
    return (pure[0] | pure[1]).astype(bool)


def read_as_return(stat_sky, stat_return, dropped_pct: float) -> float:
    """% of no-return pixels whose statistic reaches the threshold that drops `dropped_pct` % of the returns
    (those strictly below it)."""
    threshold = np.quantile(stat_return, dropped_pct / 100.0)
    return 100.0 * float(np.mean(stat_sky >= threshold))


def model_output(model, windows, batch: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """`model`'s (depth, no-return logit), each (N, H, W), on `windows`, before its decision."""
    run = jax.jit(lambda w: apply_model_raw(model.params, model.state, w, model.config))
    out = np.concatenate([np.asarray(run(jnp.asarray(windows[i:i + batch]))) for i in range(0, len(windows), batch)])
    return out[..., 0], out[..., 1]


def rates(no_return, gt, keep=None) -> tuple[float, float]:
    """(% of no-return HR pixels (gt >= 1) output as depth, % of returns dropped) of a no-return decision, over
    the pixels where `keep` (default all): the benchmark's `no_return_rates` of it."""
    keep = np.ones(np.shape(gt), bool) if keep is None else keep
    return no_return_rates(np.where(no_return, 1.0, 0.0)[keep], np.asarray(gt)[keep])


def measure(seqs, photons: float, snr: float, model, *, frames: int, seed: int, sensor: SensorConfig) -> dict:
    scored = scored_frames(frames, SEQUENCE_FRAMES)
    stats = {(s, t, name): [] for s in POOLS for t in (1, 2 * R + 1) for name in STATISTICS}
    labels, windows, gts, inside_hr, quiet = [], [], [], [], {a: [] for a in ALPHAS}
    for i, seq in enumerate(seqs.values()):
        alpha, beta = _calibration(jnp.asarray(seq.depth), jnp.asarray(seq.intensity), jnp.float32(snr),
                                   jnp.float32(photons), sensor)
        keep = needed_frames(scored, len(seq.depth), R)
        expected = calibrated_rates(jnp.asarray(seq.depth[keep]), jnp.asarray(seq.intensity[keep]), alpha, beta, sensor)
        counts = sample_poisson(jax.random.fold_in(jax.random.key(seed), i), expected, method="fast")
        gt = np.asarray(normalise_depth(jnp.asarray(seq.depth[keep]), sensor))
        t_, hh, ww = gt.shape
        share = (gt >= 1.0).reshape(t_, hh // sensor.scale, sensor.scale, ww // sensor.scale, sensor.scale).mean((2, 4))
        pos = np.searchsorted(keep, scored)
        window_of = np.clip(pos[:, None] + np.arange(-R, R + 1), 0, len(keep) - 1)
        inside = lr_interior(share[pos])
        labels.append(np.where(inside, share[pos], np.nan).ravel())
        for s in POOLS:
            pooled = box_sum(counts, s)
            for t, hist in ((1, pooled[pos]), (2 * R + 1, pooled[window_of].sum(axis=1))):
                for name, v in statistics(hist, sensor).items():
                    stats[(s, t, name)].append(np.asarray(v).ravel())
        for a in ALPHAS:  # the scored frames' windows are consecutive frames of `keep`: their sums are whole
            flag = np.asarray(ambient_only(counts, sensor, alpha=a, pixels=GATE[0], frames=GATE[1]))[pos]
            quiet[a].append(np.kron(flag, np.ones((1, sensor.scale, sensor.scale), np.uint8)).astype(bool))
        x = np.asarray(network_inputs(counts, sensor, model.config.inputs))
        windows.append(x[window_of])
        gts.append(gt[pos])
        inside_hr.append(np.kron(inside, np.ones((1, sensor.scale, sensor.scale), np.uint8)).astype(bool))
    label = np.concatenate(labels)
    sky, ret = label == 1.0, label == 0.0
    gt, inside_hr = np.concatenate(gts), np.concatenate(inside_hr)
    depth, logit = model_output(model, np.concatenate(windows))
    said = np.where(logit > model.config.no_return_logit, 1.0, depth) >= NO_RETURN_AT  # as merge_no_return
    as_depth, dropped = rates(said, gt, inside_hr)
    gated = {}
    for (a, unsure), q in ((k, q) for k in GATES for q in [quiet[k[0]]]):
        decision = said | (np.concatenate(q) & (logit > unsure))
        gated[f"{a:g}, {unsure:g}"] = {"interior": rates(decision, gt, inside_hr), "all": rates(decision, gt)}
    rows = {f"{s}x{s} px, {t} frame{'s' if t > 1 else ''}, {name}": read_as_return(
        np.concatenate(v)[sky], np.concatenate(v)[ret], dropped) for (s, t, name), v in stats.items()}
    return {"photons": photons, "snr": snr, "model_as_depth": as_depth, "model_dropped": dropped,
            "model_all": rates(said, gt), "gated": gated, "detectors": rows,
            "no_return_pixels": int(sky.sum()), "return_pixels": int(ret.sum())}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photons", type=float, nargs="+", default=list(PHOTONS),
                        help="signal photons per LR pixel (default 3 14 100)")
    parser.add_argument("--snr", type=float, default=NO_RETURN_SNR, help=f"frame SNR (default {NO_RETURN_SNR:g})")
    parser.add_argument("--frames", type=int, default=16, help="frames scored per test scene (default 16)")
    parser.add_argument("--model", default="tr4-photons", help="a photon model with a no-return head (TR4)")
    parser.add_argument("--seed", type=int, default=20, help="noise seed (the benchmark's are 0 and 1)")
    parser.add_argument("--out", default="experiments/results/no_return_evidence.md")
    args = parser.parse_args(argv)
    started = time.time()
    model = jaxsr.load_model(args.model)
    if not getattr(model.config, "no_return_head", False) or model.config.tr != R:
        raise SystemExit(f"--model: a TR{R} model with a no-return head, such as tr4-photons; got {args.model}")
    sensor = SensorConfig()
    seqs = with_no_return(jaxsr.scenes.test_sequences(n_frames=SEQUENCE_FRAMES, names=TEST_SCENES))
    results = []
    for p in args.photons:
        t0 = time.time()
        results.append(measure(seqs, p, args.snr, model, frames=args.frames, seed=args.seed, sensor=sensor))
        r = results[-1]
        print(f"{p:g} photons: model {r['model_as_depth']:.1f} % as depth / {r['model_dropped']:.2f} % dropped; "
              f"best detector {min(r['detectors'].values()):.1f} %; gated (all pixels) "
              + ", ".join(f"({k}): {v['all'][0]:.1f} % / {v['all'][1]:.2f} %" for k, v in r["gated"].items())
              + f" ({time.time() - t0:.0f} s)", flush=True)
    names = list(results[0]["detectors"])
    columns = ["pooled histogram, statistic"] + [f"{r['photons']:g} photons" for r in results]
    rows = [[f"**{args.model}** (its own threshold): as depth / dropped"]
            + [f"**{r['model_as_depth']:.1f} % / {r['model_dropped']:.2f} %**" for r in results]]
    rows += [[n] + [f"{r['detectors'][n]:.1f} %" for r in results] for n in names]
    pct = lambda pair: f"{pair[0]:.1f} % / {pair[1]:.2f} %"
    gate = (f"{GATE[0]}x{GATE[0]} px, {GATE[1]} frames")
    gated = [[f"{args.model} or ({gate} p > {a:g} where logit > {unsure:g}), {where}"]
             + [pct(r["gated"][f"{a:g}, {unsure:g}"][where]) for r in results]
             for a, unsure in GATES for where in ("interior", "all")]
    gated.insert(0, [f"{args.model}, all"] + [pct(r["model_all"]) for r in results])
    text = (header("Local photon evidence for no return, against a photon model", started)
            + f"Scenes: {', '.join(TEST_SCENES)} with the benchmark's no-return regions, {args.frames} frames each, "
            f"SNR {args.snr:g}, noise seed {args.seed}. Interior LR pixels only: "
            f"{results[0]['no_return_pixels']:,} without a return, {results[0]['return_pixels']:,} with one per "
            "photon level. First row: the model's share of no-return pixels output as depth and of returns "
            "dropped. Other rows: the share of no-return pixels a detector on the summed histogram reads as a "
            "return, at the threshold where it drops the model's share of returns (see the script's docstring).\n\n"
            + markdown_table(columns, rows)
            + "\nA decision without the truth, for comparison: the model's, plus no return wherever the "
            f"{gate} sum is consistent with ambient light alone (`jaxsr.sensor.ambient_only` at false-alarm rate "
            "alpha) where the model's no-return logit is above a level (-inf: everywhere; its own threshold is "
            f"{model.config.no_return_logit:g}). As depth / dropped, interior pixels and all pixels (edges "
            "included):\n\n"
            + markdown_table(columns, gated))
    write_atomic(Path(args.out), text)
    write_atomic(Path(args.out).with_suffix(".json"), json.dumps(results, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
