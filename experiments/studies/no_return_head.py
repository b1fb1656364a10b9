"""Refitting a photon model's no-return branch on its own features: how much of the no-return error at the
regions' edges the branch can still remove while the trunk stays as trained, and how much HR convolutions after it
can.

    python experiments/studies/no_return_head.py                       # tr4-ambient, about 30 min on 2 CPU cores
    python experiments/studies/no_return_head.py --draws 256 --steps 200 --frames 2 --out /tmp/head.md  # a try

The no-return goal (at most 5 % of the no-return pixels output as depth, at most 2 % of the true returns dropped,
from 3 signal photons per LR pixel up, SNR 1.3) is met inside the regions and missed at their edges
(experiments/results/photon_regimes_ambient_test.md, no_return_edges.md). The no-return branch is two 1x1x1
convolutions on the head's features (`jaxsr.nn.no_return_logits`), 70 k of the network's parameters; if its
error at the edges came from the branch (too little training at the edges, a loss that weighs the edges little),
refitting the branch alone would remove it, at a cost a CPU affords: the features of a training set are computed
once (`jaxsr.nn.apply_model_features`) and the branch trains on them by Adam on the head's cross-entropy. If it
does not, the features are what limit the decision, and only training the whole network (a GPU) can move it.
The branch decides each HR pixel from its LR pixel's features alone; an edge inside an LR block might instead be
placed from the decisions around it (as interpolating the blocks' true shares places it, no_return_edges.md), so a
third fit keeps the bundled branch and adds three 3 x 3 convolutions at HR over its logit, the network's depth and
the LR pixel's inputs (`hr_inputs`; a field of 15 x 15 HR pixels, about four LR blocks across), trained on the
same windows with the same loss and started at the bundled branch's decision (up to float16 rounding).

Steps:
1. Training set: `--draws` windows of 16 x 16 LR pixels from the wide photon regime with no-return regions on
   every clip (`jaxsr.training.no_return_set`, photons log-uniform 2-1000, every SNR of the regime), drawn from
   `jax.random.key(REFIT_SEED)`: apart from the calibration's, the benchmark's and any training run's keys.
2. The branch, started from the model's, trained `--steps` steps of 32 windows (Adam `--lr`, cut tenfold for the
   last 30 %); the trunk, the depth branches and the batch norms are left alone, so the depth output is the same.
   The HR convolutions the same way, on the bundled branch's logits of the same windows.
3. Each decision's threshold chosen as `jaxsr.training.calibrate_no_return` chooses it, on the calibration set
   (`no_return_set`'s defaults: whole frames, photons 3-1000, `CALIBRATION_SEED`).
4. All three on the benchmark's scenes and regions (experiments/studies/photon_regimes.py's no-return test:
   `--frames` frames per scene, SNR 1.3, its noise keys): over all pixels and inside the regions, at the chosen
   threshold and at the threshold that is best on these very pixels (the smallest share "as depth" with at most
   2 % dropped: in-sample, a bound on what any threshold on that decision gives, not a result to quote).

Static scenes (every training clip of the photon models moved; real recordings are static): `--static-prob P`
draws that share of the training and calibration windows from static clips (`PhotonRegime.static_prob`), and
`--static` benchmarks static scenes as photon_regimes.py --static does; `--hr-steps 0` leaves the HR convolutions out.

Writes experiments/results/no_return_head.md (or --out) and a .json beside it; `--save PATH` also saves the
refitted model (a .npz for `--model` of the benchmarks).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxsr
from jaxsr.config import PhotonRegime
from jaxsr.io.checkpoint import resolve_model_path, save_model
from jaxsr.nn import apply_model_features, no_return_logits
from jaxsr.nn.layers import conv2d, glorot_limit
from jaxsr.training import CALIBRATION_SEED, no_return_outputs, no_return_set
from jaxsr.training.duf import no_return_cross_entropy
from jaxsr.training.no_return import DEFAULT_THRESHOLDS, choose_no_return_logit, no_return_table
from jaxsr.training.optim import adam_init, adam_update

from _photon_benchmark import (AMBIENT_RADIUS, GOAL_AS_DEPTH, GOAL_DROPPED, NO_RETURN_MIN_PHOTONS, NO_RETURN_SNR,
                               benchmark_clips, check_static, interior, no_return_rates, with_no_return)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import header, markdown_table, write_atomic  # noqa: E402
from harness.scoring import SEQUENCE_FRAMES, TEST_SCENES, frame_windows, scored_frames  # noqa: E402

SCRIPT = "experiments/studies/no_return_head.py"
REFIT_SEED = 2**31 - 3  # the training set's root key: apart from CALIBRATION_SEED (2**31 - 2) and the validation's
PATCH = (16, 16)  # LR rows, cols of a training window
BATCH = 32  # windows per step
CUT_AT = 0.7  # the learning rate drops tenfold after this share of the steps
CALIBRATION_DRAWS = 192  # as experiments/studies/no_return_threshold.py
HR_WIDTH = 24  # channels of the HR convolutions
HR_DILATIONS = (1, 2, 4)  # their 3 x 3 kernels' spacing: a field of 15 x 15 HR pixels
LOGIT_CLIP = 20.0  # the branch's logit as the HR convolutions read it: clipped (a far logit decides alike) ...
LOGIT_UNIT = 4.0  # ... and in units of 4, near the other inputs' range of [0, 1]
HR = "HR convolutions"  # the third fit's name in the tables


@functools.partial(jax.jit, static_argnames="cfg")
def _features(params, state, windows, cfg):
    return apply_model_features(params, state, windows, cfg)


@functools.partial(jax.jit, static_argnames="cfg")
def _logits(branch, features, cfg):
    return no_return_logits(branch, features[:, None].astype(jnp.float32), cfg)[:, 0]


def _batched(fn, x, batch: int) -> np.ndarray:
    return np.concatenate([np.asarray(fn(jnp.asarray(x[i:i + batch]))) for i in range(0, len(x), batch)])


def features_of(model, windows, batch: int = 8) -> np.ndarray:
    """The head's features (N, h, w, F) of (N, 2tr+1, h, w, C) windows, as float16 (they feed a fit and the
    branches' logits, not a score)."""
    cfg = dataclasses.replace(model.config, temporal="window")
    run = lambda w: _features(model.params, model.state, w.astype(jnp.float32), cfg).astype(jnp.float16)  # noqa: E731
    return _batched(run, windows, batch)


def logits(branch, features, cfg, batch: int = 64) -> np.ndarray:
    """The branch's no-return logits (N, H, W) from features (N, h, w, F)."""
    return _batched(lambda f: _logits(branch, f, cfg), features, batch)


def fit_on_fixed(params, predict, inputs, no_return, *, steps: int, lr: float, seed: int = 0, log=print):
    """`params` trained on fixed `inputs` (N, ...) against the truth no_return (N, H, W) bool: Adam on the mean
    cross-entropy of `predict(params, inputs[batch])`'s logits (`no_return_cross_entropy`, the training loss's
    no-return term), `BATCH` windows a step drawn with NumPy's generator at `seed`, the rate cut tenfold after
    `CUT_AT` of the steps."""

    def loss(p, x, y):
        return no_return_cross_entropy(predict(p, x.astype(jnp.float32)), y)

    @jax.jit
    def step(p, opt, x, y, rate):
        value, grads = jax.value_and_grad(loss)(p, x, y)
        p, opt = adam_update(grads, opt, p, lr=rate)
        return p, opt, value

    rng = np.random.default_rng(seed)
    opt, started, seen = adam_init(params), time.time(), []
    for s in range(steps):
        pick = rng.choice(len(inputs), BATCH, replace=False)
        rate = lr * (0.1 if s >= CUT_AT * steps else 1.0)
        params, opt, value = step(params, opt, jnp.asarray(inputs[pick]), jnp.asarray(no_return[pick]), rate)
        seen.append(float(value))
        if (s + 1) % max(steps // 10, 1) == 0:
            log(f"step {s + 1}/{steps}: loss {np.mean(seen[-100:]):.4f} ({time.time() - started:.0f} s)")
    return params


def refit_branch(branch, features, no_return, cfg, *, steps: int, lr: float, seed: int = 0, log=print) -> dict:
    """The branch trained on fixed features (N, h, w, F) (`fit_on_fixed`)."""
    predict = lambda p, f: no_return_logits(p, f[:, None], cfg)[:, 0]  # noqa: E731
    return fit_on_fixed(branch, predict, features, no_return, steps=steps, lr=lr, seed=seed, log=log)


def hr_inputs(windows, depth, logit, scale: int) -> np.ndarray:
    """What the HR convolutions read per HR pixel, (N, H, W, 2C + 1) float16 from windows (N, 2tr+1, h, w, C)
    (depth, then photon channels), the network's depth (N, H, W) and the branch's logit (N, H, W): the logit
    (clipped to +-`LOGIT_CLIP`, over `LOGIT_UNIT`), the depth, the LR pixel's C channels in the centre frame and its
    C - 1 photon channels' means over the window, each LR value on its scale x scale block."""
    windows = np.asarray(windows, np.float32)
    lr = np.concatenate([windows[:, windows.shape[1] // 2], windows[..., 1:].mean(axis=1)], axis=-1)
    lr = np.repeat(np.repeat(lr, scale, axis=1), scale, axis=2)
    logit = np.clip(np.asarray(logit, np.float32), -LOGIT_CLIP, LOGIT_CLIP) / LOGIT_UNIT
    return np.concatenate([logit[..., None], np.asarray(depth, np.float32)[..., None], lr], -1).astype(np.float16)


def init_hr(key, channels: int) -> list:
    """The HR convolutions' params: len(HR_DILATIONS) 3 x 3 convolutions of `HR_WIDTH` channels (Glorot-uniform,
    zero bias) and a last 1 x 1 one with zero weights, so that they start at the branch's own logit (as
    `hr_inputs` carries it: clipped, in float16)."""
    layers, cin = [], channels
    for k in jax.random.split(key, len(HR_DILATIONS)):
        limit = glorot_limit((1, 3, 3), cin, HR_WIDTH)
        layers.append({"w": jax.random.uniform(k, (3, 3, cin, HR_WIDTH), minval=-limit, maxval=limit),
                       "b": jnp.zeros(HR_WIDTH)})
        cin = HR_WIDTH
    return layers + [{"w": jnp.zeros((1, 1, HR_WIDTH, 1)), "b": jnp.zeros(1)}]


def hr_logits(layers, x):
    """The no-return logit (N, H, W) from `hr_inputs` x (N, H, W, C): the branch's logit (as clipped) plus what
    the convolutions add (ReLU between them, zero padding at the frame's border)."""
    h = x
    for layer, dilation in zip(layers[:-1], HR_DILATIONS):
        h = jax.nn.relu(conv2d(layer, h, dilation=dilation))
    return LOGIT_UNIT * x[..., 0] + conv2d(layers[-1], h)[..., 0]


_hr_logits = jax.jit(hr_logits)


def decisions(model, fits: dict, windows) -> tuple[np.ndarray, dict]:
    """(the network's depth (N, H, W), {name: no-return logit (N, H, W)}) of each fit on `windows`: "bundled" and
    "refitted" (branches on the head's features) and, where fitted, `HR` (convolutions on the bundled branch's
    logit)."""
    cfg = dataclasses.replace(model.config, temporal="window")
    depth, features = no_return_outputs(model, windows)[0], features_of(model, windows)
    logit = {name: logits(fits[name], features, cfg) for name in ("bundled", "refitted")}
    if HR in fits:
        x = hr_inputs(windows, depth, logit["bundled"], cfg.scale)
        logit[HR] = _batched(lambda b: _hr_logits(fits[HR], b.astype(jnp.float32)), x, 8)
    return depth, logit


def shares(depth, logit, gt, threshold: float, keep=None) -> tuple[float, float]:
    """(% no-return pixels output as depth, % true returns dropped) of the branch's decision at `threshold`
    (`merge_no_return`), read as the benchmark reads it (`no_return_rates`), over the pixels where `keep` (all
    when None)."""
    out = np.where(logit > threshold, 1.0, depth)
    return no_return_rates(out, gt) if keep is None else no_return_rates(out[keep], gt[keep])


def best_threshold(depth, logit, gt, thresholds=DEFAULT_THRESHOLDS) -> float:
    """The threshold with the least sky as depth among those dropping at most `GOAL_DROPPED` % of the true returns
    on these pixels (`choose_no_return_logit` over one band holding them all): in-sample, a bound, not a choice."""
    one_band = no_return_table(depth, logit, gt, np.ones(len(gt)), thresholds, edges=(0.0, 2.0))
    return choose_no_return_logit(one_band, target_dropped=GOAL_DROPPED, min_photons=0.0)["no_return_logit"]


def benchmark_windows(model, photons, *, frames: int, seed: int, static: bool = False) -> list[dict]:
    """photon_regimes.py's no-return test data at each photon level (levels from 3 photons up, as there; the same
    draws as its run with the same `--frames`, seed, levels and `--static`): {"photons", "windows" (N, 2tr+1, h,
    w, C), "gt" (N, H, W), "interior" (N, H, W) bool}, the scenes' scored frames stacked."""
    scored, tr, scale = scored_frames(frames, SEQUENCE_FRAMES), model.config.tr, model.config.scale
    # photon_regimes draws the frames of TR4 (always scored there) and of the ambient test, +-4 around each
    radius = max(tr, AMBIENT_RADIUS)
    if static:
        check_static(scored, SEQUENCE_FRAMES, radius, "benchmark_windows")
    seqs = with_no_return(jaxsr.scenes.test_sequences(n_frames=SEQUENCE_FRAMES, names=TEST_SCENES), seed=seed)
    levels = []
    for k, p in enumerate(photons):  # photon_regimes.evaluate's no-return keys: level k (from 3 photons) of seed + 1
        key = jax.random.fold_in(jax.random.key(seed + 1), k)
        clips, _ = benchmark_clips(seqs, float(p), NO_RETURN_SNR, scored=scored, radius=radius, key=key,
                                   static=static)
        windows = [frame_windows(c.network_input(model.config.inputs), c.scored, tr) for c in clips.values()]
        gt = np.concatenate([c.gt[c.scored] for c in clips.values()])
        levels.append({"photons": float(p), "windows": np.concatenate(windows), "gt": gt,
                       "interior": np.stack([interior(g >= 1.0, scale) for g in gt])})
    return levels


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="tr4-ambient", help="a model with a no-return head (default tr4-ambient)")
    parser.add_argument("--draws", type=int, default=3072, help="training windows of 16 x 16 LR pixels (3072)")
    parser.add_argument("--steps", type=int, default=3000, help="Adam steps of 32 windows (3000)")
    parser.add_argument("--lr", type=float, default=1e-3, help="Adam's learning rate (1e-3)")
    parser.add_argument("--hr-steps", type=int, default=None,
                        help="Adam steps of the HR convolutions (default --steps; 0: not fitted)")
    parser.add_argument("--static-prob", type=float, default=0.0,
                        help="share of static clips in the training and calibration sets (PhotonRegime.static_prob, 0)")
    parser.add_argument("--static", action="store_true",
                        help="benchmark static scenes (photon_regimes.py --static: each frame shows the scored frame "
                             "nearest to it)")
    parser.add_argument("--calibration-draws", type=int, default=CALIBRATION_DRAWS,
                        help=f"whole-frame windows the thresholds are chosen on ({CALIBRATION_DRAWS})")
    parser.add_argument("--frames", type=int, default=8, help="benchmark frames per scene (8)")
    parser.add_argument("--photons", type=float, nargs="+", default=[3.0, 14.0, 100.0],
                        help="benchmark photon levels (3 14 100)")
    parser.add_argument("--seed", type=int, default=0, help="the benchmark's noise seed (0)")
    parser.add_argument("--save", default=None,
                        help="also save the refitted model here (.npz; an existing file is refused)")
    parser.add_argument("--out", default="experiments/results/no_return_head.md")
    args = parser.parse_args(argv)
    if args.save and Path(args.save).exists():
        parser.error(f"--save {args.save} exists: choose another path (files are never overwritten)")
    started = time.time()
    if min(args.photons) < NO_RETURN_MIN_PHOTONS:
        parser.error(f"--photons: the no-return test starts at {NO_RETURN_MIN_PHOTONS:g} photons, got {args.photons}")
    model = jaxsr.load_model(args.model)
    if not getattr(model.config, "no_return_head", False):
        parser.error(f"--model {args.model} has no no-return head: there is no branch to refit")
    if args.hr_steps is not None and args.hr_steps < 0:
        parser.error(f"--hr-steps: 0 or more steps, got {args.hr_steps}")
    if args.hr_steps != 0 and len(model.config.inputs) < 2:
        parser.error(f"--model {args.model} reads depth alone: the HR convolutions read its photon channels "
                     "(--hr-steps 0 leaves them out)")
    try:
        regime = PhotonRegime(static_prob=args.static_prob)
    except ValueError as e:
        parser.error(f"--static-prob: {e}")
    cfg = dataclasses.replace(model.config, temporal="window")
    log = lambda msg: print(f"[{time.time() - started:5.0f} s] {msg}", flush=True)  # noqa: E731

    train = no_return_set(cfg.tr, draws=args.draws, photon_range=(2.0, 1000.0), key=jax.random.key(REFIT_SEED),
                          patch=PATCH, inputs=cfg.inputs, regime=regime)
    features, no_return = features_of(model, train["windows"]), train["gt"] >= 1.0
    log(f"training set: {args.draws} windows and their features")
    fits = {"bundled": model.params["no_return"]}
    fits["refitted"] = refit_branch(fits["bundled"], features, no_return, cfg, steps=args.steps, lr=args.lr, log=log)
    hr_steps = args.steps if args.hr_steps is None else args.hr_steps
    if hr_steps:
        x = hr_inputs(train["windows"], no_return_outputs(model, train["windows"])[0],
                      logits(fits["bundled"], features, cfg), cfg.scale)
        fits[HR] = fit_on_fixed(init_hr(jax.random.key(REFIT_SEED), x.shape[-1]), hr_logits, x, no_return,
                                steps=hr_steps, lr=args.lr, log=log)
        del x
    del features, train

    cal = no_return_set(cfg.tr, draws=args.calibration_draws, key=jax.random.key(CALIBRATION_SEED),
                        inputs=cfg.inputs, regime=regime)
    cal_depth, cal_logits = decisions(model, fits, cal["windows"])
    chosen = {name: choose_no_return_logit(no_return_table(cal_depth, logit, cal["gt"], cal["photons"]))
              for name, logit in cal_logits.items()}
    log("thresholds: " + ", ".join(f"{n} {c['no_return_logit']:+.2f}" for n, c in chosen.items()))

    rows = []
    for level in benchmark_windows(model, args.photons, frames=args.frames, seed=args.seed, static=args.static):
        depth, level_logits = decisions(model, fits, level["windows"])
        for name, logit in level_logits.items():
            best = best_threshold(depth, logit, level["gt"])
            row = {"photons": level["photons"], "branch": name, "chosen": chosen[name]["no_return_logit"],
                   "best": best}
            for where, keep in (("all", None), ("interior", level["interior"]), ("edges", ~level["interior"])):
                row[where] = shares(depth, logit, level["gt"], row["chosen"], keep)
                row[f"{where}_best"] = shares(depth, logit, level["gt"], best, keep)
            rows.append(row)
        log(f"{level['photons']:g} photons: " + "; ".join(
            f"{r['branch']} {r['all'][0]:.2f} / {r['all'][1]:.2f} %" for r in rows[-len(fits):]))

    if args.save:
        refitted = dataclasses.replace(model, params={**model.params, "no_return": fits["refitted"]})
        refitted = jaxsr.nn.with_no_return_logit(refitted, chosen["refitted"]["no_return_logit"])
        base_card = jaxsr.read_metadata(resolve_model_path(args.model)).get("card") or {}
        card = {**base_card, "no_return_refit": {"script": SCRIPT, "base": args.model, "draws": args.draws,
                                                 "steps": args.steps, "lr": args.lr, "seed": REFIT_SEED,
                                                 "static_prob": args.static_prob}}
        save_model(args.save, refitted, card=card, storage_dtype="float16")
        log(f"saved {args.save}")
    write_report(Path(args.out), rows, chosen, args, started)


def _cell(pair) -> str:
    a, d = pair
    bold = a <= GOAL_AS_DEPTH and d <= GOAL_DROPPED
    text = f"{a:.2f} / {d:.2f}"
    return f"**{text}**" if bold else text


def write_report(out: Path, rows: list, chosen: dict, args, started: float) -> None:
    text = header("Refitting the no-return branch on fixed features", started)
    text += (f"Model `{args.model}`; branch refitted on {args.draws} windows of {PATCH[0]} x {PATCH[1]} LR pixels "
             f"(photons 2-1000, the wide regime's SNRs, no-return regions on every clip), {args.steps} Adam steps of "
             f"{BATCH} at {args.lr:g} (tenfold lower for the last {100 * (1 - CUT_AT):.0f} %)"
             + (f"; {HR}: the bundled branch followed by {len(HR_DILATIONS)} 3 x 3 convolutions at HR ({HR_WIDTH} "
                f"channels, dilations {', '.join(map(str, HR_DILATIONS))}) over its logit, the network's depth and "
                "the LR pixel's inputs (`hr_inputs`), trained the same way on the same windows"
                + (f" ({args.hr_steps} steps)" if args.hr_steps not in (None, args.steps) else "")
                if HR in chosen else "")
             + (f"; {100 * args.static_prob:g} % of the training and calibration clips static "
                "(`PhotonRegime.static_prob`)" if args.static_prob else "")
             + f". Thresholds chosen on {args.calibration_draws} calibration frames (`calibrate_no_return`'s rule, "
             f"at most "
             f"{GOAL_DROPPED:g} % dropped over 3-1000 photons): "
             + ", ".join(f"{n} {c['no_return_logit']:+.2f} (calibration: {c['as_depth']:.1f} % as depth, "
                         f"{c['dropped']:.2f} % dropped, worst band)" for n, c in chosen.items())
             + f". Benchmark: the scenes and no-return regions of experiments/studies/photon_regimes.py, "
             f"{args.frames} frames per scene, SNR {NO_RETURN_SNR:g}, noise seed {args.seed}"
             + (", **static**: each frame shows the scored frame nearest to it (`--static`)" if args.static else "")
             + ".\n\n"
             "Each cell: % of no-return HR pixels output as depth / % of true returns dropped; bold where both "
             f"goals hold (at most {GOAL_AS_DEPTH:g} / {GOAL_DROPPED:g} %). Interior: HR pixels whose LR block and "
             "its 8 neighbours are of one kind (_photon_benchmark.interior); edges: the others. `best`: the threshold "
             "with the least sky as depth dropping at most 2 % over all the level's pixels, chosen on those very "
             "pixels (in-sample: a bound on the decision, not a result); the interior and edge columns at that same "
             "threshold.\n\n")
    header_row = ["photons", "branch", "all pixels", "interior", "edges", "best threshold", "all pixels, best",
                  "interior, best", "edges, best"]
    body = [[f"{r['photons']:g}", r["branch"], _cell(r["all"]), _cell(r["interior"]), _cell(r["edges"]),
             f"{r['best']:+.2f}", _cell(r["all_best"]), _cell(r["interior_best"]), _cell(r["edges_best"])]
            for r in rows]
    text += markdown_table(header_row, body) + "\n"
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, text)
    write_atomic(out.with_suffix(".json"), json.dumps({"rows": rows, "chosen": chosen, "args": vars(args)}, indent=1)
                 + "\n")
    print(f"wrote {out} and {out.with_suffix('.json')}")


if __name__ == "__main__":
    main()
