"""Image and video quality metrics on normalised depth (docs/sensor-model.md, section 5).

All take (..., H, W) frames with any leading axes and return one value per frame (or per transition for
temporal coherence), so report the mean over frames yourself. Predictions are clipped to [0, 1] (the
data range) before scoring; the ground truth is used as given. Values are not checked, eager or traced
alike: a NaN in either frame makes that frame's PSNR and SSIM NaN (a prediction's +-inf is clipped like any
value); in `temporal_coherence` a NaN prediction never counts as flicker, nor a NaN ground truth as static.
`huber_loss`, the training loss, is the exception: it scores the prediction unclipped (clipping before the loss
would stop its gradients outside [0, 1]) and averages over the axes asked for.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

# MSE floor: a perfect prediction scores 120 dB instead of inf, so means and gradients stay finite.
_MSE_FLOOR = 1e-12


def _pair(name, pred, gt):
    pred, gt = jnp.asarray(pred), jnp.asarray(gt)
    if pred.shape != gt.shape or pred.ndim < 2:
        raise ValueError(
            f"{name}: pred and gt must be (..., H, W) arrays of equal shape, got {pred.shape} and {gt.shape}"
        )
    dtype = jnp.result_type(pred.dtype, gt.dtype, float)
    return jnp.clip(pred.astype(dtype), 0.0, 1.0), gt.astype(dtype)


def psnr(pred, gt):
    """Peak signal-to-noise ratio in dB, peak 1: 20 log10(1 / RMSE) per frame (capped at 120 dB).

    Args:
      pred: (..., H, W) normalised depth; clipped to [0, 1].
      gt: (..., H, W) ground-truth normalised depth, of the same shape.
    Returns:
      (...) PSNR of each frame.
    """
    pred, gt = _pair("psnr", pred, gt)
    mse = jnp.mean((pred - gt) ** 2, axis=(-2, -1))
    return -10.0 * jnp.log10(jnp.maximum(mse, _MSE_FLOOR))


def huber_loss(pred, gt, *, delta: float = 0.01, axis=None):
    """Mean Huber loss (the paper's Eq. 3, Keras's `Huber`): per pixel e = pred - gt,
    0.5 e^2 if |e| <= delta else delta (|e| - delta / 2), averaged over `axis`.

    pred, gt: arrays of the same shape, e.g. (B, H, W). axis: None (every pixel: a scalar) or the axes to
    average over, e.g. (-2, -1) for one loss per frame (B,). Returns the mean over `axis`.
    """
    e = jnp.abs(pred - gt)
    # min(e, delta) written once gives both branches: the quadratic part and the linear excess beyond delta
    quad = jnp.minimum(e, delta)
    return jnp.mean(0.5 * quad**2 + delta * (e - quad), axis=axis)


def _gaussian_kernel(size: int, sigma: float):
    x = np.arange(size) - (size - 1) / 2
    k = np.exp(-(x**2) / (2 * sigma**2))
    return k / k.sum()


def _filter_valid(x, kernel):
    """Separable 'valid' filtering of (N, H, W) frames with a 1-D kernel along both axes."""
    k = jnp.asarray(kernel, x.dtype)
    n = k.shape[0]
    rows = sum(k[i] * x[:, i : x.shape[1] - n + 1 + i, :] for i in range(n))
    return sum(k[i] * rows[:, :, i : x.shape[2] - n + 1 + i] for i in range(n))


def ssim(pred, gt, *, win_size: int = 11, sigma: float = 1.5, k1: float = 0.01, k2: float = 0.03):
    """Windowed SSIM: Gaussian window, valid region, mean of the SSIM map (data range 1).

    Equals `tf.image.ssim` and scikit-image's `structural_similarity(gaussian_weights=True, sigma=1.5,
    use_sample_covariance=False, data_range=1)`.

    Args:
      pred: (..., H, W) normalised depth with H, W >= win_size; clipped to [0, 1].
      gt: (..., H, W) ground-truth normalised depth, of the same shape.
    Returns:
      (...) SSIM of each frame.
    """
    pred, gt = _pair("ssim", pred, gt)
    if min(pred.shape[-2:]) < win_size:
        raise ValueError(f"ssim: frames must be at least {win_size}x{win_size}, got {pred.shape[-2:]}")
    lead = pred.shape[:-2]
    x = pred.reshape((-1,) + pred.shape[-2:])
    y = gt.reshape((-1,) + gt.shape[-2:])
    kernel = _gaussian_kernel(win_size, sigma)
    mu_x, mu_y = _filter_valid(x, kernel), _filter_valid(y, kernel)
    var_x = _filter_valid(x * x, kernel) - mu_x**2
    var_y = _filter_valid(y * y, kernel) - mu_y**2
    cov = _filter_valid(x * y, kernel) - mu_x * mu_y
    c1, c2 = k1**2, k2**2
    ssim_map = ((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))
    return jnp.mean(ssim_map, axis=(-2, -1)).reshape(lead)


def ssim_global(pred, gt, *, c1: float = 1e-4, c2: float = 9e-4):
    """The paper's Eq. 2 SSIM with whole-frame means, variances and covariance (secondary metric).

    Args:
      pred: (..., H, W) normalised depth; clipped to [0, 1].
      gt: (..., H, W) ground-truth normalised depth, of the same shape.
    Returns:
      (...) global SSIM of each frame.
    """
    pred, gt = _pair("ssim_global", pred, gt)
    axes = (-2, -1)
    mu_x, mu_y = jnp.mean(pred, axes), jnp.mean(gt, axes)
    var_x, var_y = jnp.var(pred, axes), jnp.var(gt, axes)
    cov = jnp.mean((pred - mu_x[..., None, None]) * (gt - mu_y[..., None, None]), axes)
    return ((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))


class TemporalCoherence(NamedTuple):
    """Flicker of a super-resolved sequence where the ground truth is static.

    counts: (..., T-1) pixels per transition with |GT_{t+1} - GT_t| <= eps_gt and |SR_{t+1} - SR_t| > eps.
    mean: (...) Tc, the mean of `counts` over transitions.
    flicker_fraction: (...) flickering pixels / static pixels, over all transitions.
    """

    counts: jax.Array
    mean: jax.Array
    flicker_fraction: jax.Array


def temporal_coherence(pred_seq, gt_seq, *, eps: float = 0.01, eps_gt: float = 1e-6) -> TemporalCoherence:
    """Temporal coherence Tc: count of static ground-truth pixels whose prediction changes by more than eps.

    Meaningful on static-camera sequences. The paper's Eq. 4 counts any change (eps = 0); real-valued outputs
    change a little almost everywhere, so report eps = 0.01 (default), 1/255 and 0.05 beside it.

    Args:
      pred_seq: (..., T, H, W) normalised depth sequence, T >= 2; clipped to [0, 1].
      gt_seq: (..., T, H, W) ground-truth normalised depth sequence, of the same shape.
    Returns:
      `TemporalCoherence(counts (..., T-1), mean (...), flicker_fraction (...))`.
    """
    pred, gt = _pair("temporal_coherence", pred_seq, gt_seq)
    if pred.ndim < 3 or pred.shape[-3] < 2:
        raise ValueError(f"temporal_coherence: expected (..., T, H, W) with T >= 2, got {pred.shape}")
    static = jnp.abs(jnp.diff(gt, axis=-3)) <= eps_gt
    flicker = static & (jnp.abs(jnp.diff(pred, axis=-3)) > eps)
    counts = jnp.sum(flicker, axis=(-2, -1))
    n_static = jnp.sum(static, axis=(-3, -2, -1))
    fraction = jnp.sum(counts, axis=-1) / jnp.maximum(n_static, 1)
    return TemporalCoherence(counts, jnp.mean(counts.astype(fraction.dtype), axis=-1), fraction)
