"""Sensor effects beyond the paper's forward model: dark counts, hot and dead pixels, regions with no return,
a per-clip IRF width, and background-subtracted (negative) counts.

docs/sensor-model.md, section 2 ("Sensor effects"). The forward model gives Poisson rates (..., h, w, K) per LR
pixel and bin (`expected_histograms`, `calibrated_rates`); the effects here act on those rates before the
Poisson draw (`dark_counts`, `hot_pixels`, `dead_pixels`), on the HR radial depth before the rates are computed
(`no_return_regions`, `thin_returns`), on the sensor config (`with_irf_sigma`), or on measured counts
(`clip_negative_counts`).
Every function is pure and jit/vmap compatible, takes its key first and its options by keyword. Eagerly, an
option out of its domain is a `ValueError`; traced (under `jit`, `vmap` or `grad`), a scalar out of its domain
makes the result NaN, as in `jaxsr.sensor.forward`.

Pixel masks (hot, dead, no return) are drawn over the last two spatial axes only and shared by every leading
axis: a hot pixel is a property of the sensor, so it is the same in every frame of a clip. `jax.vmap` over keys
gives each clip its own masks.
"""

from __future__ import annotations


import jax
import jax.numpy as jnp
import numpy as np

from ..checks import is_concrete, require_bins
from ..config import Sensor

__all__ = [
    "dark_counts",
    "hot_pixels",
    "dead_pixels",
    "no_return_regions",
    "thin_returns",
    "with_irf_sigma",
    "clip_negative_counts",
]


def _check_scalar(name, label, value, *, lo=0.0, strict=False, hi=None, unit=""):
    """Eagerly refuse a concrete `value` (any shape) outside [lo, hi] (or (lo, hi] if strict) or not finite;
    return a boolean array, True where in the domain (traced: the mask the caller selects NaN with)."""
    if is_concrete(value):
        v = np.asarray(value, np.float64)
        ok = np.isfinite(v) & ((v > lo) if strict else (v >= lo))
        if hi is not None:
            ok &= v <= hi
        if not np.all(ok):
            bound = f"{'>' if strict else '>='} {lo:g}" + ("" if hi is None else f" and <= {hi:g}")
            raise ValueError(f"{name}: {label} must be finite and {bound}{unit}, got {value} (under jit the "
                             "result would be NaN)")
    v = jnp.asarray(value)
    ok = jnp.isfinite(v) & ((v > lo) if strict else (v >= lo))
    return ok if hi is None else ok & (v <= hi)


def _rates(name, rates):
    rates = jnp.asarray(rates)
    if rates.ndim < 3:
        raise ValueError(f"{name}: rates must have shape (..., h, w, K) (LR rows, cols, bins), got {rates.shape}")
    return jnp.asarray(rates, jnp.promote_types(rates.dtype, jnp.float32))


def dark_counts(rates, *, rate_per_bin):
    """Add dark counts (and any other flat background not tied to the scene): `rate_per_bin` photons in every
    bin of every pixel, on top of the calibrated ambient.

    Args:
      rates: (..., h, w, K) Poisson rates (photons), e.g. from `calibrated_rates`.
      rate_per_bin: photons per bin, finite and >= 0: a scalar or an array broadcastable to (..., h, w) (one
        rate per pixel).
    Returns:
      (..., h, w, K) rates + rate_per_bin. The expected counts of a draw are the sum. Dark counts lower the
      SNR below the frame SNR the rates were calibrated to (that SNR counts ambient only). NaN if, traced,
      `rate_per_bin` is out of its domain.
    """
    rates = _rates("dark_counts", rates)
    ok = _check_scalar("dark_counts", "rate_per_bin", rate_per_bin, unit=" photons per bin")
    dark = jnp.asarray(rate_per_bin, rates.dtype)
    return rates + jnp.where(ok, dark, jnp.nan)[..., None]


def _pixel_mask(key, shape, fraction):
    """(h, w) bool: each LR pixel independently True with probability `fraction`."""
    return jax.random.uniform(key, shape) < fraction


def hot_pixels(key, rates, *, fraction, rate, return_mask=False):
    """Hot pixels: a random `fraction` of the LR pixels each get `rate` extra photons in every bin (a dark count
    rate far above the others').

    Args:
      key: a `jax.random` key (the mask).
      rates: (..., h, w, K) Poisson rates (photons).
      fraction: probability that a pixel is hot, in [0, 1].
      rate: extra photons per bin of a hot pixel, finite and >= 0 (scalar).
      return_mask: also return the (h, w) boolean mask.
    Returns:
      (..., h, w, K) rates, raised by `rate` in every bin of the hot pixels (the same pixels in every leading
      index: frames of one clip share a sensor); with `return_mask`, (rates, mask). NaN if, traced, an option is
      out of its domain.
    """
    rates = _rates("hot_pixels", rates)
    ok = _check_scalar("hot_pixels", "fraction", fraction, hi=1.0) & _check_scalar(
        "hot_pixels", "rate", rate, unit=" photons per bin")
    mask = _pixel_mask(key, rates.shape[-3:-1], fraction)
    out = rates + jnp.where(mask, jnp.asarray(rate, rates.dtype), 0.0)[..., None]
    out = jnp.where(ok, out, jnp.nan)
    return (out, mask) if return_mask else out


def dead_pixels(key, rates, *, fraction, return_mask=False):
    """Dead pixels: a random `fraction` of the LR pixels record nothing (rate 0 in every bin, so their counts
    are 0 and the centre of mass reads them as no return).

    Args:
      key: a `jax.random` key (the mask).
      rates: (..., h, w, K) Poisson rates (photons).
      fraction: probability that a pixel is dead, in [0, 1].
      return_mask: also return the (h, w) boolean mask.
    Returns:
      (..., h, w, K) rates, zero on the dead pixels (the same in every leading index); with `return_mask`,
      (rates, mask). NaN if, traced, `fraction` is out of its domain.
    """
    rates = _rates("dead_pixels", rates)
    ok = _check_scalar("dead_pixels", "fraction", fraction, hi=1.0)
    mask = _pixel_mask(key, rates.shape[-3:-1], fraction)
    out = jnp.where(ok, jnp.where(mask[..., None], 0.0, rates), jnp.nan)
    return (out, mask) if return_mask else out


def no_return_regions(key, depth, *, fraction, sky=0.5, blob_size=16, return_mask=False):
    """Regions with no return (sky, absorbing or specular surfaces, open doors): set a random `fraction` of the
    HR pixels to +inf radial depth.

    The regions are the top `fraction` of a random field: `sky` times a ramp that is highest at the top row
    (a sky band with a ragged skyline) plus (1.01 - sky) times smooth Gaussian noise on a grid of `blob_size`
    HR pixels (blobs). sky = 1 gives a band of the top rows, sky = 0 blobs anywhere. The field is thresholded
    at its (1 - fraction) quantile, so the share of masked pixels is `fraction` up to one pixel's worth.
    Intensity is left alone: a no-return region still collects ambient light from its intensity.

    Args:
      key: a `jax.random` key.
      depth: (..., H, W) radial depth (m); the mask is (H, W), shared by every leading index (frames).
      fraction: share of HR pixels without a return, in [0, 1].
      sky: weight of the sky band against the blobs, in [0, 1].
      blob_size: HR pixels per cell of the noise grid (static int >= 1): the blobs' size.
      return_mask: also return the (H, W) boolean mask.
    Returns:
      (..., H, W) depth with +inf (no return) on the masked pixels; with `return_mask`, (depth, mask). NaN
      everywhere if, traced, `fraction` or `sky` is out of its domain.
    """
    depth = jnp.asarray(depth)
    if depth.ndim < 2:
        raise ValueError(f"no_return_regions: depth must have shape (..., H, W), got {depth.shape}")
    if int(blob_size) != blob_size or blob_size < 1:
        raise ValueError(f"no_return_regions: blob_size must be an integer >= 1 HR pixels, got {blob_size}")
    ok = _check_scalar("no_return_regions", "fraction", fraction, hi=1.0) & _check_scalar(
        "no_return_regions", "sky", sky, hi=1.0)
    h, w = depth.shape[-2:]
    gh, gw = -(-h // int(blob_size)) + 1, -(-w // int(blob_size)) + 1
    noise = jax.image.resize(jax.random.normal(key, (gh, gw)), (h, w), "cubic")
    noise = noise / jnp.maximum(jnp.std(noise), 1e-6)
    ramp = 2.0 * (1.0 - (jnp.arange(h, dtype=noise.dtype) + 0.5) / h)[:, None] * jnp.sqrt(3.0)  # std 1, as the noise's
    sky = jnp.asarray(sky, noise.dtype)
    # A little noise even at sky = 1: a skyline within a row or two, and no ties at the threshold.
    field = sky * ramp + (1.0 - sky + 0.01) * noise
    fraction = jnp.asarray(fraction, noise.dtype)
    threshold = jnp.quantile(field, jnp.clip(1.0 - fraction, 0.0, 1.0))
    mask = ((field > threshold) | (fraction >= 1.0)) & (fraction > 0.0)
    out = jnp.where(mask, jnp.inf, depth)
    out = jnp.where(ok, out, jnp.nan)
    return (out, mask) if return_mask else out


def thin_returns(key, shape, *, lines, width_range=(1.0, 8.0), max_lines: int = 8):
    """Thin structures in front of the regions with no return: poles, masts, cables, a lattice tower's beams
    against the sky, which blobs and bands of sky (`no_return_regions`) never show a network.

    `lines` straight lines (the first `lines` of `max_lines` drawn), each through a uniform random point of the
    frame at a uniform random angle, as wide as a log-uniform draw in `width_range` (HR pixels). A caller keeps
    the scene's depth on them inside its no-return regions (`jaxsr.training.regime_clips`).

    Args:
      key: a `jax.random` key.
      shape: (H, W) HR pixels.
      lines: how many lines, an integer in [0, max_lines] (may be traced: one draw per clip; traced, a count
        outside the range is clipped to it, as a mask cannot carry NaN).
      width_range: (lo, hi) widths in HR pixels, 0 < lo <= hi (static).
      max_lines: the most lines (static int >= 0).
    Returns:
      (H, W) bool, True on the lines: one mask, for every frame of a clip (as `no_return_regions`' is).
      jit/vmap-able; eagerly an option out of its domain is a `ValueError`.
    """
    if int(max_lines) != max_lines or max_lines < 0:
        raise ValueError(f"thin_returns: max_lines must be an integer >= 0, got {max_lines}")
    lo, hi = (float(v) for v in width_range)
    if not (0.0 < lo <= hi < float("inf")):
        raise ValueError(f"thin_returns: width_range must be (lo, hi) HR pixels with 0 < lo <= hi, got {width_range}")
    if is_concrete(lines) and not (int(lines) == lines and 0 <= lines <= max_lines):
        raise ValueError(f"thin_returns: lines must be an integer in [0, {max_lines}], got {lines}")
    h, w = (int(v) for v in shape)
    k_point, k_angle, k_width = jax.random.split(key, 3)
    centre = jax.random.uniform(k_point, (int(max_lines), 2)) * jnp.array([h, w], jnp.float32)
    angle = jax.random.uniform(k_angle, (int(max_lines),), maxval=jnp.pi)
    width = jnp.exp(jax.random.uniform(k_width, (int(max_lines),), minval=np.log(lo), maxval=np.log(hi)))
    y = jnp.arange(h, dtype=jnp.float32)[:, None] + 0.5
    x = jnp.arange(w, dtype=jnp.float32)[None, :] + 0.5
    # distance of each pixel centre from each line: |(p - c) . n| with n the line's unit normal
    dist = jnp.abs((y[None] - centre[:, 0, None, None]) * jnp.cos(angle)[:, None, None]
                   - (x[None] - centre[:, 1, None, None]) * jnp.sin(angle)[:, None, None])
    on = (dist < width[:, None, None] / 2) & (jnp.arange(int(max_lines)) < lines)[:, None, None]
    return on.any(0)


def with_irf_sigma(sensor: Sensor, irf_sigma):
    """The sensor with another IRF width (bins): `sensor.replace(irf_sigma=irf_sigma)`, checked.

    The pulse's sigma (`Sensor.pulse.sigma`) is a pytree leaf, so the width may be traced: a per-clip width drawn
    inside a
    jitted, vmapped data source simulates each clip with its own pulse (`irf_bin_weights` reads it from the
    config). Eagerly a width that is not finite and > 0 is a `ValueError`; traced, it makes the rates NaN.
    Returns a `Sensor`.
    """
    _check_scalar("with_irf_sigma", "irf_sigma", irf_sigma, strict=True, unit=" bins")
    return sensor.replace(irf_sigma=irf_sigma)


def clip_negative_counts(counts, sensor: Sensor = Sensor()):
    """Background-subtracted histograms (some published data sets) -> counts the depth extractors accept.

    `centre_of_mass` and `maximum_likelihood_depth` refuse negative counts (eagerly a `ValueError`, traced "no
    return"), which is right for raw photon counts. For histograms whose background was subtracted, clip them
    at zero and say how many were negative.

    Args:
      counts: (..., K) counts, K = `sensor.bins`; NaN stays NaN (and is still refused downstream).
    Returns:
      (counts clipped at 0 (float, same shape), number of negative counts (int32 scalar)).
    """
    counts = require_bins("clip_negative_counts", counts, sensor)
    counts = jnp.asarray(counts, jnp.promote_types(counts.dtype, jnp.float32))
    negative = counts < 0
    return jnp.where(negative, jnp.zeros_like(counts), counts), jnp.sum(negative, dtype=jnp.int32)
