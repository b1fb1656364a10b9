"""Scene-adaptive model: measure the motion in a recording, pick the TR that the frame-rate study found best for
that motion (beyond the paper, which fixes TR per model), or for photon histograms the bundled model a simulated
study found best at the motion and photon level.

The paper's frame-rate study shows the trade: more frames help while objects move little between frames, and
hurt once they move far (the network cannot align them). `estimate_motion` measures the motion of the moving
parts of the scene in LR pixels per frame from the centre-of-mass frames themselves, by block matching at
several frame lags; `choose_tr` looks that motion up in the table `experiments/paper/fps_study.py` measured
(`jaxsr/weights/frame_rate_study.json`: PSNR of each TR against the same estimator's motion, and each TR's
frames/s) and returns the best TR within a frame-rate budget; `choose_photon_model` does the same over every
bundled model that reads histograms, in the table `experiments/studies/model_auto.py` measured
(`jaxsr/weights/model_auto_study.json`: PSNR against signal photons per pixel and motion); `resolve_model` loads
the bundled weights `choose_tr` picks (`jaxsr upscale --model auto` on depth frames).
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..io.checkpoint import load_model

STUDY_TABLE = Path(__file__).parents[1] / "weights" / "frame_rate_study.json"
SEARCH_RADIUS = 6  # LR px: block matching searches shifts up to this far
LAGS = (1, 2, 4, 8)
# fewer moving pixels than this share of the surface's are noise: static scenes through jaxsr's sensor model at
# 3-100 signal photons and SNR 0.1-5, with and without sky, showed at most 0.3 % (tests/inference/test_adaptive.py)
MIN_MOVING = 0.004
MIN_SURFACE = 0.05  # fewer pixels holding a surface than this share: nothing to measure motion on
COHERENCE = 0.08  # a surface's pixel lies within this share of the depth's spread of its 3x3 median
BORDER = 2  # px left out at the frame edges, where the 5x5 blocks are edge-replicated


def _median3(frames):
    """3x3 median of (N, h, w) frames (edge-replicated): removes the centre of mass's wrong-peak outliers."""
    p = jnp.pad(frames, ((0, 0), (1, 1), (1, 1)), mode="edge")
    h, w = frames.shape[1:]
    stack = jnp.stack([p[:, i : i + h, j : j + w] for i in range(3) for j in range(3)])
    return jnp.sort(stack, axis=0)[4]


def _box(x, r=2):
    """Mean over a (2r+1)^2 neighbourhood of (N, h, w), edge-replicated."""
    p = jnp.pad(x, ((0, 0), (r, r), (r, r)), mode="edge")
    h, w = x.shape[1:]
    c = jnp.cumsum(jnp.cumsum(jnp.pad(p, ((0, 0), (1, 0), (1, 0))), 1), 2)
    k = 2 * r + 1
    return (c[:, k:, k:] - c[:, :h, k:] - c[:, k:, :w] + c[:, :h, :w]) / (k * k)


def _coherent(frames, tolerance):
    """(N, h, w) bool: pixels that hold a surface's depth. A pixel is coherent where its raw depth lies within
    `tolerance` of its 3x3 median; a surface's depth does (on a slope the median is the pixel's own), while the
    centre of mass of ambient light alone (sky, beyond the gate, too few photons) falls anywhere in the gate and
    does mostly not. A pixel holds a surface where most of its 3x3 neighbourhood is coherent: a sky pixel passes
    by chance now and then, its neighbours seldom with it."""
    coherent = (jnp.abs(frames - _median3(frames)) <= tolerance).astype(jnp.float32)
    return _box(coherent, 1) >= 0.5


@functools.partial(jax.jit, static_argnames="radius")
def _block_match(a, b, ma, mb, *, radius: int = SEARCH_RADIUS):
    """For every pixel of b, the shift d (|d_y|, |d_x| <= radius) minimising the local mean |b(x) - a(x - d)|
    over the 5x5 block's pixels that hold a surface in both frames (ma, mb: `_coherent`), plus a small penalty on
    |d|: along an edge many shifts fit equally well (the aperture problem), and the penalty picks the shortest of
    them instead of the first in scan order. A shift under which fewer than half of the block's pixels hold a
    surface in both frames (sky, the frame's edge) does not fit.

    Returns (|d| in px, penalised cost at d, cost at 0, whether the block holds a surface at 0, d_y, d_x), each
    (N, h, w)."""
    pa = jnp.pad(a, ((0, 0), (radius, radius), (radius, radius)))
    pm = jnp.pad(ma.astype(jnp.float32), ((0, 0), (radius, radius), (radius, radius)))  # outside the frame: none
    shifts = jnp.array([(dy, dx) for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)])
    mb = mb.astype(jnp.float32)

    def cost(d):
        start = (0, radius - d[0], radius - d[1])
        both = mb * jax.lax.dynamic_slice(pm, start, a.shape)
        share = _box(both)
        diff = _box(both * jnp.abs(b - jax.lax.dynamic_slice(pa, start, a.shape)))
        return jnp.where(share >= 0.5, diff / jnp.maximum(share, 1e-6), jnp.inf), share >= 0.5

    zero, held = cost(jnp.array([0, 0]))
    typical = jnp.nanmedian(jnp.where(held, zero, jnp.nan), axis=(1, 2), keepdims=True)
    penalty = 0.25 * jnp.nan_to_num(typical)  # per px of shift: a quarter of the noise

    def step(best, d):
        mag = jnp.sqrt(jnp.sum(d.astype(jnp.float32) ** 2))
        c = cost(d)[0] + penalty * mag
        better = c < best[1]
        return (jnp.where(better, mag, best[0]), jnp.where(better, c, best[1]), jnp.where(better, d[0], best[2]),
                jnp.where(better, d[1], best[3])), None

    none = jnp.zeros_like(zero, dtype=jnp.int32)
    (mag, best, dy, dx), _ = jax.lax.scan(step, (jnp.zeros_like(zero), zero, none, none), shifts)
    return mag, best, zero, held, dy, dx


class MotionEstimate(NamedTuple):
    """`motion`: LR px per frame of the moving parts (0 when nothing moves); `lag`: the frame lag it was
    measured at; `moving_fraction`: the share of the surface's pixels found moving; `saturated`: True when at
    every lag the shifts exceed half the search radius (the motion is at least `motion`); `surface_fraction`: the
    share of pixels that hold a surface, which the motion is measured on."""

    motion: float
    lag: int
    moving_fraction: float
    saturated: bool
    surface_fraction: float = 1.0


def estimate_motion(lr_seq, *, max_frames: int = 64) -> MotionEstimate:
    """Motion of the moving parts of a recording in LR pixels per frame, from its first `max_frames` frames.

    lr_seq: (T, h, w) LR normalised depth (centre of mass), T >= 2 (4 or more to measure anything). Only pixels
    that hold a surface count (`_coherent`): the centre of mass of ambient light alone (sky, beyond the gate, too
    few photons) falls anywhere in the gate from frame to frame. Frames are 3x3-median filtered; for frame lags
    k = 1, 2, 4, 8 (3k below T) every pair (t, t + k) is block matched (5x5 blocks of surface, shifts up to 6
    px). A pixel moves when its zero-shift difference is above twice the frame's typical (noise) difference, its
    best shift explains at least half of it, and its content is matched again at that shift twice along its way
    (`_followed`); a share of the surface under MIN_MOVING counts as noise. The motion is the mean shift of
    moving pixels over k at the longest lag whose shifts stay within half the search radius (small motions are
    measured over several frames, large ones over one); where every lag's exceed it, the shortest lag's, as
    `saturated`: the motion is at least that. Nothing moving reads 0.

    Measured (tests/inference/test_adaptive.py): translating blocks within 15 % from 0.25 to 5 px/frame; a static
    scene through jaxsr's sensor model reads 0 at 3 to 100 signal photons and frame SNR 0.1 to 5, with and without
    sky. Motion that few photons at a low SNR hide (3 photons at SNR 0.3 and below), or faster than the search
    radius with nothing matched, reads 0. Returns a `MotionEstimate` (motion, lag, moving_fraction, saturated,
    surface_fraction).
    """
    seq = np.asarray(lr_seq, np.float32)[:max_frames]
    if seq.ndim != 3 or seq.shape[0] < 2:
        raise ValueError(f"estimate_motion: expected an LR sequence (T, h, w) with T >= 2, got shape {seq.shape}")
    if not np.all(np.isfinite(seq)):
        raise ValueError("estimate_motion: the sequence holds NaN or inf; expected normalised depth in [0, 1]")
    lags, surface = lag_shares(seq)
    if surface < MIN_SURFACE:  # too few pixels hold a surface to measure anything on
        return MotionEstimate(0.0, 1, 0.0, False, surface)
    unsaturated = [k for k, (_, m, s) in lags.items() if m >= MIN_MOVING and s <= SEARCH_RADIUS / 2]
    if unsaturated:  # the longest lag measures small motions most precisely
        k = max(unsaturated)
        return MotionEstimate(lags[k][2] / k, k, lags[k][1], False, surface)
    fast = [k for k, (_, m, s) in lags.items() if m >= MIN_MOVING]
    if fast:  # moving pixels, but at every lag further than half the radius: the motion is at least that
        k = min(fast)
        return MotionEstimate(lags[k][2] / k, k, lags[k][1], True, surface)
    return MotionEstimate(0.0, 1, 0.0, False, surface)


def _followed(matched, dy, dx, k: int, steps: int = 2) -> np.ndarray:
    """(N - steps k, h, w) bool: pixels matched at shift d between frames t and t + k (`matched`, (N, h, w), pair t
    = frames t, t + k) whose content is matched again at the same shift, within 1 px, `steps` more times along
    its way: at x + d in pair t + k, x + 2d in pair t + 2k. What moves keeps moving; noise that matches some
    block at some shift does not match again where that shift leads, in frames of other noise."""
    n = matched.shape[0] - steps * k
    h, w = matched.shape[1:]
    yy, xx = np.mgrid[:h, :w]
    vy, vx = dy[:n], dx[:n]
    out = matched[:n].copy()
    for s in range(1, steps + 1):
        y, x = yy + s * vy, xx + s * vx
        inside = (y >= 0) & (y < h) & (x >= 0) & (x < w)
        y, x = np.clip(y, 0, h - 1), np.clip(x, 0, w - 1)
        t = np.arange(n)[:, None, None] + s * k
        out &= inside & matched[t, y, x] & (np.abs(dy[t, y, x] - vy) <= 1) & (np.abs(dx[t, y, x] - vx) <= 1)
    return out


def lag_shares(seq) -> tuple[dict, float]:
    """The block matching of `estimate_motion` at each lag k of LAGS (3k below T): {k: (share of the surface's
    pixels changed, share moving, their mean shift in px)}, and the share of the frames' pixels that hold a surface
    (`_coherent`). A pixel moves between frames t and t + k when its zero-shift difference is above twice the
    frame's typical (noise) difference, its best shift explains at least half of it, and its content is matched
    again at that shift where the shift leads, twice (`_followed`)."""
    seq = jnp.asarray(seq, jnp.float32)
    returns = seq[seq < 1.0]
    spread = float(jnp.percentile(returns, 99) - jnp.percentile(returns, 1)) if returns.size else 1.0
    surface = _coherent(seq, COHERENCE * max(spread, 1e-3))
    frames = _median3(seq)
    inner = np.zeros(seq.shape[1:], bool)
    inner[BORDER:-BORDER, BORDER:-BORDER] = True
    lags = {}
    for k in LAGS:
        if 3 * k >= seq.shape[0]:  # a match followed over two more pairs: frames t, t + k, t + 2k, t + 3k
            break
        mag, best, zero, held, dy, dx = (np.asarray(v) for v in _block_match(frames[:-k], frames[k:], surface[:-k],
                                                                              surface[k:]))
        held = held & inner
        if not held.any():
            lags[k] = (0.0, 0.0, 0.0)
            continue
        noise = np.nanmedian(np.where(held, zero, np.nan), axis=(1, 2), keepdims=True)
        changed = held & (zero > 2.0 * noise)
        matched = changed & (best < 0.5 * zero)
        moving = _followed(matched, dy, dx, k)
        n = len(moving)
        count = held[:n].sum()
        lags[k] = (float(changed[:n].sum() / count), float(moving.sum() / count),
                   float(mag[:n][moving].mean()) if moving.any() else 0.0)
    return lags, float(np.asarray(surface)[:, inner].mean())


class TRChoice(NamedTuple):
    """`tr`: the chosen temporal radius; `motion`: the `MotionEstimate`; `reason`: one line for people."""

    tr: int
    motion: MotionEstimate
    reason: str


def load_study(path=None) -> dict:
    """The frame-rate study table (see `experiments/paper/fps_study.py`): {"motion": [...] LR px/frame (as
    `estimate_motion` measures it), "psnr": {"0": [...], ..., "4": [...]} dB at those motions,
    "fps": {"0": frames/s, ...}, "source": how it was measured}."""
    path = STUDY_TABLE if path is None else Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"no frame-rate study table at {path}; run experiments/paper/fps_study.py --write-table"
        )
    table = json.loads(path.read_text())
    if not {"motion", "psnr", "fps"} <= table.keys():
        raise ValueError(f"{path}: expected keys motion, psnr and fps, got {sorted(table)}")
    return table


def choose_tr(lr_seq, *, min_fps: float | None = None, table: dict | None = None) -> TRChoice:
    """Pick the temporal radius for a recording from its measured motion and a frame-rate budget.

    lr_seq: (T, h, w) LR normalised depth (T >= 2). The study's PSNR of each TR is interpolated linearly in
    log motion at `estimate_motion(lr_seq).motion` (held constant beyond the measured range); among the TRs
    whose measured frames/s reach `min_fps` (all when None) the best is chosen. When none is fast enough the
    fastest is chosen and the reason says so. table: a `load_study()` dict (default: the bundled one).
    Returns a `TRChoice`.
    """
    table = load_study() if table is None else table
    est = estimate_motion(lr_seq)
    motion = np.log(np.maximum(np.asarray(table["motion"], np.float64), 1e-3))
    order = np.argsort(motion)
    at = np.log(max(est.motion, 1e-3))
    predicted = {int(tr): float(np.interp(at, motion[order], np.asarray(p)[order])) for tr, p in table["psnr"].items()}
    fps = {int(tr): float(v) for tr, v in table["fps"].items()}
    allowed = [tr for tr in predicted if min_fps is None or fps.get(tr, 0.0) >= min_fps]
    if not allowed:
        tr = max(fps, key=fps.get)
        return TRChoice(tr, est, f"no TR reaches {min_fps:g} frames/s; TR{tr} is the fastest ({fps[tr]:.1f})")
    tr = max(allowed, key=predicted.get)
    budget = "" if min_fps is None else f", {len(allowed)} TRs reach {min_fps:g} frames/s"
    # no predicted PSNR in the reason: the study's scores are its test scenes', and their error on a recording of
    # another scene and sensor is not measured
    return TRChoice(tr, est, f"motion {est.motion:.2f} LR px/frame{budget}; the best TR of the frame-rate study at it")


MODEL_TABLE = Path(__file__).parents[1] / "weights" / "model_auto_study.json"
STATIC_MOTION = 0.05  # LR px/frame: a measured motion below this reads as the table's least motion
# a model displaces the table's default only where its lead over it exceeds this many standard errors of the lead
# across the table's clips: one clip per cell chose by noise (leads of 0.1-0.7 dB that reversed on other clips,
# experiments/results/model_auto.md)
LEAD_Z = 2.0


def lead_holds(lead: float, se: float) -> bool:
    """Whether a model's lead over the table's default (dB) exceeds `LEAD_Z` standard errors `se` of that lead."""
    return lead > LEAD_Z * se


class ModelPick(NamedTuple):
    """`model`: the bundled model chosen; `motion`: the `MotionEstimate`; `signal`: the signal photons per LR
    pixel and frame it was chosen at; `reason`: one line for people."""

    model: str
    motion: MotionEstimate
    signal: float
    reason: str


def load_model_table(path=None) -> dict:
    """The table `choose_photon_model` reads (experiments/studies/model_auto.py --write-table): {"signal": [...]
    signal photons per LR pixel and frame, "motion": [...] LR px/frame (as `estimate_motion` measures it),
    "psnr": {model: [[mean dB over the cell's clips at each signal (rows) and motion (columns)]]}, "lead_se":
    {model: [[the standard error of its lead over "default" across those clips]]}, "default": the model for
    histograms the command uses without --model, "fps": {model: frames/s}, "source"}."""
    path = MODEL_TABLE if path is None else Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no model table at {path}; run experiments/studies/model_auto.py --write-table")
    table = json.loads(path.read_text())
    keys = {"signal", "motion", "psnr", "lead_se", "default", "fps"}
    if not keys <= table.keys():
        raise ValueError(f"{path}: expected keys {', '.join(sorted(keys))}, got {sorted(table)}")
    return table


def _interp2(table: dict, values, signal: float, motion: float) -> float:
    """Bilinear interpolation of a (signal, motion) grid in log signal and log motion, held at the ends."""
    xs, ys = (np.log(np.maximum(np.asarray(table[k], np.float64), 1e-3)) for k in ("signal", "motion"))
    grid = np.asarray(values, np.float64)
    at_y = np.array([np.interp(np.log(max(motion, STATIC_MOTION)), ys, row) for row in grid])
    return float(np.interp(np.log(max(signal, 1e-3)), xs, at_y))


def choose_photon_model(lr_head, signal: float, *, min_fps: float | None = None,
                        table: dict | None = None) -> ModelPick:
    """The bundled model for photon histograms or time tags, from the recording's measured signal photons per LR
    pixel and frame (`jaxsr.app.photon_levels`) and motion (`estimate_motion` of `lr_head`, its first LR
    centre-of-mass frames (T, h, w)): the model with the highest PSNR the model table measured there
    (interpolated in log signal and log motion, held at the table's ends), among those whose frames/s reach
    `min_fps` (the fastest when none does); the table's default instead where it reaches `min_fps` and the best
    model's lead over it is not more than `LEAD_Z` standard errors of that lead across the table's clips (a lead
    the clips do not establish). A signal of NaN (no return seen) reads as the table's least. table: a
    `load_model_table()` dict (default: the bundled one). No PSNR is predicted: the table's scores are its
    simulated scenes', and their error on a recording of another scene and sensor is not measured."""
    table = load_model_table() if table is None else table
    est = estimate_motion(lr_head)
    signal = float(signal) if np.isfinite(signal) else float(min(table["signal"]))
    scores = {m: _interp2(table, v, signal, est.motion) for m, v in table["psnr"].items()}
    fps = {m: float(table["fps"][m]) for m in scores}
    allowed = [m for m in scores if min_fps is None or fps[m] >= min_fps]
    seen = f"motion {est.motion:.2f} LR px/frame, {signal:.3g} signal photons per pixel and frame"
    if not allowed:
        m = max(fps, key=fps.get)
        return ModelPick(m, est, signal, f"{seen}; no model reaches {min_fps:g} frames/s, {m} is the fastest "
                                         f"({fps[m]:.1f})")
    m = max(allowed, key=scores.get)
    budget = "" if min_fps is None else f", {len(allowed)} of {len(scores)} models reach {min_fps:g} frames/s"
    default = table["default"]
    if m != default and default in allowed:
        se = _interp2(table, table["lead_se"][m], signal, est.motion)
        if not lead_holds(scores[m] - scores[default], se):
            return ModelPick(default, est, signal, f"{seen}{budget}; the default: no model's lead over it in the "
                                                   f"simulated model study there exceeds {LEAD_Z:g} standard errors")
    return ModelPick(m, est, signal, f"{seen}{budget}; the best of the simulated model study there")


def resolve_model(spec, lr_head, *, min_fps: float | None = None):
    """The model for a recording: `spec` is "auto" (`choose_tr` on `lr_head`, the recording's first LR frames
    (T, h, w), within `min_fps`; then the bundled weights of that TR) or anything `jaxsr.load_model` takes
    (tr0..tr4, a checkpoint path). Returns (Model, a one-line description for people)."""
    if spec == "auto":
        choice = choose_tr(lr_head, min_fps=min_fps)
        return load_model(f"tr{choice.tr}"), f"tr{choice.tr} (auto: {choice.reason})"
    return load_model(spec), str(spec)
