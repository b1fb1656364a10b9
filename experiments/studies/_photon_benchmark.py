"""The simulated photon benchmark that the photon studies share (photon_regimes.py, no_return_head.py,
real_photons.py, upscale_defaults.py): the test scenes at a photon level and SNR, with regions of no return, the
no-return decisions a model is run with, the methods' scores and the goals they are held to.

`benchmark_clips` draws a regime's photons for the frames the methods read only: unlike
`jaxsr.training.data.regime_clips` (random training clips of a `PhotonRegime`), it simulates given test sequences
at one level and SNR and returns `harness.scoring.Clip`s.
"""

from __future__ import annotations

import functools
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage

import jaxsr
from jaxsr.baselines import block_mean
from jaxsr.config import DEFAULT_MEAN_SIGNAL, MODEL_INPUTS, Sensor
from jaxsr.io.checkpoint import resolve_model_path
from jaxsr.inference import no_return_where, overrule_no_return
from jaxsr.nn import network_inputs
from jaxsr.training.no_return import no_return_outputs
from jaxsr.sensor import (ambient_only, beside_sky, calibrate, calibrated_rates, no_return_regions, no_return_shares,
                          normalise_depth, quiet_pixels, sample_poisson)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import BLOCK, Clip, frame_scores, frame_windows, scored_frames, scored_output  # noqa: E402

PHOTONS = (1.0, 3.0, 14.0, 100.0, 1000.0)
SNRS = (0.1, 1.3, 5.0)
PAPER = "own"  # the SNR label of the paper's regime: each scene at its own SNR
NO_RETURN_AT = 0.99  # normalised output at or above it reads as "no return"
NO_RETURN_FRACTION = 0.3
NO_RETURN_SKY = 0.5
NO_RETURN_SNR = 1.3
NO_RETURN_MIN_PHOTONS = 3.0
AMBIENT_RADIUS = 4  # frames on either side that `ambient_only` sums (its 9 frames)
MAJORITY = "block majority"  # the no-return tables' column of `block_majority`
TV_TR = 1  # the TV baseline's temporal radius (its default)
# The goals, for PSNR and for no return
GOAL_LOW = 6.0  # dB over bicubic, mean over 1-3 photons
GOAL_100 = 3.0  # dB over bicubic at 100 photons
GOAL_TODAY = -0.3  # dB against the bundled TR4 at the paper's regime
GOAL_AS_DEPTH = 5.0  # % of no-return pixels output as depth, at most
GOAL_DROPPED = 2.0  # % of true returns dropped, at most


@functools.partial(jax.jit, static_argnames=("sensor",))
def calibration(depth, intensity, snr, mean_signal, sensor):
    return calibrate(depth, intensity, sensor, snr=snr, mean_signal=mean_signal)


@functools.partial(jax.jit, static_argnames=("sensor", "tests", "keep_counts"))
def _draw(key, depth, intensity, alpha, beta, sensor, tests=(), keep_counts=False):
    """Network inputs, normalised ground truth, for each (kind, alpha) of `tests` its `no_return_decision` (the
    frames drawn are consecutive around each scored frame, so a scored frame's test sums its own) and, with
    keep_counts, the photon counts (T, h, w, K) themselves (else an empty (T, 0))."""
    counts = sample_poisson(key, calibrated_rates(depth, intensity, alpha, beta, sensor), method="fast")
    flags = tuple(no_return_decision(counts, sensor, test) for test in tests)
    kept = counts.astype(jnp.float32) if keep_counts else jnp.zeros((len(depth), 0), jnp.float32)
    return network_inputs(counts, sensor, MODEL_INPUTS), normalise_depth(depth, sensor), flags, kept


def needed_frames(scored, total: int, radius: int) -> np.ndarray:
    """The frames the methods read: each scored frame's window of +- radius, clipped to the sequence, sorted."""
    scored = np.asarray(scored)
    return np.unique(np.clip(scored[:, None] + np.arange(-radius, radius + 1), 0, total - 1))


def benchmark_clips(seqs: dict, photons: float, snr, *, scored, radius: int, key, sensor=Sensor(),
                 tests=(), static: bool = False, counts: bool = False) -> dict:
    """The sequences at one regime: {name: Clip} of the frames the methods need (`needed_frames`), with `scored`
    as positions in them. snr None: each sequence's own. The laser and ambient are calibrated over the whole
    sequence, as `simulate_histograms` would, and photons are drawn only for those frames. static: each of those
    frames shows the scored frame nearest to it (`nearest_scored`; the calibration still of the whole moving
    sequence, so that a scored frame gets the same photons as without). counts: keep the photon counts in
    `Clip.counts` (T, h, w, K), for methods that read histograms (else (T, 0): the methods read the centre of
    mass and the photons' channels). Returns (clips, ambient): ambient {name:
    {(kind, alpha): (F, h, w)}}, the `no_return_decision` of the scored frames for each test of `tests`."""
    clips, ambient = {}, {}
    for i, (name, seq) in enumerate(seqs.items()):
        s = float(seq.snr if snr is None else snr)
        alpha, beta = calibration(jnp.asarray(seq.depth), jnp.asarray(seq.intensity), jnp.float32(s),
                                   jnp.float32(photons), sensor)
        # the ambient-only test sums 9 frames: each scored frame needs its +-4 (else windows far apart would meet)
        keep = needed_frames(scored, len(seq.depth), max(radius, AMBIENT_RADIUS) if tests else radius)
        shown = nearest_scored(len(seq.depth), scored)[keep] if static else keep
        x, gt, flags, kept = _draw(jax.random.fold_in(key, i), jnp.asarray(seq.depth[shown]),
                                   jnp.asarray(seq.intensity[shown]), alpha, beta, sensor, tuple(tests), counts)
        x = np.asarray(x)
        clips[name] = Clip(name, x[..., 0], np.asarray(kept), np.asarray(gt), float(seq.fps), s,
                           np.asarray(seq.intensity[shown], np.float32), np.searchsorted(keep, scored), x[..., 1:],
                           channels=MODEL_INPUTS[1:])
        ambient[name] = {a: np.asarray(f)[clips[name].scored] for a, f in zip(tests, flags)}
    return clips, ambient


def with_no_return(seqs: dict, *, seed: int = 0, fraction=NO_RETURN_FRACTION, sky=NO_RETURN_SKY) -> dict:
    """The sequences with regions of no return (`no_return_regions`, one mask per sequence, all frames)."""
    out = {}
    for i, (name, seq) in enumerate(seqs.items()):
        depth = no_return_regions(jax.random.key(10_000 + 100 * seed + i), jnp.asarray(seq.depth),
                                  fraction=fraction, sky=sky)
        out[name] = SimpleNamespace(**{**vars_of(seq), "depth": np.asarray(depth)})
    return out


def nearest_scored(total: int, scored) -> np.ndarray:
    """(total,) for each frame of a sequence the scored frame nearest to it (a tie: the earlier): what a static
    scene shows in each frame (`benchmark_clips(static=True)`), so that each scored frame's window holds one scene
    under independent photon noise, as a photon video made of a real recording of a still scene does."""
    scored = np.asarray(scored)
    return scored[np.abs(np.arange(total)[:, None] - scored[None]).argmin(1)]


def check_static(scored, total: int, window: int, name: str) -> None:
    """Refuse static scenes (`benchmark_clips(static=True)`) whose scored frames' windows of +-`window` frames would
    meet: each must hold its own scored frame alone, else a window would show two scenes."""
    if len(scored) >= total or (len(scored) > 1 and 2 * window >= np.diff(scored).min()):
        raise ValueError(f"{name}(static=True): each scored frame's window of +-{window} frames must hold it "
                         f"alone; {len(scored)} scored frames of {total} are too close (fewer frames, or no "
                         "sequence-form model)")


def vars_of(seq) -> dict:
    """A sequence record's fields (a TestSequence or a SimpleNamespace)."""
    return seq._asdict() if hasattr(seq, "_asdict") else dict(vars(seq))


def no_return_rates(sr, gt, threshold: float = NO_RETURN_AT) -> tuple[float, float]:
    """(% of no-return pixels (gt >= 1) output as depth (sr < threshold), % of true returns (gt < 1) dropped
    (sr >= threshold or NaN)); NaN where there is no pixel of the kind."""
    sr, gt = np.asarray(sr), np.asarray(gt)
    as_depth = sr < threshold  # NaN compares False: no return
    sky = gt >= 1.0
    as_depth_pct = 100.0 * as_depth[sky].mean() if sky.any() else float("nan")
    dropped_pct = 100.0 * (~as_depth[~sky]).mean() if (~sky).any() else float("nan")
    return float(as_depth_pct), float(dropped_pct)


def interior(no_return, scale: int) -> np.ndarray:
    """(H, W) True for HR pixels whose LR block (scale x scale) and its 8 neighbours hold one kind only, the
    pixel's (all without a return, or all with one): the insides of the regions, where the LR pixels the
    networks read near it are pure; False near the edges that an LR block straddles."""
    from scipy import ndimage

    blocks = block_mean(np.asarray(no_return, float), scale)
    pure = ndimage.minimum_filter((blocks == 1.0).astype(np.uint8), size=3, mode="nearest") | ndimage.minimum_filter(
        (blocks == 0.0).astype(np.uint8), size=3, mode="nearest")
    return np.kron(pure, np.ones((scale, scale), np.uint8)).astype(bool)


def block_majority(no_return, scale: int) -> np.ndarray:
    """(H, W) one decision per LR block, known from the truth: no return where at least half of its scale x scale
    HR pixels have none (a tie is no return). It minimises the two errors' total, not each of them: a measure of
    what the regions' ragged edges cost any decision made per LR pixel, which only placing an edge inside a block
    beats."""
    blocks = block_mean(np.asarray(no_return, float), scale) >= 0.5
    return np.kron(blocks, np.ones((scale, scale), np.uint8)).astype(bool)




def _pooled(outputs, keep=None) -> tuple[np.ndarray, np.ndarray]:
    """[(sr, gt) per scene] -> (sr, gt) of all their pixels (those where `keep`, one mask per scene), flat."""
    keep = keep or [None] * len(outputs)
    pick = lambda x, k: np.asarray(x).ravel() if k is None else np.asarray(x)[k]
    return (np.concatenate([pick(sr, k) for (sr, _), k in zip(outputs, keep)]),
            np.concatenate([pick(gt, k) for (_, gt), k in zip(outputs, keep)]))


def bicubic_output(clip: Clip, scale: int) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(jaxsr.bicubic(clip.lr[clip.scored], scale=scale)), clip.gt[clip.scored]


def tv_output(clip: Clip, frames, scale: int) -> tuple[np.ndarray, np.ndarray]:
    """TV on the clip's frames at positions `frames` (each solved with its own window of 2 TV_TR + 1 frames)."""
    out = []
    for t in frames:
        window = frame_windows(clip.lr, [t], TV_TR)[0]
        out.append(np.asarray(jaxsr.tv_super_resolve(window, scale=scale, tr=TV_TR))[TV_TR])
    return np.stack(out), clip.gt[frames]


def method_scores(outputs) -> dict:
    """{"psnr": (scenes, T), "ssim": (scenes, T)} per-frame scores of [(sr, gt) per scene]."""
    scores = [frame_scores(sr, gt) for sr, gt in outputs]
    return {"psnr": np.stack([p for p, _ in scores]), "ssim": np.stack([s for _, s in scores])}


def regime_label(photons, snr) -> str:
    return f"{photons:g} photons, SNR {PAPER if snr is None else f'{snr:g}'}"


def frame_interval(a, b, spacing: float, seed: int = 0):
    """Mean difference a - b of per-frame scores ((T,) or (rows, T)) of frames `spacing` apart in their
    sequence, with its 95 % block-bootstrap interval (`jaxsr.paired_interval`): blocks span about
    `harness.scoring.BLOCK` frames of the sequence, as `interval` resamples consecutive frames, so frames
    spread far apart are resampled one by one."""
    block = int(np.clip(round(BLOCK / max(spacing, 1.0)), 1, np.shape(a)[-1]))
    return jaxsr.paired_interval(jax.random.key(seed), a, b, block=block)


def evaluate(models: dict, seqs: dict, *, frames: int, photons=PHOTONS, snrs=SNRS, tv_frames: int = 0,
             seed: int = 0, sensor=Sensor(), paper: bool = True, no_return: bool = True, ambient=None,
             static: bool = False, log=print) -> dict:
    """Score bicubic, TV (tv_frames > 0) and `models` ({label: Model}) on `seqs` ({name: sequence record with
    depth, intensity, fps, snr}) at every (photons, snr) regime, plus the paper's (14 photons, own SNR), and the
    no-return measure. ambient: {label: alpha} for models whose output is also no return where
    `jaxsr.sensor.ambient_only` flags a pixel at that false-alarm rate (as `ambient_alpha` of
    `super_resolve_histograms`), {label: ("shares", alpha)} where `jaxsr.sensor.no_return_shares` say so, or
    {label: ("keep", alpha)} for `returns_kept`. static: the scenes held still around each scored frame
    (`benchmark_clips`). Returns the raw results: {"regimes": [{"photons", "snr", "scores":
    {method: {"psnr", "ssim"}: (scenes, T)}, "tv_frames": positions in the scored frames}], "no_return": [...]}
    (NumPy arrays)."""
    total = len(next(iter(seqs.values())).depth)
    scored = scored_frames(frames, total)
    # TV's frames: tv_frames of the scored ones, spread over them (positions in `scored`)
    tv_idx = scored_frames(tv_frames, len(scored)) if tv_frames else np.zeros(0, int)
    sequence_form = any(m.architecture.sequence_form(m.config) for m in models.values())
    radius = total if sequence_form else max([TV_TR if tv_frames else 0] + [m.config.tr for m in models.values()])
    grid = [(float(p), float(s)) for p in photons for s in snrs]
    if paper:
        grid.append((DEFAULT_MEAN_SIGNAL, None))
    ambient = {label: decision_of(v) for label, v in (ambient or {}).items()}
    tests = tuple(sorted(set(ambient.values())))
    window = max(radius, AMBIENT_RADIUS) if tests else radius
    if static:
        check_static(scored, total, window, "evaluate")

    def outputs_of(label, model, clips, flags):
        if ambient.get(label, ("",))[0] == "keep":
            return [(returns_kept(model, c.network_input(model.config.inputs), c.scored, flags[name][ambient[label]]),
                     c.gt[c.scored]) for name, c in clips.items()]
        out = [scored_output(model, c) for c in clips.values()]
        if label not in ambient:
            return out
        return [(no_return_where(sr, flags[name][ambient[label]]), gt) for name, (sr, gt) in zip(clips, out)]

    results = {"scored": scored, "tv_idx": tv_idx, "spacing": total / len(scored),
               "tv_spacing": total / max(len(tv_idx), 1), "regimes": [], "no_return": [], "scenes": list(seqs),
               "methods": ["bicubic"] + (["TV"] if tv_frames else []) + list(models)}
    for k, (p, s) in enumerate(grid):
        started = time.time()
        key = jax.random.fold_in(jax.random.key(seed), k)
        clips, flags = benchmark_clips(seqs, p, s, scored=scored, radius=radius, key=key, sensor=sensor, tests=tests,
                                    static=static)
        scores = {"bicubic": method_scores([bicubic_output(c, sensor.scale) for c in clips.values()])}
        if tv_frames:
            scores["TV"] = method_scores([tv_output(c, c.scored[tv_idx], sensor.scale) for c in clips.values()])
        for label, model in models.items():
            scores[label] = method_scores(outputs_of(label, model, clips, flags))
        results["regimes"].append({"photons": p, "snr": s, "scores": scores})
        log(f"{regime_label(p, s)}: " + ", ".join(f"{m} {v['psnr'].mean():.2f} dB" for m, v in scores.items())
            + f" ({time.time() - started:.0f} s)")
    if no_return:
        dark = with_no_return(seqs, seed=seed)
        for k, p in enumerate(q for q in photons if q >= NO_RETURN_MIN_PHOTONS):
            key = jax.random.fold_in(jax.random.key(seed + 1), k)
            clips, flags = benchmark_clips(dark, float(p), NO_RETURN_SNR, scored=scored, radius=radius, key=key,
                                        sensor=sensor, tests=tests, static=static)
            outputs = {"bicubic": [bicubic_output(c, sensor.scale) for c in clips.values()]}
            for label, model in models.items():
                outputs[label] = outputs_of(label, model, clips, flags)
            # per frame: the added regions are one mask, but a scene's own sky moves with its camera
            inside = [np.stack([interior(g >= 1.0, sensor.scale) for g in gt]) for _, gt in outputs["bicubic"]]
            majority = [np.stack([block_majority(g >= 1.0, sensor.scale) for g in gt]).astype(np.float32)
                        for _, gt in outputs["bicubic"]]
            outputs[MAJORITY] = [(m, gt) for m, (_, gt) in zip(majority, outputs["bicubic"])]
            rates = {m: no_return_rates(*_pooled(o)) for m, o in outputs.items()}
            inner = {m: no_return_rates(*_pooled(o, inside)) for m, o in outputs.items()}
            results["no_return"].append({"photons": float(p), "snr": NO_RETURN_SNR, "rates": rates,
                                         "interior": inner, "interior_share": float(np.mean(inside))})
            log(f"no return, {p:g} photons: " + ", ".join(f"{m} {a:.1f} % as depth, {d:.1f} % dropped"
                                                          for m, (a, d) in rates.items()))
    return results



def no_return_decision(counts, sensor, setting):
    """(T, h, w) no-return decision of (T, h, w, K) counts for an `ambient` setting (`decision_of`):
    `ambient_only`'s flags or `no_return_shares`, at its false-alarm rate; for ("keep", alpha), where a head may
    mark no return (`returns_kept`): `ambient_only` of each pixel's own photons over its 9 frames; for ("pooled",
    alpha), `jaxsr upscale`'s (`jaxsr.sensor.quiet_pixels`): those of the quiet pixels pooled around it too, and no
    hole that returns enclose (`without_holes`); ("pooled-sky", alpha): that and the pixels beside the sky
    (`jaxsr.sensor.beside_sky`, measured, not the default)."""
    kind, alpha = decision_of(setting)
    tests = {"flags": ambient_only, "shares": no_return_shares, "keep": functools.partial(ambient_only, pixels=1),
             "pooled": quiet_pixels,
             "pooled-sky": lambda counts, sensor, alpha: beside_sky(quiet_pixels(counts, sensor, alpha=alpha))}
    if kind not in tests:
        raise ValueError(f"no_return_decision: unknown decision {kind!r}; expected one of {sorted(tests)}")
    return tests[kind](counts, sensor, alpha=alpha)


def returns_kept(model, x, frames, quiet) -> np.ndarray:
    """HR output (F, H, W) of `model` (one with a no-return head) on `frames` (indices) of its input `x` (T, h,
    w[, C]), its no-return decision overruled where the LR block's own photons show a return: a pixel is no return
    only where the head says so AND `quiet` (F, h, w: `no_return_decision` of ("keep", alpha), the block's
    histograms summed over 9 frames passing for ambient light alone). A head trained where ambient light is common
    can call a dim surface of a dark scene sky (a couple of photons in one bin, no ambient light around); summed
    over the frames those photons stand out. A block that a sky edge crosses holds a return, so its sky part is
    output as depth: the price, on the regions' edges. Windows edge-replicated as `super_resolve_frames`'.
    `jaxsr.inference.iter_returns_kept` makes the same decision streaming every frame; this computes only the
    scored frames' windows."""
    depth, logit = no_return_outputs(model, frame_windows(x, frames, model.config.tr))
    return overrule_no_return(np.stack([depth, logit], axis=-1), quiet, model.config.no_return_logit)


def decision_of(setting) -> tuple[str, float]:
    """An `ambient` setting of `evaluate` as its test: an alpha -> ("flags", alpha); ("shares", alpha) and
    ("keep", alpha) kept."""
    return (str(setting[0]), float(setting[1])) if isinstance(setting, tuple) else ("flags", float(setting))


def load_models(specs, logits=(), alphas=(), shares=(), keep=()) -> tuple[dict, dict, dict]:
    """TR0 and TR4 bundled, and each NAME=PATH of --model that exists (PATH a file, a run folder or the name of
    bundled weights such as tr4-photons; a printed line for one that does not), each NAME=LOGIT of
    --no-return-logit run at that no-return threshold (`jaxsr.nn.with_no_return_logit`), each NAME=ALPHA of
    --ambient-alpha with the ambient-only test at that false-alarm rate, each of --no-return-shares with
    `no_return_shares` at it, each of `keep` (real_photons' --keep-returns) keeping the returns its block's own
    photons show. Returns ({label: Model}, {label: source}, {label: alpha, ("shares", alpha) or ("keep", alpha)})."""
    thresholds = _named_numbers(logits, specs, "--no-return-logit", "LOGIT")
    decisions = {"--ambient-alpha": _named_numbers(alphas, specs, "--ambient-alpha", "ALPHA"),
                 "--no-return-shares": _named_numbers(shares, specs, "--no-return-shares", "ALPHA"),
                 "--keep-returns": _named_numbers(keep, specs, "--keep-returns", "ALPHA")}
    named = [name for given in decisions.values() for name in given]
    if len(named) != len(set(named)):
        twice = sorted({n for n in named if named.count(n) > 1})
        raise SystemExit(f"{', '.join(f for f, g in decisions.items() if set(g) & set(twice))} all name {twice}: "
                         "one decision per model name")
    ambient = dict(decisions["--ambient-alpha"])
    ambient.update({k: ("shares", v) for k, v in decisions["--no-return-shares"].items()})
    ambient.update({k: ("keep", v) for k, v in decisions["--keep-returns"].items()})
    if any(not 0.0 < decision_of(a)[1] < 1.0 for a in ambient.values()):
        raise SystemExit(f"{', '.join(f for f, g in decisions.items() if g)}: ALPHA is a false-alarm rate in (0, 1), "
                         "such as 0.001")
    models = {"TR0": jaxsr.load_model("tr0"), "TR4": jaxsr.load_model("tr4")}
    info = {"TR0": "bundled tr0", "TR4": "bundled tr4"}
    for spec in specs:
        name, sep, path = spec.partition("=")
        if not sep or not name or not path:
            raise SystemExit(f"--model expects NAME=PATH, got {spec!r}")
        try:
            resolve_model_path(path)
        except FileNotFoundError:
            print(f"skipping {name}: {path} does not exist")
            info[name] = f"skipped: {path} absent"
            continue
        models[name] = jaxsr.load_model(path)
        info[name] = path
        if name in thresholds:
            try:
                models[name] = jaxsr.nn.with_no_return_logit(models[name], thresholds[name])
            except ValueError as e:
                raise SystemExit(f"--no-return-logit {name}: {e}") from None
            info[name] = f"{path} at no-return logit {thresholds[name]:g}"
        if name in ambient:
            kind, a = decision_of(ambient[name])
            if kind == "keep" and not getattr(models[name].config, "no_return_head", False):
                raise SystemExit(f"--keep-returns {name}: the model has no no-return head, so no decision to overrule")
            info[name] += {"flags": f", no return where ambient alone (alpha {a:g})",
                           "shares": f", no return by no_return_shares (alpha {a:g})",
                           "keep": f", its no return overruled where the block's own photons over 9 frames "
                                   f"show a return (alpha {a:g})"}[kind]
    return models, info, {k: v for k, v in ambient.items() if k in models}


def _named_numbers(given, specs, flag: str, what: str) -> dict:
    """{NAME: number} of NAME=NUMBER options, each NAME one of --model's."""
    out = {}
    for spec in given:
        name, sep, value = spec.partition("=")
        try:
            out[name] = float(value)
        except ValueError:
            raise SystemExit(f"{flag} expects NAME={what}, got {spec!r}") from None
        if not sep or name not in [m.partition("=")[0] for m in specs]:
            raise SystemExit(f"{flag} {spec!r}: NAME must be one of --model's names")
    return out


# ------------------------------------------------------------------------------------------------ held-out measures

def away_from_edges(gt) -> np.ndarray:
    """(T, H, W) True for HR pixels with a return (normalised ground truth < 1) whose 8 neighbours all hold a
    return; none beyond the frame counts against it."""
    ret = np.asarray(gt) < 1.0
    return np.stack([ndimage.minimum_filter(r.astype(np.uint8), size=3, mode="nearest").astype(bool) for r in ret])


def dropped_error(sr, gt) -> float:
    """% of the squared error (output clipped to [0, 1], NaN as no return, as PSNR counts it) that lies on true
    returns output as no return, anywhere in the frame; NaN where there is no error."""
    sr, gt = np.asarray(sr, np.float64), np.asarray(gt, np.float64)
    out = np.clip(np.where(np.isnan(sr), 1.0, sr), 0.0, 1.0)
    err = (out - gt) ** 2
    total = err.sum()
    return 100.0 * float(err[(gt < 1.0) & (out >= NO_RETURN_AT)].sum() / total) if total > 0 else float("nan")


def shares(sr, gt) -> tuple[float, float, int, int]:
    """(% of returns away from the edges output as no return (sr >= NO_RETURN_AT or NaN), % of no-return pixels
    (gt >= 1) output as depth, how many pixels of each kind): NaN where there is none of a kind."""
    sr, gt = np.asarray(sr), np.asarray(gt)
    as_depth = sr < NO_RETURN_AT  # NaN compares False: no return
    inner, sky = away_from_edges(gt), gt >= 1.0
    dropped = 100.0 * float((~as_depth[inner]).mean()) if inner.any() else float("nan")
    shown = 100.0 * float(as_depth[sky].mean()) if sky.any() else float("nan")
    return dropped, shown, int(inner.sum()), int(sky.sum())


def regime_key(seed: int, photons: float, snr):
    """One noise key per regime, from its numbers (wrapped into fold_in's 32 bits): the same photons whatever else
    runs, and for the paper's (snr None) not those of SNR 1.3."""
    regime = (int(photons * 1000) * 7919 + int(-1 if snr is None else snr * 1000)) % 2 ** 32
    return jax.random.fold_in(jax.random.key(seed), regime)
