"""Rules that overrule a no-return head where the photons show a return, on the real tower recording.

The default for photons (tr4-ambient with `--keep-returns`, `jaxsr.inference.video.overrule_no_return`) keeps the
head's no return only where the LR block's own photons over 9 frames pass for ambient light alone. On tower that
gives back the building the head drops, and it shows the sky in the blocks that the building's outline crosses
as depth (simulated sky regions: 12-20 % of their sky at 14-1000 photons). This study asks whether a rule that
trusts the head more where a block's photons show a return gives the building back as well and the sky less. The
network runs once per level; each rule is applied to its output (depth and no-return logit per HR pixel):

- head: the head alone (logit above the model's threshold t);
- keep: the library's rule (`overrule_no_return`): head, and the block's photons pass for ambient light alone;
- split blocks: keep, but the head's no return also stands where it marks only part of a block (an edge it
  placed inside the block, which the block's photons showing a return does not contradict);
- signal >= S: keep, but the head also stands where the block's own signal (photons less the ambient estimate,
  `jaxsr.sensor.ambient_photons`, of its histogram summed over the 9 frames, per frame) reaches S, where it saw
  many photons (in simulation the head alone meets both no-return goals from 100 photons); S in photons, the
  same at every level;
- +d where a return: keep, but where the block's photons show a return the head stands above t + d.

Scores, on the photon video of `real_photons.py` at each level (the same permutation of photons): PSNR on the
valid pixels, % of them dropped, % of the reference's sky and of the sky beside the building (`edge_sky`) shown
as depth; and where the head drops the building: the photons per frame of the LR blocks in which it drops a
valid pixel against those of the blocks it keeps whole, the share of those blocks' pixels that are valid, and
its logit there. Run `python experiments/studies/keep_rules.py` (under a minute on 2 cores); tower.mat is read
from --data.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import jaxsr
from jaxsr.baselines import block_mean
from jaxsr.inference import lr_blocks
from jaxsr.inference.video import overrule_no_return
from jaxsr.sensor.peaks import window_sums
from jaxsr.training.no_return import no_return_outputs
from photon_regimes import no_return_decision  # experiments/studies
from real_photons import (DEFAULT_DATA, FACTOR, LEVELS, MAX_FRAMES, RESULTS, SOURCES, bin_pixels, histogram_frames,
                          masked_scores, model_input, photon_video, read_recording, references)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import header, markdown_table, write_atomic  # noqa: E402
from harness.scoring import frame_windows  # noqa: E402

KEEP_ALPHA = 1e-3  # the default's false-alarm rate (jaxsr.inference.AUTO_KEEP_RETURNS)
SIGNALS = (10.0, 30.0)  # S of "signal >= S", photons per LR pixel and frame
MARGINS = (2.0, 4.0)  # d of "+d where a return"
WINDOW = 9  # frames the keep test sums (a TR4 window)


def block_signal(counts, sensor, frames: int = WINDOW) -> np.ndarray:
    """(T, h, w) each LR pixel's signal photons per frame: its histograms summed over the `frames` frames centred
    on it (`window_sums`: cut at the sequence's ends), less their ambient estimate
    (`jaxsr.sensor.ambient_photons`), divided by the frames summed."""
    summed = window_sums(jnp.asarray(counts, jnp.float32), frames)
    present = window_sums(jnp.ones((len(summed), 1, 1, 1)), frames)[..., 0]  # frames inside each window
    signal = summed.sum(-1) - jaxsr.sensor.ambient_photons(summed, sensor)
    return np.asarray(signal / present)


def rules(depth, logit, quiet, signal, threshold: float) -> dict:
    """{rule: HR output (F, H, W)} of the head's depth and logit (F, H, W), the keep test's `quiet` (F, h, w) and
    the blocks' `signal` (F, h, w), for each rule of the module's docstring."""
    r = depth.shape[-1] // quiet.shape[-1]
    raw = np.stack([depth, logit], axis=-1)
    head = logit > threshold

    def trusted(where):  # the library's rule, the head also standing where `where` (F, h, w) says so
        return overrule_no_return(raw, quiet | where, threshold)

    def above(d):  # the head at the threshold where the block is quiet, at the threshold + d elsewhere
        return np.where((head & lr_blocks(quiet, r)) | (logit > threshold + d), np.float32(1.0), depth)

    return {"head": np.where(head, np.float32(1.0), depth),
            "keep": trusted(np.zeros_like(quiet)),
            "split blocks": trusted(block_mean(head, r) < 1.0),  # the head marks part of the block
            **{f"signal >= {s:g}": trusted(signal >= s) for s in SIGNALS},
            **{f"+{d:g} where a return": above(d) for d in MARGINS}}


def _percentiles(values) -> str:
    """10th / 50th / 90th percentiles, "-" for none."""
    values = np.asarray(values, float)
    return " / ".join(f"{v:.1f}" for v in np.percentile(values, [10, 50, 90])) if values.size else "-"


def evaluate(rec, model, *, levels=LEVELS, max_frames: int = MAX_FRAMES, seed: int = 0, log=print) -> list[dict]:
    """Each level: {"level", "frames", "outputs": {rule: (F, H, W)}, "scores": {rule: masked_scores}, "drops":
    {...}} on `rec`'s photon video (the permutation `real_photons.evaluate` draws for its first recording)."""
    refs = references(rec)
    lr_tags = bin_pixels(rec.tags)
    valid_share = block_mean(refs.valid, FACTOR)  # of each block's pixels
    out = []
    for k, level in enumerate(levels):
        t0 = time.time()
        video = photon_video(lr_tags, level, max_frames=max_frames, seed=(seed, 0, k))
        if video is None:
            log(f"{level:g} photons: fewer photons than one frame needs, skipped")
            continue
        frames, _ = histogram_frames(video, rec.gate, rec.scale)
        sensor = jaxsr.SensorConfig(bins=frames.gate.bins)
        t = np.arange(len(frames.depth))
        depth, logit = (np.asarray(a) for a in
                        no_return_outputs(model, frame_windows(model_input(model, frames), t, model.config.tr)))
        quiet = np.asarray(no_return_decision(frames.counts, sensor, ("keep", KEEP_ALPHA)))
        outputs = rules(depth, logit, quiet, block_signal(frames.counts, sensor), model.config.no_return_logit)
        scores = {name: masked_scores(sr, refs.depth, refs.valid, refs.sky, refs.edge, None, refs.beside)
                  for name, sr in outputs.items()}
        dropped = (logit > model.config.no_return_logit) & refs.valid
        photons = frames.counts.sum(-1)
        in_drop = block_mean(dropped, FACTOR) > 0
        kept_whole = (valid_share == 1.0) & ~in_drop
        share = np.broadcast_to(valid_share, in_drop.shape)[in_drop]  # of the blocks with a drop
        out.append({"level": float(level), "frames": len(t), "outputs": outputs, "scores": scores,
                    "drops": {"blocks": _percentiles(photons[in_drop]), "whole": _percentiles(photons[kept_whole]),
                              "valid": _percentiles(100 * share), "logit": _percentiles(logit[dropped])}})
        log(f"{level:g} photons, {len(t)} frames: " + ", ".join(f"{m} {s['psnr'].mean():.2f} dB"
                                                              for m, s in scores.items())
            + f" ({time.time() - t0:.0f} s)")
    return out


def report(results, names) -> str:
    def rows(key, fmt):
        return [[f"{e['level']:g}"] + [fmt(e["scores"][m][key]) for m in names] for e in results]

    def pct(values):
        return "-" if np.all(np.isnan(values)) else f"{100 * np.nanmean(values):.1f}"

    text = ["### PSNR (dB) on the valid pixels\n\n"
            + markdown_table(["photons", *names], rows("psnr", lambda v: f"{v.mean():.2f}")),
            "### % of the valid pixels output as no return\n\n"
            + markdown_table(["photons", *names], rows("no_return", pct)),
            "### % of the sky beside the building output as depth (`edge_sky`)\n\n"
            + markdown_table(["photons", *names], rows("edge_sky_as_depth", pct)),
            "### % of the reference's sky output as depth (`reference_sky`)\n\n"
            + markdown_table(["photons", *names], rows("sky_as_depth", pct)),
            "### Where the head drops the building\n\nPhotons per frame of the LR blocks in which the head alone "
            "drops a valid pixel, and of the blocks whose pixels are all valid and all kept; the % of a block's "
            "pixels that are valid, in the blocks with a drop (below 100: the building's outline or a gap crosses "
            "the block); the head's logit on the dropped pixels (10th / 50th / 90th percentiles over the blocks, or "
            "pixels, of all the frames).\n\n"
            + markdown_table(["photons", "blocks with a drop", "blocks kept whole", "% valid, blocks with a drop",
                              "logit at the drops"],
                             [[f"{e['level']:g}", e["drops"]["blocks"], e["drops"]["whole"], e["drops"]["valid"],
                               e["drops"]["logit"]] for e in results])]
    return "\n".join(text)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(DEFAULT_DATA) if DEFAULT_DATA.is_dir() else None,
                        help="folder holding tower.mat (default ../shared/realdata beside the repository)")
    parser.add_argument("--model", default="tr4-ambient", help="a model with a no-return head (default tr4-ambient)")
    parser.add_argument("--levels", type=float, nargs="+", default=list(LEVELS),
                        help="photons per LR pixel and frame (default 1 2 4 8 16)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the photon permutations")
    parser.add_argument("--out", default=str(RESULTS / "keep_rules.md"), help="the results file")
    args = parser.parse_args(argv)
    if args.data is None:
        raise SystemExit(f"no recordings: {DEFAULT_DATA} does not exist; give the folder with --data")
    started = time.time()
    model = jaxsr.load_model(args.model)
    if not getattr(model.config, "no_return_head", False):
        raise SystemExit(f"--model {args.model}: the model has no no-return head, so no decision to overrule")
    rec = read_recording(args.data, SOURCES[0])
    results = evaluate(rec, model, levels=args.levels, seed=args.seed)
    names = list(results[0]["scores"]) if results else []
    text = (header("Rules overruling a no-return head, on the tower recording", started)
            + f"Model {args.model} at its no-return threshold {model.config.no_return_logit:g}; the photon video "
            f"and reference of experiments/studies/real_photons.py (seed {args.seed}); the keep test at a "
            f"false-alarm rate of {KEEP_ALPHA:g} over {WINDOW} frames. The rules: the docstring of "
            "experiments/studies/keep_rules.py. The recording is third-party and not part of the project.\n\n"
            + report(results, names))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, text)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
