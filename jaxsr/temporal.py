"""Temporal windows and frame-rate changes of depth sequences (the paper's input construction)."""

from __future__ import annotations

import jax.numpy as jnp


def windows(seq, tr):
    """Temporal windows of radius `tr` around every frame, edge-replicated at the sequence ends (the paper).

    seq (T, ...) -> (T, 2 tr + 1, ...): window t holds frames clip(t - tr .. t + tr, 0, T - 1).

    Returns an array of shape (T, 2 tr + 1, ...), same dtype as seq.
    """
    seq = jnp.asarray(seq)
    if tr < 0:
        raise ValueError(f"temporal radius must be >= 0, got {tr}")
    if seq.ndim < 1 or seq.shape[0] < 1:
        raise ValueError(f"expected a sequence with a leading time axis, got shape {seq.shape}")
    n = seq.shape[0]
    idx = jnp.clip(jnp.arange(n)[:, None] + jnp.arange(-tr, tr + 1)[None, :], 0, n - 1)
    return seq[idx]


def change_frame_rate(seq, fps, new_fps):
    """Subsample a sequence captured at `fps` to `new_fps` by keeping every (fps / new_fps)-th frame (the paper's
    frame-rate study: 100 FPS -> 50, 25, ...). The ratio must be an integer.

    Returns seq[::k], shape (ceil(T / k), ...) for seq (T, ...), k = fps / new_fps."""
    ratio = fps / new_fps
    step = int(round(ratio))
    if step < 1 or abs(ratio - step) > 1e-6:
        raise ValueError(f"can only subsample by an integer factor: {fps} FPS -> {new_fps} FPS is x{ratio:g}")
    return seq[::step]
