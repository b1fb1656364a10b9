"""The held-out benchmark: the photon benchmark's regimes on public third-party depth that jaxsr's scene generator did
not make and training never sees, beside the test scenes, for bicubic, the paper's TR4 and the default for
histograms (what `jaxsr.upscale` gives, and the same model with the keep rule on its head's logit).

    # 1. the data, from fetched repositories (bare git mirrors or checkouts), into a folder outside the repository
    python experiments/studies/heldout.py prepare --data /work/data/heldout \\
        --source isl-org/Open3D=/work/.mirror/isl-org+Open3D/repo --source yanzq95/STDNet=/work/.mirror/yanzq95+STDNet/repo
    # 2. the scores (resumable: each scene-regime is kept in <out>.cache.json as it is done)
    python experiments/studies/heldout.py score --data /work/data/heldout --photons 3 14 --snr 1.3   # the issue's first
    python experiments/studies/heldout.py score --data /work/data/heldout          # every regime of the benchmark
    python experiments/studies/heldout.py score --data /work/data/heldout --photons 3 14 --snr 1.3 0.3 --grid-only
    python experiments/studies/heldout.py score --data /work/data/heldout --report-only   # the report of the cache

Data (`_heldout_data.SETS`: repository, commit, paths, licence, units of each): three static indoor scenes (a NYU
Depth V2, a TUM RGB-D and a SUN RGB-D frame, each repeated over 30 frames) and a rendered indoor dToF video with
moving objects (DyDToF school_shot8, 30 frames), as 128 x 256 radial metres + intensity. The test scenes: the
benchmark's (harness.scoring.TEST_SCENES, 500 frames each).

Regimes: the issue's first (3 and 14 photons at SNR 1.3, 0.3 and 0.1), then `_photon_benchmark.PHOTONS` x `SNRS`
(signal photons per LR pixel with a return, frame SNR) and the paper's
(14 photons, each scene's own SNR: the test scenes' 1.3, 1.3, 3; the held-out scenes have none, so 1.3), drawn
as the benchmark draws them (`benchmark_clips`: the laser and ambient calibrated over each whole sequence, photons
drawn for the frames the methods read). `--frames` frames scored per scene, spread over it.

Methods, on the same photons:
- bicubic of the centre-of-mass depth;
- the paper's TR4 (bundled `paper-tr4`) reading the centre of mass;
- "jaxsr.upscale default": what a user gets, `jaxsr.upscale(counts, None, read=Reading(units="normalised"))` with
  every other option the library's default (the model `DEFAULT_MODELS["histograms"]`, the gate read from the
  histograms: their 16 bins over the sensor's 35 m, the confidence's no-return decision: no return where P(return)
  < 0.5 and the pixel's own photons over 9 frames, and those of the quiet pixels pooled in the 3 x 3 and 5 x 5
  around it, pass for ambient light alone), on the photon counts of each scored frame's +-4 frames;
- "tr4-ambient + keep 0.001": that model with the keep rule on its head's logit, each pixel's own photons alone
  (`_photon_benchmark.returns_kept`), the default decision before the confidence's P(return) and the pools (`jaxsr
  upscale --keep-returns 0.001` now pools them too and fills black holes); cached as "default" before the other
  was scored (`OLD_NAMES`). Where both output the network's depth the two are the same numbers.

Scores per scene and regime: PSNR over all pixels (normalised depth clipped to [0, 1], no return = 1.0, as the
photon benchmark scores it); true returns dropped: the share of HR pixels with a return whose 8 neighbours all
hold a return (away from the edges of no-return regions) that a method outputs as no return (normalised >=
`NO_RETURN_AT`); no return shown as depth: the share of the pixels without a return (beyond the 35 m gate, sky)
output as depth. Writes experiments/results/heldout.md (or --out) and a .json of the raw numbers beside it.
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
from jaxsr.app import AUTO_KEEP_RETURNS, DEFAULT_MODELS, Reading
from jaxsr.config import Sensor
from jaxsr.inference import lr_blocks
from jaxsr.nn import Model
from jaxsr.sensor import calibrated_rates, normalise_depth

import _heldout_data  # beside this script
from _heldout_data import regimes
from _photon_benchmark import (PHOTONS, SNRS, benchmark_clips, bicubic_output, calibration,  # noqa: E402
                               dropped_error, regime_key, regime_label, returns_kept, shares)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import header, markdown_table, write_atomic  # noqa: E402
from harness.scoring import SCENE_LABELS, SEQUENCE_FRAMES, TEST_SCENES, frame_scores, scored_frames, scored_output  # noqa: E402

BICUBIC, PAPER_TR4 = "bicubic", "paper's TR4"
# the default model for histograms with the keep rule on its head's logit: the default decision until the
# confidence's P(return) replaced it; cached as "default" before there was another (`OLD_NAMES`)
KEEP = f"{DEFAULT_MODELS['histograms']} + keep {AUTO_KEEP_RETURNS:g}"
UPSCALE = "jaxsr.upscale default"  # what a user gets: `jaxsr.upscale(counts, None)` with the library's defaults
METHODS = (BICUBIC, PAPER_TR4, KEEP, UPSCALE)
DEFAULTS = (KEEP, UPSCALE)  # set against the paper's TR4 in the report
OWN_KEY = (UPSCALE,)  # cached under a key of their own: the entries of the methods before them stay valid
OLD_NAMES = {"default": KEEP}


# ------------------------------------------------------------------------------------------------ the measures

def dim_returns(seq, photons: float = 3.0, snr: float = 1.3, *, every: int = 10) -> dict:
    """Why a dropped return costs a scene what it does: {"dim_pct": % of LR pixels with a return whose expected
    signal is below one photon at `photons` (mean over the LR pixels with a return) and `snr`, the laser calibrated
    over the whole sequence; "cost": mean (1 - normalised depth)^2 over the HR returns, the squared error of one
    output as no return; "dim_cost": the same over the HR pixels of those dim LR pixels; "median_depth":
    normalised}. Every `every`-th frame is counted."""
    sensor = Sensor()
    alpha, _ = calibration(jnp.asarray(seq.depth), jnp.asarray(seq.intensity), jnp.float32(snr),
                           jnp.float32(photons), sensor)
    depth, intensity = jnp.asarray(seq.depth[::every]), jnp.asarray(seq.intensity[::every])
    signal = np.asarray(calibrated_rates(depth, intensity, alpha, 0.0, sensor)).sum(-1)  # (T, h, w), no ambient
    gt = np.asarray(normalise_depth(depth, sensor))
    ret = gt < 1.0
    dim = lr_blocks(signal < 1.0, sensor.scale) & ret
    lit = signal > 0
    return {"dim_pct": 100.0 * float((signal[lit] < 1.0).mean()), "cost": float(((1 - gt[ret]) ** 2).mean()),
            "dim_cost": float(((1 - gt[dim]) ** 2).mean()) if dim.any() else float("nan"),
            "median_depth": float(np.median(gt[ret]))}


def kept_output(model: Model, clip, flags) -> tuple[np.ndarray, np.ndarray]:
    """(sr, gt) of the scored frames: `model` with, for one with a no-return head, the keep rule's decision
    `flags` ((F, h, w) of the scored frames) on its head's logit."""
    if not model.has_no_return_head:
        return scored_output(model, clip)
    return returns_kept(model, clip.network_input(model.config.inputs), clip.scored, flags), clip.gt[clip.scored]


def upscale_output(model, clip) -> tuple[np.ndarray, np.ndarray]:
    """(sr, gt) of the scored frames: `jaxsr.upscale` of the clip's photon counts (T, h, w, K) with the library's
    defaults (`model` "default" as a user gives none; the gate read from the histograms: their K bins over the
    sensor's 35 m), in normalised units. The clip's frames are each scored frame's window (+-4 frames, what the
    network, the no-return tests and the confidence read), one after another."""
    if clip.counts.ndim != 4 or clip.counts.shape[-1] == 0:
        raise ValueError(f"{UPSCALE}: clip {clip.name!r} was made without its photon counts (benchmark_clips("
                         "counts=True))")
    result = jaxsr.upscale(clip.counts, None, model=model, read=Reading(units="normalised"))
    return np.asarray(result.depth)[clip.scored], clip.gt[clip.scored]


def method_outputs(models: dict, clip, flags, methods=METHODS) -> dict:
    """{method: (sr, gt)} on the clip's scored frames for each of `methods`: bicubic, the paper's TR4, the
    default model with the keep rule (its decision `flags`, (F, h, w) of the scored frames) and `jaxsr.upscale`'s
    default (the clip made with its counts)."""
    outputs = {BICUBIC: lambda: bicubic_output(clip, Sensor().scale),
               PAPER_TR4: lambda: scored_output(models[PAPER_TR4], clip),
               KEEP: lambda: kept_output(models[KEEP], clip, flags),
               UPSCALE: lambda: upscale_output(models[UPSCALE], clip)}
    unknown = [m for m in methods if m not in outputs]
    if unknown:
        raise ValueError(f"method_outputs: unknown methods {unknown}; expected some of {list(outputs)}")
    return {m: outputs[m]() for m in methods}


def score_scene(models: dict, name: str, seq, photons: float, snr, *, frames: int, seed: int = 0,
                methods=METHODS) -> dict:
    """One scene at one regime: {method: {"psnr": [per frame], "dropped_pct", "as_depth_pct"}, "returns",
    "no_return"} (pixel counts over the scored frames) for each of `methods`. Every method reads the same photons
    whichever are scored: the frames drawn are those of the largest radius of the networks of `models` and of the
    keep rule's 9 frames."""
    total = len(seq.depth)
    scored = scored_frames(frames, total)
    radius = max(m.config.tr for m in models.values() if isinstance(m, Model))
    key = regime_key(seed, photons, snr)
    keep = ("keep", float(AUTO_KEEP_RETURNS))
    clips, flags = benchmark_clips({name: seq}, photons, snr, scored=scored, radius=radius, key=key,
                                   tests=(keep,), counts=UPSCALE in methods)
    clip = clips[name]
    result = {}
    for method, (sr, gt) in method_outputs(models, clip, flags[name][keep], methods).items():
        psnr, _ = frame_scores(sr, gt)
        dropped, shown, n_ret, n_sky = shares(sr, gt)
        result[method] = {"psnr": np.round(np.asarray(psnr, float), 4).tolist(), "dropped_pct": dropped,
                          "as_depth_pct": shown, "dropped_error_pct": dropped_error(sr, gt)}
    result["returns"], result["no_return"] = n_ret, n_sky
    return result


def load_methods() -> tuple[dict, dict]:
    """({method: Model, or what `jaxsr.upscale` takes as its model}, {method: what it is}) of the methods scored."""
    name = DEFAULT_MODELS["histograms"]
    models = {PAPER_TR4: jaxsr.load_model("paper-tr4"), KEEP: jaxsr.load_model(name), UPSCALE: "default"}
    rule = (f", its head's no return kept only where the pixel's own photons over 9 frames pass for ambient light "
            f"alone (alpha {AUTO_KEEP_RETURNS:g}: --keep-returns {AUTO_KEEP_RETURNS:g}), the default decision "
            "before the confidence's P(return)" if models[KEEP].has_no_return_head else "")
    return models, {BICUBIC: "bicubic of the centre of mass", PAPER_TR4: "bundled paper-tr4",
                    KEEP: f"bundled {name}{rule}",
                    UPSCALE: "`jaxsr.upscale(counts, None, read=Reading(units=\"normalised\"))` with every other "
                             "option the library's default (what a user gets: the model, the gate read from the "
                             "histograms, the no-return decision: P(return) < 0.5 where the pixel's photons and "
                             "those of the quiet pixels pooled around it pass for ambient light alone, outside the "
                             "holes that returns enclose), on the photon counts of each scored frame's +-4 frames"}


def cache_key(group: str, name: str, photons: float, snr, frames: int) -> str:
    return f"{group}|{name}|{photons:g}|{'own' if snr is None else f'{snr:g}'}|{frames}"


def slot(key: str, method: str) -> str:
    """Where a method's scores of a scene-regime are cached: the scene-regime's key, or for a method of
    `OWN_KEY` a key of its own beside it."""
    return f"{key}|{method}" if method in OWN_KEY else key


def load_cache(path: Path) -> dict:
    """The cache file's entries ({} where there is none), methods cached under an earlier name (`OLD_NAMES`)
    under their name now."""
    cache = json.loads(path.read_text()) if path.exists() else {}
    return {k: {OLD_NAMES.get(m, m): v for m, v in e.items()} for k, e in cache.items()}


def cached(cache: dict, key: str) -> dict:
    """A scene-regime's scores held in the cache, every method's slot merged: {method: ..., "returns",
    "no_return"}."""
    out = dict(cache.get(key, {}))
    for m in OWN_KEY:
        out.update(cache.get(slot(key, m), {}))
    return out


def run(models: dict, groups: dict, grid, *, frames: dict, cache_path: Path, seed: int = 0, log=print) -> dict:
    """Score every scene of `groups` ({group: {name: sequence}}) at every regime of `grid`, reusing and extending
    the cache file (each method's scores of a scene-regime in its `slot`, written as each scene-regime is done):
    only the methods a scene-regime's entries lack are scored."""
    cache = load_cache(cache_path)
    for p, s in grid:
        for group, seqs in groups.items():
            for name, seq in seqs.items():
                key = cache_key(group, name, p, s, frames[group])
                missing = [m for m in METHODS if m not in cached(cache, key)]
                if not missing:
                    continue
                started = time.time()
                result = score_scene(models, name, seq, p, s, frames=frames[group], seed=seed, methods=missing)
                for m in missing:
                    cache[slot(key, m)] = {**cache.get(slot(key, m), {}), m: result[m], "returns": result["returns"],
                                           "no_return": result["no_return"]}
                write_atomic(cache_path, json.dumps(cache) + "\n")
                log(f"{group} {name}, {regime_label(p, s)}: " + ", ".join(
                    f"{m} {np.mean(cached(cache, key)[m]['psnr']):.2f} dB" for m in METHODS)
                    + f" ({', '.join(missing)} in {time.time() - started:.0f} s)")
    return cache


# ------------------------------------------------------------------------------------------------ the report

def summary(cache: dict, groups: dict, grid, frames: dict) -> list:
    """Per regime and group: the mean over scenes of each method's mean PSNR, the pooled dropped and shown
    shares (weighted by pixel counts), per-scene PSNRs, for each method that has scored every scene of the group
    (a group none has scored is left out). [{"photons", "snr", "groups": {group: {method: {...}}}}]."""
    rows = []
    for p, s in grid:
        row = {"photons": p, "snr": "own" if s is None else s, "groups": {}}
        for group, seqs in groups.items():
            entries = {n: cached(cache, cache_key(group, n, p, s, frames[group])) for n in seqs}
            g = {}
            for m in (m for m in METHODS if all(m in e for e in entries.values())):
                ret = sum(e["returns"] for e in entries.values())
                sky = sum(e["no_return"] for e in entries.values())
                weighted = lambda k, n: (sum(np.nan_to_num(e[m][k]) * e[n] for e in entries.values()) / total
                                         if (total := sum(e[n] for e in entries.values())) else float("nan"))
                errors = [e[m].get("dropped_error_pct") for e in entries.values()]
                g[m] = {"psnr": float(np.mean([np.mean(e[m]["psnr"]) for e in entries.values()])),
                        "dropped_error_pct": {n: e[m].get("dropped_error_pct") for n, e in entries.items()}
                        if None not in errors else None,
                        "scenes": {n: float(np.mean(e[m]["psnr"])) for n, e in entries.items()},
                        "dropped_pct": weighted("dropped_pct", "returns") if ret else float("nan"),
                        "as_depth_pct": weighted("as_depth_pct", "no_return") if sky else float("nan")}
            if g:
                row["groups"][group] = g
        rows.append(row)
    return rows


def _f(x, fmt="{:.2f}"):
    return "-" if x is None or not np.isfinite(x) else fmt.format(x)


def tables(rows, groups: dict) -> str:
    """The report's tables: PSNR beside each other, each of the defaults (`DEFAULTS`) against the paper's TR4 on
    each group, the no-return shares; then the held-out scenes one by one."""
    names = list(groups)
    head = (["regime"] + [f"{g}: {m}" for g in names for m in METHODS]
            + [f"{g}: {m} - TR4" for g in names for m in DEFAULTS])
    body = []
    for r in rows:
        if not r["groups"]:
            continue
        cells = [regime_label(r["photons"], None if r["snr"] == "own" else r["snr"])]
        for g in names:
            cells += [_f(r["groups"].get(g, {}).get(m, {}).get("psnr")) for m in METHODS]
        for g in names:
            x = r["groups"].get(g)
            cells += [_f(x[m]["psnr"] - x[PAPER_TR4]["psnr"], "{:+.2f}") if x and {m, PAPER_TR4} <= set(x) else "-"
                      for m in DEFAULTS]
        body.append(cells)
    text = "### Mean PSNR (dB) over the scenes of each group\n\n" + markdown_table(head, body) + "\n\n"
    compared = (PAPER_TR4, *DEFAULTS)
    head = ["regime"] + [f"{g}: {m} dropped %" for g in names for m in compared] + [
        f"{g}: {m} no return as depth %" for g in names for m in compared]
    body = []
    for r in rows:
        if not r["groups"]:
            continue
        cells = [regime_label(r["photons"], None if r["snr"] == "own" else r["snr"])]
        for k in ("dropped_pct", "as_depth_pct"):
            for g in names:
                cells += [_f(r["groups"].get(g, {}).get(m, {}).get(k), "{:.3f}") for m in compared]
        body.append(cells)
    text += ("### True returns dropped (away from the edges) and no return shown as depth\n\n"
             "Pooled over each group's scored pixels; `-` where a group has no pixel of the kind (the held-out "
             "scenes lie within the gate: no sky).\n\n" + markdown_table(head, body) + "\n\n")
    body = []
    for r in rows:
        for g in names:
            x = r["groups"].get(g)
            if not x or any(x.get(m, {}).get("dropped_error_pct") is None for m in compared):
                continue
            for n in groups[g]:
                body.append([regime_label(r["photons"], None if r["snr"] == "own" else r["snr"]), g, n]
                            + [_f(x[m]["dropped_error_pct"][n], "{:.1f}") for m in compared]
                            + [_f(x[m]["scenes"][n]) for m in compared])
    if body:
        text += ("### How much of the error is returns output as no return\n\n% of each method's squared error "
                 "(over all pixels, as PSNR counts it) on true returns it outputs as no return, anywhere in the "
                 "frame (`dropped_error`); the regimes scored with it.\n\n"
                 + markdown_table(["regime", "group", "scene"] + [f"{m} %" for m in compared]
                                  + [f"{m} PSNR" for m in compared], body) + "\n\n")
    for g in names:
        scenes = list(groups[g])
        head = ["regime"] + [f"{n}: {m}" for n in scenes for m in METHODS]
        body = []
        for r in rows:
            x = r["groups"].get(g)
            if not x:
                continue
            body.append([regime_label(r["photons"], None if r["snr"] == "own" else r["snr"])]
                        + [_f(x[m]["scenes"][n]) if m in x else "-" for n in scenes for m in METHODS])
        text += f"### {g}: PSNR (dB) per scene\n\n" + markdown_table(head, body) + "\n\n"
    return text


# ------------------------------------------------------------------------------------------------ the command

def why_table(groups: dict) -> str:
    """`dim_returns` of every scene, as a table."""
    body = []
    for g, seqs in groups.items():
        for n, seq in seqs.items():
            d = dim_returns(seq)
            body.append([g, n, f"{d['median_depth'] * Sensor().d_max:.1f}", f"{d['dim_pct']:.1f}",
                         f"{d['cost']:.2f}", _f(d["dim_cost"])])
    return ("### What a dropped return costs\n\nPer scene (every 10th frame): the median depth of its returns (m), "
            "the share of its LR pixels with a return whose expected signal is below one photon at 3 photons "
            "(SNR 1.3, the laser calibrated over the sequence), and the squared error of a return output as no "
            "return (normalised depth 1.0: 35 m), (1 - depth / 35 m)^2, mean over the HR returns and over those of "
            "the dim LR pixels (`dim_returns`).\n\n"
            + markdown_table(["group", "scene", "median depth (m)", "LR pixels < 1 signal photon at 3 (%)",
                              "cost of a dropped return", "the same, dim pixels"], body) + "\n\n")


def write_report(out: Path, rows, groups, frames, info, manifest, args, started, pending=(), running=True) -> None:
    """experiments/results/heldout.md (out) and its .json: the sets, the methods and the tables of `rows`."""
    heldout = groups["held-out"]
    sets = "\n".join(f"- `{n}` ({m['kind']}, {m['frames']} frames, {m['range_m'][0]}-{m['range_m'][1]} m): "
                     f"{m['holds']}; {m['repo']} @ {m['commit'][:10]} (`{m['paths'][0]}`); {m['licence']}; "
                     f"units: {m['units']}" for n, m in manifest.items() if n in heldout)
    test_text = (f"the test scenes ({', '.join(SCENE_LABELS[n] for n in TEST_SCENES)}), {args.test_frames} frames "
                 f"each of {SEQUENCE_FRAMES}" if args.test_frames else "no test scenes (`--test-frames 0`)")
    listed = ", ".join(regime_label(p, s) for p, s in pending)
    waiting = ("" if not pending else f"**Still running**: {len(pending)} regimes to go ({listed}).\n\n" if running
               else f"**Not scored by every method** ({len(pending)} regimes: {listed}): `-` where a method has no "
                    "score.\n\n")
    text = (header("Held-out benchmark: the photon regimes on third-party depth", started) + waiting
            + f"Held-out scenes ({args.frames} frames scored each of their 30), from `{args.data}`:\n\n{sets}\n\n"
            f"Beside them {test_text}. Noise seed {args.seed}; every method of a scene-regime reads the same "
            "photons. Methods: " + "; ".join(f"{k}: {v}" for k, v in info.items()) + ".\n\n" + tables(rows, groups)
            + why_table(groups))
    write_atomic(out, text)
    write_atomic(out.with_suffix(".json"), json.dumps({"methods": info, "frames": frames, "seed": args.seed,
                                                       "sets": {n: manifest.get(n) for n in heldout},
                                                       "regimes": rows}, indent=1) + "\n")


def _sources(specs) -> dict:
    out = {}
    for spec in specs:
        repo, sep, folder = spec.partition("=")
        if not sep or "/" not in repo or not folder:
            raise SystemExit(f"--source expects OWNER/NAME=FOLDER, got {spec!r}")
        out[repo] = folder
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="step", required=True)
    prep = sub.add_parser("prepare", help="write the held-out scenes from fetched repositories")
    prep.add_argument("--source", action="append", default=[], metavar="OWNER/NAME=FOLDER",
                      help="a repository's bare git mirror or checkout (see _heldout_data.SETS); repeatable")
    prep.add_argument("--data", default=str(_heldout_data.DEFAULT_DATA), help="the data folder (outside the repo)")
    prep.add_argument("--sets", nargs="+", default=None, help=f"sets to write (default all: {list(_heldout_data.SETS)})")
    score = sub.add_parser("score", help="score the methods on the held-out scenes beside the test scenes")
    score.add_argument("--data", default=str(_heldout_data.DEFAULT_DATA), help="the data folder `prepare` wrote")
    score.add_argument("--frames", type=int, default=4, help="frames scored per held-out scene (default 4 of 30)")
    score.add_argument("--test-frames", type=int, default=4,
                       help=f"frames scored per test scene, of its {SEQUENCE_FRAMES} (default 4; 0: no test scenes)")
    score.add_argument("--photons", type=float, nargs="+", default=list(PHOTONS))
    score.add_argument("--snr", type=float, nargs="+", default=list(SNRS),
                       help="frame SNRs of the grid (default the benchmark's 0.1 1.3 5; the issue's 3 and 14 photons "
                            "at 1.3, 0.3 and 0.1 always run first)")
    score.add_argument("--grid-only", action="store_true",
                       help="only --photons x --snr and the paper's regime, not the issue's first regimes as well")
    score.add_argument("--seed", type=int, default=0)
    score.add_argument("--report-only", action="store_true",
                       help="write the report from the scores done so far (<out>.cache.json), scoring nothing")
    score.add_argument("--out", default="experiments/results/heldout.md", help="the results file (.json beside it)")
    args = parser.parse_args(argv)
    if args.step == "prepare":
        sources = _sources(args.source)
        if not sources:
            raise SystemExit("prepare: give at least one --source OWNER/NAME=FOLDER (see _heldout_data.SETS)")
        try:
            _heldout_data.prepare(sources, args.data, names=args.sets)
        except (FileNotFoundError, ValueError) as e:
            raise SystemExit(str(e)) from None
        return
    started = time.time()
    try:
        heldout = _heldout_data.load_scenes(args.data)
    except FileNotFoundError as e:
        raise SystemExit(str(e)) from None
    groups = {"held-out": heldout}
    frames = {"held-out": args.frames}
    if args.test_frames:
        groups["test scenes"] = jaxsr.scenes.test_sequences(n_frames=SEQUENCE_FRAMES, names=TEST_SCENES)
        frames["test scenes"] = args.test_frames
    models, info = load_methods()
    grid = regimes(args.photons, args.snr, first=not args.grid_only)
    out = Path(args.out)
    manifest_path = Path(args.data) / "manifest.json"
    manifest = json.loads(manifest_path.read_text()) if manifest_path.exists() else {}
    cache_path = out.with_suffix(".cache.json")
    if args.report_only:
        cache = load_cache(cache_path)
        done = [r for r in grid if all(set(METHODS) <= set(cached(cache, cache_key(g, n, *r, frames[g])))
                                       for g, seqs in groups.items() for n in seqs)]
        write_report(out, summary(cache, groups, grid, frames), groups, frames, info, manifest, args, started,
                     pending=[r for r in grid if r not in done], running=False)
        print(f"wrote {out} and {out.with_suffix('.json')} ({len(done)} of {len(grid)} regimes)")
        return
    for done in range(1, len(grid) + 1):  # the report rewritten as each regime is done: a long run shows progress
        cache = run(models, groups, grid[done - 1:done], frames=frames, cache_path=cache_path, seed=args.seed)
        write_report(out, summary(cache, groups, grid[:done], frames), groups, frames, info, manifest, args,
                     started, pending=grid[done:])
    print(f"wrote {out} and {out.with_suffix('.json')}")


if __name__ == "__main__":
    main()
