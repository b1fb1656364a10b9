"""The pools and holes of the default no-return decision: which neighbourhoods of quiet pixels
`jaxsr.sensor.ambient_only` pools (`pools`, `jaxsr.sensor.QUIET_POOLS`) before a pixel is output as no return, and
which quiet regions enclosed by returns are given back to a return instead (`jaxsr.sensor.without_holes`,
`jaxsr.sensor.HOLE_PIXELS`) and what depth they take (`jaxsr.inference.fill_holes`), on the test scenes and the
held-out scenes alike.

    python experiments/studies/quiet_pools.py --data /work/data/heldout

The default for histograms outputs no return where the confidence's P(return) is below one half and the LR pixel's
photons pass for ambient light alone (`jaxsr.upscale`, keep_returns "auto"). A dim wall's pixels each hold too few
photons over 9 frames to pass the test, so the network's no-return head decides them alone. Pooling the quiet
pixels around each (only those: a bright return beside the sky does not pool into it) finds the wall's return; it
costs the sky within a pool's reach of a dim surface. A quiet region that returns enclose on every side (a surface
that returns no photon at all: a black screen) is given back to a return in the default, up to a size, and where it
is black (`jaxsr.sensor.black_holes`) its depth is the harmonic interpolation of the inverse depth around it (or
the network's, or the harmonic of the depth, measured here); sky and ground beyond the gate reach the frame's
edge. The LR pixels beside a large quiet region (sky) hold a return in part of their block: `beside_sky` lets the
network's P(return) say which of their HR pixels are sky (measured here, not in the default: on the real tower
recording it drops the building's edge, real_photons_pools.md). For each choice, on the same photons and the same network outputs (tr4-ambient run once per scene and regime): PSNR
over all pixels (no return = 1.0, as the photon benchmark scores it), true returns dropped away from the edges of
no-return regions, and no return shown as depth.
Scenes: the three test scenes (4 frames of 500) and the held-out scenes (`heldout.py prepare`; 4 frames of 30).
Writes experiments/results/quiet_pools.md and .json beside it.
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
from jaxsr.app import AUTO_KEEP_RETURNS, Reading
from jaxsr.app.job import prepare_upscale
from jaxsr.config import DepthScale, Sensor
from jaxsr.inference import filled_where_holes, iter_super_resolve, lr_blocks
from jaxsr.inference.holes import _harmonic  # the fill's solver, here on depth itself: the alternative measured
from jaxsr.sensor import ambient_only, beside_sky, black_hole_pixels, without_holes

import _heldout_data  # beside this script
from _photon_benchmark import benchmark_clips, regime_key, regime_label, shares  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import header, markdown_table, write_atomic  # noqa: E402
from harness.scoring import SEQUENCE_FRAMES, TEST_SCENES, frame_scores, scored_frames  # noqa: E402

# pools; the largest enclosed quiet region given back to a return (`without_holes(max_pixels=...)`; 1: a lone
# pixel anywhere; None: every quiet pixel may be no return); the least quiet region whose bordering pixels the
# network's P(return) decides at HR (`beside_sky(min_pixels=...)`; None: not); the holes' depth (`FILLS`)
CHOICES = {"none (each pixel alone)": ((), None, None, None), "3": ((3,), None, None, None),
           "3, 5": ((3, 5), None, None, None), "3, 7": ((3, 7), None, None, None),
           "3, 5, 9": ((3, 5, 9), None, None, None), "3, 5, no lone pixel": ((3, 5), 1, None, None),
           "3, 5, holes up to 16": ((3, 5), 16, None, None), "3, 5, holes up to 64": ((3, 5), 64, None, None),
           "3, 5, holes up to 256": ((3, 5), 256, None, None),
           "3, 5, holes of any size": ((3, 5), 32 * 64, None, None),
           "3, 5, holes up to 64, filled in depth": ((3, 5), 64, None, "depth"),
           "3, 5, holes up to 64, filled in inverse depth (the default)": ((3, 5), 64, None, "inverse depth"),
           "3, 5, holes of any size, filled in inverse depth": ((3, 5), 32 * 64, None, "inverse depth"),
           "3, 5, holes up to 64, beside any quiet region": ((3, 5), 64, 0, None),
           "3, 5, holes up to 64, beside sky over 64": ((3, 5), 64, 64, None),
           "3, 5, holes up to 64, beside sky over 256": ((3, 5), 64, 256, None)}
# the depth of the holes given back to a return: None, the network's; "depth", the harmonic interpolation of the
# depth around them; "inverse depth", of the inverse depth (`jaxsr.inference.fill_holes`, the default)
FILLS = (None, "depth", "inverse depth")
REGIMES = ((3.0, 1.3), (14.0, 1.3), (14.0, 0.3), (100.0, 1.3), (1000.0, 5.0))


def network_outputs(clip) -> tuple[np.ndarray, np.ndarray, DepthScale]:
    """(raw HR normalised depth, P(return), the depth scale) of the clip's frames from `jaxsr.upscale`'s default
    model and confidence, before any no-return decision."""
    job = prepare_upscale(clip.counts, read=Reading(units="normalised"))
    raw = np.stack([out[..., 0] for out in iter_super_resolve(job.model, job.lr_frames(), raw=True)])
    p = np.stack([p for _, p, _ in job.iter_outputs()])
    return raw, p, job.scale


def decided(raw, p, counts, pools, max_hole, sky, fill=None, scale: DepthScale = DepthScale()) -> np.ndarray:
    """The default decision with `pools`: no return where P(return) < 1/2 and the LR pixel is quiet (with
    `max_hole`, not in a quiet region of at most that many pixels that returns enclose, nor alone, whose depth is
    `fill`'s where it is black (`FILLS`, on `scale`); with `sky`, or beside a quiet region of more than that many
    pixels)."""
    if fill not in FILLS:
        raise ValueError(f"decided: fill must be one of {FILLS}, got {fill!r}")
    flags = ambient_only(jnp.asarray(counts), Sensor(), alpha=AUTO_KEEP_RETURNS, pixels=1, pools=pools)
    quiet = flags if max_hole is None else without_holes(flags, max_hole)
    quiet = np.asarray(quiet if sky is None else beside_sky(quiet, sky))
    out = np.where(lr_blocks(quiet, Sensor().scale) & (p < 0.5), np.float32(1.0), raw)
    if fill is None or max_hole is None:
        return out
    holes = np.asarray(black_hole_pixels(jnp.asarray(counts), Sensor(), alpha=AUTO_KEEP_RETURNS, pools=pools,
                                         max_pixels=max_hole))
    if fill == "inverse depth":
        return np.stack([filled_where_holes(o, h, scale) for o, h in zip(out, holes)])
    at_hr = lr_blocks(holes, Sensor().scale)
    return np.stack([np.asarray(_harmonic(jnp.asarray(o), jnp.asarray(h), iterations=256)) if h.any() else o
                     for o, h in zip(out, at_hr)])


def score(groups: dict, frames: dict, seed: int = 0, log=print) -> list:
    rows = []
    for photons, snr in REGIMES:
        for group, seqs in groups.items():
            for name, seq in seqs.items():
                started = time.time()
                scored = scored_frames(frames[group], len(seq.depth))
                clips, _ = benchmark_clips({name: seq}, photons, snr, scored=scored, radius=4,
                                           key=regime_key(seed, photons, snr), counts=True)
                clip = clips[name]
                raw, p, scale = network_outputs(clip)
                row = {"group": group, "scene": name, "photons": photons, "snr": snr, "choices": {}}
                for label, (pools, max_hole, sky, fill) in CHOICES.items():
                    sr = decided(raw, p, clip.counts, pools, max_hole, sky, fill, scale)[clip.scored]
                    gt = clip.gt[clip.scored]
                    psnr, _ = frame_scores(sr, gt)
                    dropped, shown, n_ret, n_sky = shares(sr, gt)
                    row["choices"][label] = {"psnr": float(np.mean(psnr)), "dropped_pct": dropped,
                                             "as_depth_pct": shown}
                row["returns"], row["no_return"] = n_ret, n_sky
                rows.append(row)
                log(f"{group} {name}, {regime_label(photons, snr)}: " + ", ".join(
                    f"{k} {v['psnr']:.2f} dB" for k, v in row["choices"].items()) + f" ({time.time() - started:.0f} s)")
    return rows


def tables(rows) -> str:
    out = []
    for photons, snr in REGIMES:
        out.append(f"### {regime_label(photons, snr)}\n")
        table = []
        for label in CHOICES:
            line = [label]
            for group in ("test scenes", "held-out"):
                sel = [r for r in rows if r["group"] == group and r["photons"] == photons and r["snr"] == snr]
                if not sel:
                    line += ["-"] * 3
                    continue
                psnr = np.mean([r["choices"][label]["psnr"] for r in sel])
                ret = sum(r["returns"] for r in sel)
                sky = sum(r["no_return"] for r in sel)
                drop = sum(r["choices"][label]["dropped_pct"] * r["returns"] for r in sel) / ret if ret else np.nan
                shown = (sum(np.nan_to_num(r["choices"][label]["as_depth_pct"]) * r["no_return"] for r in sel) / sky
                         if sky else np.nan)
                line += [f"{psnr:.2f}", f"{drop:.3f}", "-" if np.isnan(shown) else f"{shown:.2f}"]
            table.append(line)
        out.append(markdown_table(["pools, holes", "test scenes: PSNR (dB)", "test scenes: dropped %",
                                   "test scenes: no return as depth %", "held-out: PSNR (dB)", "held-out: dropped %",
                                   "held-out: no return as depth %"], table))
        out.append("")
        per = [[r["group"], r["scene"]] + [f"{r['choices'][k]['psnr']:.2f}" for k in CHOICES]
               for r in rows if r["photons"] == photons and r["snr"] == snr]
        out.append(markdown_table(["group", "scene", *[f"{k}: PSNR" for k in CHOICES]], per))
        out.append("")
    return "\n".join(out)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(_heldout_data.DEFAULT_DATA),
                        help="the held-out data (heldout.py prepare)")
    parser.add_argument("--frames", type=int, default=4, help="frames scored per held-out scene")
    parser.add_argument("--test-frames", type=int, default=4, help="frames scored per test scene")
    parser.add_argument("--out", default="experiments/results/quiet_pools.md")
    args = parser.parse_args(argv)
    started = time.time()
    heldout = _heldout_data.load_scenes(args.data)
    if not heldout:
        raise SystemExit(f"quiet_pools.py: no held-out scenes in {args.data}: run heldout.py prepare first")
    groups = {"test scenes": jaxsr.scenes.test_sequences(n_frames=SEQUENCE_FRAMES, names=TEST_SCENES),
              "held-out": heldout}
    rows = score(groups, {"test scenes": args.test_frames, "held-out": args.frames})
    out = Path(args.out)
    text = "\n".join([
        header("The pools, holes and sky edges of the no-return decision", started),
        "",
        "The default decision for histograms (`jaxsr.upscale`: tr4-ambient, no return where P(return) < 1/2 and the LR "
        "pixel's photons pass for ambient light alone at 0.001) with each choice of the quiet pixels' pools "
        "(`jaxsr.sensor.ambient_only(pools=...)`), of the largest quiet region enclosed by returns that is given "
        "back to a return (`jaxsr.sensor.without_holes(max_pixels=...)`; 'no lone pixel': 1, a lone quiet "
        "pixel anywhere; 'any size': every enclosed region) and of its depth (the network's unless said; 'filled "
        "in depth' / 'in inverse depth': the harmonic interpolation of the depth / of the inverse depth around "
        "it, `jaxsr.inference.fill_holes`), and whether the P(return) decides the HR pixels of the "
        "LR pixels beside a quiet region larger than a size (`jaxsr.sensor.beside_sky(min_pixels=...)`; 'any': 0), "
        "on the same photons and network outputs. PSNR: mean over the "
        "group's scenes (over all pixels, no return = 1.0); dropped: true returns output as no return, of the "
        "returns whose 8 neighbours hold a return, pooled over the group; no return as depth: of the pixels without "
        "a return (the test scenes' sky and ground beyond the 35 m gate; the held-out scenes have none).",
        "",
        tables(rows),
    ])
    write_atomic(out, text + "\n")
    write_atomic(out.with_suffix(".json"), json.dumps(rows, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
