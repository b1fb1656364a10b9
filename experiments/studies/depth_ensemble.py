"""Whose depth the returns take: the default model's own (tr4-ambient), the paper's TR4's, or their mean, by photon
level, on the held-out scenes and the test scenes (`jaxsr.app.DEPTH_ENSEMBLE` is decided here).

    python experiments/studies/depth_ensemble.py --data /work/data/heldout          # every regime (about 40 min)
    python experiments/studies/depth_ensemble.py --data /work/data/heldout --report-only

In every regime of the held-out benchmark (`_heldout_data.regimes`), on the same photons (`benchmark_clips`, 4 frames
of each scene) and with the same no-return decision (the default's: tr4-ambient's head, the confidence and the
pools, `jaxsr.upscale` with the model named, so that no other depth enters), the returns it outputs get:
- "own": tr4-ambient's depth (the default below `DEPTH_ENSEMBLE`'s bounds);
- "TR4's": the paper's TR4's depth where it outputs a return too;
- "mean": the mean of the two depths where both output a return (`jaxsr.app.job.ensemble_depth`: the default
  above the bounds);
- "nearer the photons, z Z": in each LR block, the paper's TR4's depth where its mean over the block's returns lies
  nearer the block's measured centre of mass than tr4-ambient's by more than Z of the centre of mass's standard
  deviations (`nearer_the_photons`), tr4-ambient's elsewhere;
beside the paper's TR4 alone (its own output, as the held-out benchmark scores it). Also the photon levels each
recording measures (`jaxsr.app.photon_levels`: the default decides on them) and which depth the default takes.
Results: experiments/results/depth_ensemble.md and .json (each scene-regime kept in the .json as it is done).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import jaxsr
from jaxsr.app import DEFAULT_MODELS, DEPTH_ENSEMBLE, Reading, photon_levels
from jaxsr.app.job import ensemble_depth
from jaxsr.config import Sensor
from jaxsr.inference.confidence import NO_RETURN_AT
from jaxsr.sensor import centre_of_mass, centre_of_mass_std

import _heldout_data  # beside this script
from _photon_benchmark import PHOTONS, SNRS, benchmark_clips, regime_key, regime_label

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import header, markdown_table, write_atomic  # noqa: E402
from harness.scoring import SEQUENCE_FRAMES, TEST_SCENES, frame_scores, scored_frames, scored_output  # noqa: E402

OWN, TR4S, MEAN, ALONE = "own", "TR4's", "mean", "paper's TR4 alone"
NEARER = {f"nearer the photons, z {z:g}": z for z in (0.0, 1.0, 2.0)}
DEPTHS = (OWN, TR4S, MEAN, *NEARER, ALONE)
GROUPS = ("held-out", "test scenes")


def block_returns_mean(hr, r: int):
    """(F, H, W) HR normalised depth -> ((F, H / r, W / r) mean of each r x r block's returns, their number)."""
    f, h, w = hr.shape
    returns = hr < NO_RETURN_AT
    total = np.where(returns, hr, 0.0).reshape(f, h // r, r, w // r, r).sum(axis=(2, 4))
    count = returns.reshape(f, h // r, r, w // r, r).sum(axis=(2, 4))
    return total / np.maximum(count, 1), count


def nearer_the_photons(own, other, lr_depth, lr_std, z: float) -> np.ndarray:
    """`own` with `other`'s depth in the LR blocks where `other`'s mean over the block's returns lies nearer the
    measured centre of mass `lr_depth` than `own`'s by more than `z` x `lr_std`, where both hold a return."""
    r = own.shape[-1] // lr_depth.shape[-1]
    (own_mean, own_n), (other_mean, other_n) = block_returns_mean(own, r), block_returns_mean(other, r)
    gain = np.abs(own_mean - lr_depth) - np.abs(other_mean - lr_depth)
    nearer = (gain > z * lr_std) & (own_n > 0) & (other_n > 0) & (lr_depth < NO_RETURN_AT)
    nearer = np.kron(nearer, np.ones((1, r, r), bool))
    return np.where(nearer & (own < NO_RETURN_AT) & (other < NO_RETURN_AT), other, own)


def depths(clip, tr4) -> dict:
    """{depth: (F, H, W) normalised output on the clip's scored frames} for `DEPTHS`."""
    own = np.asarray(jaxsr.upscale(clip.counts, None, model=DEFAULT_MODELS["histograms"],
                                   read=Reading(units="normalised")).depth)[clip.scored]
    alone = scored_output(tr4, clip)[0]
    returns = (own < NO_RETURN_AT) & (alone < NO_RETURN_AT)
    counts = jnp.asarray(clip.counts[clip.scored])
    sensor = Sensor()
    lr_depth = np.asarray(centre_of_mass(counts, sensor))
    lr_std = np.asarray(centre_of_mass_std(counts, sensor)) / sensor.bins
    nearer = {name: nearer_the_photons(own, alone, lr_depth, lr_std, z) for name, z in NEARER.items()}
    return {OWN: own, TR4S: np.where(returns, alone, own), MEAN: ensemble_depth(own, alone), **nearer,
            ALONE: alone}


def score(groups: dict, grid, path: Path, frames: int, log=print) -> dict:
    """{key: {"signal", "snr", depth: mean PSNR}} for every scene and regime, kept in `path` as each is done."""
    done = json.loads(path.read_text()) if path.is_file() else {}
    tr4 = jaxsr.load_model("paper-tr4")
    for photons, snr in grid:
        for group, seqs in groups.items():
            for name, seq in seqs.items():
                key = f"{group}|{name}|{photons:g}|{'own' if snr is None else f'{snr:g}'}"
                if key in done:
                    continue
                scored = scored_frames(frames, len(seq.depth))
                clips, _ = benchmark_clips({name: seq}, photons, snr, scored=scored, radius=4,
                                           key=regime_key(0, photons, snr), counts=True)
                clip = clips[name]
                levels = photon_levels(clip.counts, clip.counts.shape[-1])
                gt = clip.gt[clip.scored]
                entry = {"signal": float(levels.signal), "snr": float(levels.snr)}
                for depth, sr in depths(clip, tr4).items():
                    entry[depth] = float(np.mean(np.asarray(frame_scores(sr, gt)[0])))
                done[key] = entry
                write_atomic(path, json.dumps(done, indent=1) + "\n")
                log(f"{key}: signal {entry['signal']:.1f}, SNR {entry['snr']:.2f}, "
                    + ", ".join(f"{d} {entry[d]:.2f}" for d in DEPTHS))
    return done


def report(done: dict, grid) -> str:
    """The table: per regime, the measured levels, each group's mean PSNR of each depth, and the default's pick."""
    rows = []
    for photons, snr in grid:
        regime = f"|{photons:g}|{'own' if snr is None else f'{snr:g}'}"
        levels = [e for k, e in done.items() if k.endswith(regime)]
        if not levels:
            continue
        cells = [regime_label(photons, snr),
                 f"{np.median([e['signal'] for e in levels]):.0f} / {np.median([e['snr'] for e in levels]):.2f}"]
        for group in GROUPS:
            entries = [e for k, e in done.items() if k.startswith(f"{group}|") and k.endswith(regime)]
            mean = {d: float(np.mean([e[d] for e in entries])) for d in DEPTHS} if entries else None
            cells += ([f"{mean[d]:.2f}" for d in DEPTHS] + [f"{mean[MEAN] - mean[ALONE]:+.2f}"] if mean
                      else ["-"] * (len(DEPTHS) + 1))
        picks = [DEPTH_ENSEMBLE.applies(e["signal"], e["snr"]) for e in levels]
        cells.append(MEAN if all(picks) else OWN if not any(picks) else f"{MEAN} in {sum(picks)} of {len(picks)}")
        rows.append(cells)
    columns = (["regime", "measured signal / SNR (median)"]
               + [f"{g}: {d}" for g in GROUPS for d in (*DEPTHS, f"{MEAN} - {ALONE}")] + ["the default takes"])
    return markdown_table(columns, rows)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(_heldout_data.DEFAULT_DATA), help="the folder heldout.py prepare wrote")
    ap.add_argument("--frames", type=int, default=4, help="frames scored per scene (default 4)")
    ap.add_argument("--report-only", action="store_true", help="write the report of the .json's scores")
    ap.add_argument("--out", default="experiments/results/depth_ensemble.md")
    args = ap.parse_args(argv)
    started = time.time()
    out = Path(args.out)
    grid = _heldout_data.regimes(PHOTONS, SNRS)
    grid = sorted(grid, key=lambda r: -r[0])  # the bright regimes, where the depths differ most, first
    if args.report_only:
        done = json.loads(out.with_suffix(".json").read_text())
    else:
        groups = {"held-out": _heldout_data.load_scenes(args.data),
                  "test scenes": jaxsr.scenes.test_sequences(n_frames=SEQUENCE_FRAMES, names=TEST_SCENES)}
        done = score(groups, grid, out.with_suffix(".json"), args.frames)
    text = (header("Whose depth the returns take: tr4-ambient's, the paper's TR4's or their mean", started)
            + "Scores: `python experiments/studies/depth_ensemble.py --data DIR` (kept in the .json beside this file, "
            f"which `--report-only` reads). Mean PSNR (dB) over the scenes of each group ({args.frames} frames each, "
            "noise seed 0), every depth under the default's no-return decision (tr4-ambient's head, the confidence and "
            "the pools); the paper's TR4 alone beside them (its own output, no return included, as the held-out "
            "benchmark scores it). The default takes the mean where a recording measures "
            f"{DEPTH_ENSEMBLE.min_signal:g} signal photons per LR pixel or more at a frame SNR of "
            f"{DEPTH_ENSEMBLE.min_snr:g} or more (`jaxsr.app.DEPTH_ENSEMBLE`).\n\n" + report(done, grid))
    write_atomic(out, text)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
