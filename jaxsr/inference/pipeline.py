"""The whole pipeline as one function: HR depth + intensity and a sensor -> a quality score of the SR output.

sensor model (rates) -> Poisson draw (or, with no key, the rates themselves) -> centre of mass -> the network
-> PSNR or Huber loss against the normalised HR ground truth. One jitted, pure function of arrays and pytrees,
so `jax.grad` differentiates it with respect to the sensor's physical leaves (the `Sensor`'s pulse sigma,
`ambient_floor`, `r_min`, the gate's bin width, the depth span), the photon levels (`snr`, `mean_signal`), the
scene (depth, intensity) and the network's weights, and `jax.vmap` maps it over a batch of sensors (a `Sensor`
whose leaves are arrays with a leading axis). Through a draw the derivative is a surrogate (`simulate_histograms(gradient=...)`); with
`key=None` it is exact.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ..config import DEFAULT_MEAN_SIGNAL, Sensor
from ..eval.metrics import huber_loss, psnr
from ..nn.duf import check_conv
from ..nn.model import Model
from ..sensor.peaks import centre_of_mass
from ..sensor.poisson import PATHWISE_ESTIMATORS
from .traced import network_over_sequence
from ..sensor.forward import (levels_valid, check_photon_args, expected_histograms, normalise_depth,
                              simulate_histograms)

METRICS = ("psnr", "huber")


def _lr_depth(key, depth, intensity, sensor, snr, mean_signal, *, gradient, sampler, window):
    """(T, H, W) scene -> (T, h, w) centre-of-mass depth: of a draw, or of the expected counts when key is None."""
    if key is None:
        hist = expected_histograms(depth, intensity, sensor, snr=snr, mean_signal=mean_signal)
    else:
        hist = simulate_histograms(key, depth, intensity, sensor, snr=snr, mean_signal=mean_signal,
                                   sampler=sampler, gradient=gradient)
    return centre_of_mass(hist, sensor, window=window)


@functools.partial(jax.jit, static_argnames=("metric", "gradient", "sampler", "conv3d_impl", "precision"))
def _pipeline(key, depth, intensity, sensor, model, snr, mean_signal, window, huber_delta, *, metric, gradient,
              sampler, conv3d_impl, precision="default"):
    lr = _lr_depth(key, depth, intensity, sensor, snr, mean_signal, gradient=gradient, sampler=sampler,
                   window=window)
    hr = network_over_sequence(model, lr, conv3d_impl=conv3d_impl, precision=precision)
    gt = normalise_depth(depth, sensor)
    score = jnp.mean(psnr(hr, gt)) if metric == "psnr" else huber_loss(hr, gt, delta=huber_delta)
    # Out-of-domain levels or sensor leaves (reachable only traced: under jit, or per element under vmap) give
    # NaN histograms, which the centre of mass would turn into a plausible depth and score: NaN instead.
    return jnp.where(levels_valid(sensor, snr, mean_signal), score, jnp.nan)


def pipeline_metric(
    key,
    depth,
    intensity,
    sensor: Sensor,
    model: Model,
    *,
    snr,
    mean_signal=DEFAULT_MEAN_SIGNAL,
    metric: str = "psnr",
    gradient: str = "normal",
    sampler: str = "fast",
    window=None,
    huber_delta=0.01,
    conv3d_impl: str = "auto",
    precision: str = "default",
):
    """Score of the network's super-resolved output for a scene seen by `sensor`: the whole pipeline, jitted.

    HR depth + intensity -> `simulate_histograms` (calibrated over the whole sequence to `snr`, `mean_signal`)
    -> `centre_of_mass` -> the network (its temporal form, ends edge-replicated, BN in inference mode) -> the
    mean over frames of PSNR (dB, prediction clipped to [0, 1]) or the Huber loss (unclipped) against
    `normalise_depth(depth)`. Differentiable with respect to `depth`, `intensity`, `snr`, `mean_signal`,
    `huber_delta`, the sensor's leaves and `model`'s params; vmappable over any of them (e.g. a `Sensor`
    whose leaves have a leading batch axis). Through the draw the derivative is `gradient`'s surrogate, biased
    where a pixel's histogram peak can jump to a background bin (experiments/results/sensor_design.md); with
    `key=None` the expected counts replace the draw and the derivative is exact (but for the centre of mass's
    argmax and median, piecewise).

    Args:
      key: a `jax.random` key for the photon draw, or None for the noise-free path (expected counts).
      depth: (T, H, W) radial metres (no return: NaN, inf, negative, beyond d_max); (H, W) = `sensor.hr_shape`.
      intensity: (T, H, W) reflectivity proxy in [0, 1].
      sensor: the `Sensor`; its `scale` must be the model's.
      model: a `Model` (e.g. `jaxsr.load_model("tr0")`).
      snr: frame SNR (> 0).
      mean_signal: mean signal photons per LR pixel with a return (>= 0).
      metric: "psnr" (dB, higher is better) or "huber" (the training loss, lower is better).
      gradient: the draw's surrogate derivative, "normal" or "straight-through" (`simulate_histograms`).
      sampler: the draw's sampler, "fast" or "exact".
      window: the centre of mass's half-width (default: by `sensor.irf_sigma`, 1 bin up to 0.5 bins of IRF width,
        2 above: a step in the score).
      huber_delta: the Huber loss's delta.
      conv3d_impl: how the network's convolutions run (`apply_model`).
      precision: how they multiply, `jaxsr.config.PRECISIONS` (`apply_model`): "default", "float32" or
        "bfloat16" (bfloat16 operands, float32 sums; gradients flow through the rounding as through float32).
    Returns:
      A scalar: the mean over the T frames of the chosen metric; NaN where a value reached only under a trace
      (jit, vmap) is out of its domain (snr <= 0, mean_signal < 0, a sensor leaf <= 0, NaN or inf); concrete
      out-of-domain values raise ValueError.
    """
    depth, intensity = check_photon_args("pipeline_metric", depth, intensity, sensor, snr, mean_signal)
    if depth.ndim != 3:
        raise ValueError(f"pipeline_metric: depth and intensity must be sequences (T, H, W), got shape {depth.shape}")
    # the pipeline feeds the network centre-of-mass depth alone, and runs it in the forms the DUF network has
    if not isinstance(model, Model) or model.reads_photons or "window" not in model.forms:
        raise ValueError(f"pipeline_metric: model must be a jaxsr.Model of the DUF network reading depth alone (e.g. "
                         f"jaxsr.load_model('tr0')), got {getattr(model, 'kind', type(model).__name__)}"
                         + (f" reading {model.channels}" if isinstance(model, Model) and model.forms else ""))
    scale = model.architecture.scale(model.config)
    if scale != sensor.scale:
        raise ValueError(f"pipeline_metric: the model upsamples x{scale} but the sensor's scale is {sensor.scale}")
    if metric not in METRICS:
        raise ValueError(f"pipeline_metric: metric must be one of {METRICS}, got {metric!r}")
    if gradient not in PATHWISE_ESTIMATORS:
        raise ValueError(f"pipeline_metric: gradient must be one of {PATHWISE_ESTIMATORS}, got {gradient!r}")
    if sampler not in ("fast", "exact"):
        raise ValueError(f"pipeline_metric: sampler must be 'fast' or 'exact', got {sampler!r}")
    check_conv(conv3d_impl, precision, "pipeline_metric")
    return _pipeline(key, depth, intensity, sensor, model, snr, mean_signal, window, huber_delta, metric=metric,
                     gradient=gradient, sampler=sampler, conv3d_impl=conv3d_impl, precision=precision)
