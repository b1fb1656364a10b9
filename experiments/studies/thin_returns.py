"""Thin returns against the sky: do the no-return heads keep a pole, a cable or a lattice tower's beams?

    python experiments/studies/thin_returns.py                                  # tr4-photons and tr4-ambient
    python experiments/studies/thin_returns.py --model NAME=runs/photons/RUN/best.npz --widths 4 8

Why: on the real tower recording (experiments/studies/real_photons.py), a lattice tower against a dark sky,
tr4-ambient's head outputs 1.6-4.3 % of the tower's returns as no return, 43-73 % of them next to the sky (its
beams, and the returns seen through the lattice); without the decision its depth is 4-15 dB above bicubic there,
with it up to 12 dB below (experiments/results/real_photons_decisions.md). The models' training drew its no-return regions as blobs and bands
(`jaxsr.sensor.no_return_regions`), with no thin structure in front of them.

Data: the regime benchmark's test depth with no-return regions (experiments/studies/photon_regimes.py,
`with_no_return`: 30 % of the HR pixels, sky weight 0.5, one mask per scene), crossed by `--lines` thin returns
per scene (`jaxsr.sensor.thin_returns`, widths log-uniform in `--widths` HR pixels, one draw per scene, the
scene's own depth on them) at `--photons` signal photons per LR pixel and frame SNR `--snr` (45: a recording
with little ambient light, as tower's), `--frames` frames per scene. Scored per method, pooled over scenes and
frames: the share of the lines' HR pixels inside the regions output as no return (normalised >= 0.99), the share
of the pixels without a return (the regions' and the scenes' own sky) output as depth, the share of the other
returns dropped, and the mean PSNR. Each regime's noise comes from its photons and SNR, so a run of a few
regimes draws what the full run draws for them.

Writes experiments/results/thin_returns.md (or --out) and a .json of the numbers beside it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import jax
import numpy as np

import jaxsr
from jaxsr.sensor import thin_returns
from photon_regimes import (MAJORITY, NO_RETURN_AT, block_majority, load_models, method_scores,  # studies/
                            regime_clips, vars_of, with_no_return)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import header, markdown_table, write_atomic  # noqa: E402
from harness.scoring import SEQUENCE_FRAMES, TEST_SCENES, scored_frames, scored_output  # noqa: E402

LINES = 6
WIDTHS = (1.0, 4.0)  # HR pixels: a quarter of an LR pixel to one, as thin as a lattice tower's beams
PHOTONS = (3.0, 14.0, 100.0)
SNRS = (1.3, 45.0)


def crossed(seqs: dict, *, lines: int = LINES, widths=WIDTHS, seed: int = 0) -> tuple[dict, dict]:
    """The benchmark's sequences with no-return regions (`with_no_return`), crossed by `lines` thin returns each
    (the scene's own depth on them). Returns (sequences, {name: (H, W) bool, the lines' pixels inside the
    regions})."""
    holed = with_no_return(seqs, seed=seed)
    out, masks = {}, {}
    for i, (name, seq) in enumerate(seqs.items()):
        regions = np.all(np.isinf(holed[name].depth) & ~np.isinf(seq.depth), axis=0)
        on = np.asarray(thin_returns(jax.random.key(20_000 + 100 * seed + i), regions.shape, lines=lines,
                                     width_range=widths, max_lines=lines))
        depth = np.where(on, np.asarray(seq.depth), holed[name].depth)
        out[name] = SimpleNamespace(**{**vars_of(seq), "depth": depth})
        masks[name] = on & regions
    return out, masks


def shares(sr, gt, lines) -> dict:
    """Counts of one scene's pixels by kind and fate, (T, H, W) output and truth, (H, W) line mask: the lines'
    pixels with a return (`lines`, `lines_dropped`: output as no return), the pixels without one (`sky`: the
    regions and the scene's own sky; `sky_as_depth`), the other returns (`returns`, `returns_dropped`)."""
    sr, gt = np.asarray(sr), np.asarray(gt)
    gone = ~(sr < NO_RETURN_AT)  # NaN counts as no return
    on = np.broadcast_to(lines, sr.shape) & (gt < 1.0)
    sky = gt >= 1.0
    other = ~sky & ~on
    return {"lines": int(on.sum()), "lines_dropped": int(gone[on].sum()), "sky": int(sky.sum()),
            "sky_as_depth": int((~gone[sky]).sum()), "returns": int(other.sum()),
            "returns_dropped": int(gone[other].sum())}


def pooled_shares(counts) -> dict:
    """% of each kind over all the scenes' pixels together (`shares` of each scene summed); NaN for a kind
    without pixels."""
    total = {k: sum(c[k] for c in counts) for k in counts[0]}
    share = lambda part, whole: 100.0 * total[part] / total[whole] if total[whole] else float("nan")
    return {"lines_dropped": share("lines_dropped", "lines"), "sky_as_depth": share("sky_as_depth", "sky"),
            "returns_dropped": share("returns_dropped", "returns"), "line_pixels": total["lines"]}


def majority_output(clip, scale: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """The truth with one no-return decision per LR block known from it (`block_majority`: no return where half
    the block has none): what any decision made per LR pixel costs thin returns, with exact depth elsewhere."""
    gt = clip.gt[clip.scored]
    return np.stack([np.where(block_majority(g >= 1.0, scale), 1.0, g) for g in gt]), gt


def regime_key(seed: int, photons: float, snr: float):
    """The noise key of a regime, from its photons and SNR: a run of a few regimes draws what the full run
    draws for them."""
    return jax.random.fold_in(jax.random.fold_in(jax.random.key(seed + 2), round(1000 * photons)),
                              round(1000 * snr))


def evaluate(models: dict, seqs: dict, masks: dict, *, frames: int, photons=PHOTONS, snrs=SNRS, seed: int = 0,
             log=print) -> list:
    total = len(next(iter(seqs.values())).depth)
    scored = scored_frames(frames, total)
    radius = max(m.config.tr for m in models.values())
    rows = []
    for p, s in ((float(p), float(s)) for p in photons for s in snrs):
        started = time.time()
        clips, _ = regime_clips(seqs, p, s, scored=scored, radius=radius, key=regime_key(seed, p, s))
        row = {"photons": p, "snr": s, "methods": {}}
        for label, model in {"bicubic": None, **models, MAJORITY: None}.items():
            outs = [majority_output(c) if label == MAJORITY else scored_output(model, c) if model else
                    (np.asarray(jaxsr.bicubic(c.lr[c.scored], scale=4)), c.gt[c.scored]) for c in clips.values()]
            row["methods"][label] = {**pooled_shares([shares(sr, gt, masks[name])
                                                      for name, (sr, gt) in zip(clips, outs)]),
                                     "psnr": float(method_scores(outs)["psnr"].mean())}
        rows.append(row)
        log(f"{p:g} photons, SNR {s:g}: " + ", ".join(
            f"{m} lines dropped {v['lines_dropped']:.1f} %, sky as depth {v['sky_as_depth']:.1f} %"
            for m, v in row["methods"].items()) + f" ({time.time() - started:.0f} s)")
    return rows


def tables(rows) -> str:
    methods = list(rows[0]["methods"])
    head = ["photons", "SNR"] + methods
    text = ""
    for key, title in (("lines_dropped", "% of the thin returns' pixels output as no return"),
                       ("sky_as_depth", "% of the pixels without a return (the regions', the scenes' own sky) output as depth"),
                       ("returns_dropped", "% of the other true returns output as no return"),
                       ("psnr", "Mean PSNR (dB; outputs clipped to [0, 1])")):
        fmt = "{:.2f}" if key == "psnr" else "{:.1f}"
        text += f"### {title}\n\n" + markdown_table(head, [[f"{r['photons']:g}", f"{r['snr']:g}"] + [
            fmt.format(r["methods"][m][key]) for m in methods] for r in rows]) + "\n"
    return text


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=4, help="frames scored per test scene (default 4)")
    parser.add_argument("--photons", type=float, nargs="+", default=list(PHOTONS))
    parser.add_argument("--snr", type=float, nargs="+", default=list(SNRS))
    parser.add_argument("--lines", type=int, default=LINES, help="thin returns per scene")
    parser.add_argument("--widths", type=float, nargs=2, default=list(WIDTHS), metavar=("LO", "HI"),
                        help="their widths, HR pixels (log-uniform)")
    parser.add_argument("--model", action="append", default=[], metavar="NAME=PATH",
                        help="a model to score besides tr4-photons and tr4-ambient; repeatable")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="experiments/results/thin_returns.md")
    args = parser.parse_args(argv)
    started = time.time()
    specs = ["TR4-photons=tr4-photons", "TR4-ambient=tr4-ambient", *args.model]
    models, info, _ = load_models(specs)
    models = {k: v for k, v in models.items() if k not in ("TR0", "TR4")}  # no head: every line survives
    seqs, masks = crossed(jaxsr.scenes.test_sequences(n_frames=SEQUENCE_FRAMES, names=TEST_SCENES),
                          lines=args.lines, widths=tuple(args.widths), seed=args.seed)
    rows = evaluate(models, seqs, masks, frames=args.frames, photons=args.photons, snrs=args.snr, seed=args.seed)
    share = np.mean([m.mean() for m in masks.values()])
    text = (header("Thin returns against the sky", started)
            + f"Test scenes {', '.join(TEST_SCENES)} with the regime benchmark's no-return regions, each crossed by "
            f"{args.lines} thin returns {args.widths[0]:g}-{args.widths[1]:g} HR pixels wide "
            f"(`jaxsr.sensor.thin_returns`; {100 * share:.1f} % of the HR pixels are line inside a region), "
            f"{args.frames} frames per scene, noise seed {args.seed}. Models: "
            + "; ".join(f"{k}: {info[k]}" for k in models) + f". `{MAJORITY}`: the truth with one no-return "
            "decision per 4 x 4 block known from it (no return where half the block has none), what deciding per "
            "LR pixel costs thin returns at best (its PSNR: that decision's cost alone, with exact depth). No "
            f"return: normalised output >= {NO_RETURN_AT:g}.\n\n" + tables(rows))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, text)
    write_atomic(out.with_suffix(".json"), json.dumps({"rows": rows, "models": {k: info[k] for k in models},
                                                       "settings": vars(args)}, indent=1) + "\n")
    print(f"wrote {out} and {out.with_suffix('.json')}")


if __name__ == "__main__":
    main()
