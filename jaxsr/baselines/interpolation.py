"""Classical upsampling baselines: bicubic (Keys, a = -0.5) and Lanczos-3.

Both are separable resamplings with pixel centres aligned (output pixel o samples input coordinate
(o + 0.5) / scale - 0.5) and edge replication beyond the frame, written as two small matrix products so
they are fast, exact in float32 and differentiable. Interior pixels equal PIL's `Image.resize` with
BICUBIC / LANCZOS; near the border PIL renormalises the truncated kernel instead of replicating edges.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from ..checks import require_array


def keys_cubic(x, a: float = -0.5):
    """Keys' cubic convolution kernel (a = -0.5 reproduces quadratics)."""
    x = np.abs(x)
    return np.where(
        x <= 1,
        (a + 2) * x**3 - (a + 3) * x**2 + 1,
        np.where(x < 2, a * x**3 - 5 * a * x**2 + 8 * a * x - 4 * a, 0.0),
    )


def lanczos_kernel(x, lobes: int = 3):
    """Lanczos window sinc(x) sinc(x / lobes) on |x| < lobes."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(np.abs(x) < lobes, np.sinc(x) * np.sinc(x / lobes), 0.0)


@functools.lru_cache(maxsize=64)
def resampling_matrix(n_in: int, scale: int, kernel: str) -> np.ndarray:
    """`(n_in * scale, n_in)` matrix of an upsampling along one axis with edge replication.

    Rows sum to 1 (the Lanczos taps are normalised, as is usual).
    """
    fn, support = {"bicubic": (keys_cubic, 2), "lanczos": (lanczos_kernel, 3)}[kernel]
    out = np.arange(n_in * scale)
    centre = (out + 0.5) / scale - 0.5
    taps = np.floor(centre)[:, None] + np.arange(-support + 1, support + 1)[None, :]
    weights = fn(centre[:, None] - taps)
    weights /= weights.sum(axis=1, keepdims=True)
    matrix = np.zeros((n_in * scale, n_in))
    np.add.at(matrix, (np.repeat(out, taps.shape[1]), np.clip(taps, 0, n_in - 1).astype(int).ravel()), weights.ravel())
    return matrix


def _upsample(lr, scale: int, kernel: str, name: str):
    lr = require_array(name, "lr", lr)  # None or text: a TypeError that says so
    if lr.ndim < 2:
        raise ValueError(f"{name}: expected (..., h, w) frames, got shape {lr.shape}")
    if not (isinstance(scale, int) and scale >= 1):
        raise ValueError(f"{name}: scale must be a positive integer, got {scale!r}")
    dtype = jnp.result_type(lr.dtype, float)
    rows = jnp.asarray(resampling_matrix(lr.shape[-2], scale, kernel), dtype)
    cols = jnp.asarray(resampling_matrix(lr.shape[-1], scale, kernel), dtype)
    return jnp.einsum("Hh,...hw,Ww->...HW", rows, lr.astype(dtype), cols)


def bicubic(lr, *, scale: int = 4):
    """Bicubic (Keys, a = -0.5) upsampling with edge replication.

    Args:
      lr: (..., h, w) frames (e.g. normalised depth); no frames or empty ones give an empty result
        (..., h * scale, w * scale).
      scale: integer upsampling factor.
    Returns:
      `(..., h * scale, w * scale)`; not clipped (cubic overshoot is left to the metric's clipping). Raises
      TypeError for None or non-numeric `lr`, ValueError for fewer than 2 dimensions or a bad scale.
    """
    return _upsample(lr, scale, "bicubic", "bicubic")


def lanczos(lr, *, scale: int = 4):
    """Lanczos-3 upsampling with edge replication and normalised taps.

    Args:
      lr: (..., h, w) frames.
      scale: integer upsampling factor.
    Returns:
      `(..., h * scale, w * scale)`; not clipped.
    """
    return _upsample(lr, scale, "lanczos", "lanczos")
