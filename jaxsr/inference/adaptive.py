"""Scene-adaptive temporal radius: measure the motion in a recording, pick the TR that the frame-rate study
found best for that motion (beyond the paper, which fixes TR per model).

The paper's frame-rate study shows the trade: more frames help while objects move little between frames, and
hurt once they move far (the network cannot align them). `estimate_motion` measures the motion of the moving
parts of the scene in LR pixels per frame from the centre-of-mass frames themselves, by block matching at
several frame lags; `choose_tr` looks that motion up in the table `experiments/paper/fps_study.py` measured
(`jaxsr/weights/frame_rate_study.json`: PSNR of each TR against the same estimator's motion, and each TR's
frames/s) and returns the best TR within a frame-rate budget; `resolve_model` loads the bundled weights it
picks (`jaxsr upscale --model auto`).
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
MIN_MOVING = 0.002  # fewer moving pixels than this share are noise
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


@functools.partial(jax.jit, static_argnames="radius")
def _block_match(a, b, *, radius: int = SEARCH_RADIUS):
    """For every pixel of b, the shift d (|d_y|, |d_x| <= radius) minimising the local mean |b(x) - a(x - d)|
    plus a small penalty on |d|: along an edge many shifts fit equally well (the aperture problem), and the
    penalty picks the shortest of them instead of the first in scan order.

    Returns (|d| in px, penalised cost at d, cost at 0), each (N, h, w)."""
    h, w = a.shape[1:]
    # outside the frame nothing matches: a shift that leaves it costs about 10 per pixel
    pa = jnp.pad(a, ((0, 0), (radius, radius), (radius, radius)), constant_values=10.0)
    shifts = jnp.array([(dy, dx) for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)])

    def cost(d):
        shifted = jax.lax.dynamic_slice(pa, (0, radius - d[0], radius - d[1]), a.shape)
        return _box(jnp.abs(b - shifted))

    zero = cost(jnp.array([0, 0]))
    penalty = 0.25 * jnp.median(zero, axis=(1, 2), keepdims=True)  # per px of shift: a quarter of the noise

    def step(best, d):
        mag = jnp.sqrt(jnp.sum(d.astype(jnp.float32) ** 2))
        c = cost(d) + penalty * mag
        better = c < best[1]
        return (jnp.where(better, mag, best[0]), jnp.where(better, c, best[1])), None

    (mag, best), _ = jax.lax.scan(step, (jnp.zeros_like(zero), zero), shifts)
    return mag, best, zero


class MotionEstimate(NamedTuple):
    """`motion`: LR px per frame of the moving parts (0 when nothing moves); `lag`: the frame lag it was
    measured at; `moving_fraction`: the share of pixels found moving; `saturated`: True when even one frame
    apart the motion reaches the search radius (the motion is at least `motion`)."""

    motion: float
    lag: int
    moving_fraction: float
    saturated: bool


def estimate_motion(lr_seq, *, max_frames: int = 64) -> MotionEstimate:
    """Motion of the moving parts of a recording in LR pixels per frame, from its first `max_frames` frames.

    lr_seq: (T, h, w) LR normalised depth (centre of mass), T >= 2. Frames are 3x3-median filtered; for frame
    lags k = 1, 2, 4, 8 every pair (t, t + k) is block matched (5x5 blocks, shifts up to 6 px). A pixel moves
    when its zero-shift difference is above twice the frame's typical (noise) difference and its best shift
    explains at least half of it (a share under 0.2 % of the pixels counts as noise). The motion is the mean
    best shift of moving pixels over k at the longest lag whose shifts stay within half the search radius
    (small motions are measured over several frames, large ones over one). When no lag qualifies the lag-1
    shift is returned, or the search radius when changed pixels match no shift at all, as `saturated`: the
    motion is at least that. Measured on synthetic translating blocks (tests/inference/test_adaptive.py): within 15 %
    from 0.25 to 2 px/frame. Returns a `MotionEstimate` (motion, lag, moving_fraction, saturated).
    """
    seq = np.asarray(lr_seq, np.float32)[:max_frames]
    if seq.ndim != 3 or seq.shape[0] < 2:
        raise ValueError(f"estimate_motion: expected an LR sequence (T, h, w) with T >= 2, got shape {seq.shape}")
    if not np.all(np.isfinite(seq)):
        raise ValueError("estimate_motion: the sequence holds NaN or inf; expected normalised depth in [0, 1]")
    frames = _median3(jnp.asarray(seq))
    lags = {}  # k -> (share of changed pixels, share of matched (moving) pixels, their mean shift in px)
    for k in LAGS:
        if k >= seq.shape[0]:
            break
        mag, best, zero = (np.asarray(v) for v in _block_match(frames[:-k], frames[k:]))
        noise = np.median(zero, axis=(1, 2), keepdims=True)
        changed = zero > 2.0 * noise
        changed[:, :BORDER] = changed[:, -BORDER:] = changed[:, :, :BORDER] = changed[:, :, -BORDER:] = False
        moving = changed & (best < 0.5 * zero)
        lags[k] = (float(changed.mean()), float(moving.mean()), float(mag[moving].mean()) if moving.any() else 0.0)
    unsaturated = [k for k, (_, m, s) in lags.items() if m >= MIN_MOVING and s <= SEARCH_RADIUS / 2]
    if unsaturated:  # the longest lag measures small motions most precisely
        k = max(unsaturated)
        return MotionEstimate(lags[k][2] / k, k, lags[k][1], False)
    changed, moving, shift = lags[1]
    if moving >= MIN_MOVING and moving >= 0.5 * changed:
        return MotionEstimate(shift, 1, moving, True)
    if changed >= MIN_MOVING:  # pixels change, but no shift within the radius explains them
        return MotionEstimate(float(SEARCH_RADIUS), 1, changed, True)
    return MotionEstimate(0.0, 1, 0.0, False)


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


def resolve_model(spec, lr_head, *, min_fps: float | None = None):
    """The model for a recording: `spec` is "auto" (`choose_tr` on `lr_head`, the recording's first LR frames
    (T, h, w), within `min_fps`; then the bundled weights of that TR) or anything `jaxsr.load_model` takes
    (tr0..tr4, a checkpoint path). Returns (Model, a one-line description for people)."""
    if spec == "auto":
        choice = choose_tr(lr_head, min_fps=min_fps)
        return load_model(f"tr{choice.tr}"), f"tr{choice.tr} (auto: {choice.reason})"
    return load_model(spec), str(spec)
