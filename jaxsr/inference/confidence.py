"""A confidence people can threshold: the probability that each HR pixel holds a return, and a standard deviation
of its depth, from what the network says and what the photons behind each LR pixel show.

The probability is a logistic (Platt) model of a few features per HR pixel:

- the network's no-return logit, for a model with a no-return head (`Model.has_no_return_head`);
- whether the network's depth reads as no return (at or above `NO_RETURN_AT`), for a model without one;
- the photons' own evidence for a return: log(1 - log p) of `jaxsr.sensor.return_significance` of the LR pixel's
  histogram summed over `EVIDENCE_FRAMES` frames, and of its 3 x 3 neighbourhood's, interpolated bilinearly to HR;
- the photon level: log(1 + signal photons) of the pixel's summed histogram.

A dim, static surface that a head trained among ambient light calls no return keeps its probability where its
photons summed over the frames stand out of the ambient light; sky keeps a low one where they do not. The depth's
standard deviation grows with the centre of mass's own spread (its Poisson variance from the pixel's histogram,
one frame and summed over the frames) and with the spread of the network's output around the pixel (edges),
scaled so that 90 % intervals (+- 1.645 sigma) hold 90 % of the true depths where it was fitted.

The coefficients were fitted on simulated training-style clips (`jaxsr.training.confidence`), never on the test
scenes, and ship in `jaxsr/weights/confidence.json` with the command that fitted them. Every function here is a
pure function of arrays, jit- and vmap-compatible; `confidence_frame` is one frame's whole computation.
"""

from __future__ import annotations

import functools
import json
from collections import deque
from collections.abc import Iterable, Iterator
from importlib import resources
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..config import Sensor
from ..sensor.peaks import (
    centre_of_mass_std,
    peak_evidence,
    return_significance,
    window_sums,
)

__all__ = [
    "EVIDENCE_FRAMES",
    "NO_RETURN_AT",
    "INTERVAL_Z",
    "HEAD_FEATURES",
    "PHOTON_FEATURES",
    "STD_FEATURES",
    "ConfidenceCoefficients",
    "load_confidence",
    "coefficients_for",
    "evidence_maps",
    "return_features",
    "return_probability",
    "std_features",
    "depth_std_bins",
    "confidence_frame",
    "no_return_logit_of",
    "no_return_by_probability",
    "iter_count_windows",
]

EVIDENCE_FRAMES = 9  # frames a pixel's histograms are summed over for its evidence (the no-return tests' window)
NO_RETURN_AT = 0.99  # a normalised output at or above it reads as no return (the benchmark's reading)
INTERVAL_Z = 1.6448536  # a 90 % interval is +- this many standard deviations
_MAX_LOGIT = 30.0  # logits clipped to it: beyond, the head says nothing more, and float32 sigmoids saturate
_SPREAD_FLOOR = 0.01  # bins: the output's local spread below it reads as flat
# the features, in the order of the coefficients (`return_features`, `std_features`)
HEAD_FEATURES = ("bias", "head_logit", "evidence", "evidence_3x3", "signal", "head_logit_x_signal")
PHOTON_FEATURES = ("bias", "output_no_return", "evidence", "evidence_3x3", "signal", "output_x_signal")
STD_FEATURES = ("bias", "log_com_std", "log_com_std_summed", "log_spread")


class ConfidenceCoefficients(NamedTuple):
    """One model's fitted coefficients: `probability` over `features` (HEAD_FEATURES for a model with a no-return
    head, PHOTON_FEATURES otherwise), `std` over STD_FEATURES (log sigma in bins, the 90 % scale folded in)."""

    features: tuple[str, ...]
    probability: tuple[float, ...]
    std: tuple[float, ...]


@functools.cache
def load_confidence() -> dict:
    """The fitted coefficients shipped with jaxsr: {"models": {name: {...}}, "command": ..., ...} from
    jaxsr/weights/confidence.json."""
    text = resources.files("jaxsr").joinpath("weights", "confidence.json").read_text()
    table = json.loads(text)
    for name, entry in table["models"].items():
        want = HEAD_FEATURES if entry["head"] else PHOTON_FEATURES
        if len(entry["probability"]) != len(want) or len(entry["std"]) != len(STD_FEATURES):
            raise ValueError(f"jaxsr/weights/confidence.json: model {name!r} has {len(entry['probability'])} "
                             f"probability and {len(entry['std'])} std coefficients; expected {len(want)} and "
                             f"{len(STD_FEATURES)}")
    return table


def coefficients_for(model_name: str | None, has_head: bool) -> ConfidenceCoefficients:
    """The coefficients of a bundled model fitted by name (tr4-ambient, ...); for any other model, the generic set
    of its kind ("head" for a model with a no-return head, "photons" for one without)."""
    models = load_confidence()["models"]
    entry = models.get(model_name) if isinstance(model_name, str) else None
    if entry is None or bool(entry["head"]) != bool(has_head):
        entry = models["head" if has_head else "photons"]
    features = HEAD_FEATURES if entry["head"] else PHOTON_FEATURES
    return ConfidenceCoefficients(features, tuple(entry["probability"]), tuple(entry["std"]))


def _evidence(log_p):
    """log(1 - log p): 0 for no evidence, about 4.5 at float32's smallest p-value."""
    return jnp.log1p(-jnp.minimum(log_p, 0.0))


@functools.partial(jax.jit, static_argnames=("sensor",))
def evidence_maps(window, sensor: Sensor = Sensor()):
    """The photon features of the centre frame of a (F, h, w, K) window of histograms (F = `EVIDENCE_FRAMES`, frames
    beyond a sequence zero): a dict of (h, w) float32 maps: "evidence" (the pixel's histograms summed over the
    window: log(1 - log p) of `return_significance`), "evidence_3x3" (its 3 x 3 neighbourhood's), "signal"
    (log(1 + the summed histogram's signal photons, `peak_evidence`)), "com_std" (`centre_of_mass_std` of the
    centre frame's histogram) and "com_std_summed" (of the summed one), both in bins. Counts finite and >= 0."""
    window = jnp.asarray(window, jnp.float32)
    summed = jnp.sum(window, axis=0)
    centre = window[window.shape[0] // 2]
    around = window_sums(summed[None], 1, 3)[0]
    signal, _ = peak_evidence(summed, sensor)
    return {"evidence": _evidence(return_significance(summed, sensor)),
            "evidence_3x3": _evidence(return_significance(around, sensor)),
            "signal": jnp.log1p(signal),
            "com_std": centre_of_mass_std(centre, sensor),
            "com_std_summed": centre_of_mass_std(summed, sensor)}


def _at_hr(lr_map, scale: int):
    """(h, w) -> (h r, w r): bilinear between the LR pixels' centres (edges held)."""
    h, w = lr_map.shape[-2:]
    return jax.image.resize(lr_map, (*lr_map.shape[:-2], h * scale, w * scale), "linear")


def return_features(maps: dict, hr_depth, head_logit=None):
    """(H, W, len(features)) features of the return probability: HEAD_FEATURES where `head_logit` (H, W) is given
    (the no-return logit of a model with a head), PHOTON_FEATURES from the HR depth `hr_depth` (H, W) otherwise.
    `maps`: `evidence_maps` of the LR pixels (h, w), H = r h."""
    scale = hr_depth.shape[-1] // maps["evidence"].shape[-1]
    ev, ev3, signal = (_at_hr(maps[name], scale) for name in ("evidence", "evidence_3x3", "signal"))
    if head_logit is not None:
        first = jnp.clip(jnp.nan_to_num(head_logit, nan=_MAX_LOGIT), -_MAX_LOGIT, _MAX_LOGIT)
    else:
        first = (jnp.nan_to_num(hr_depth, nan=1.0) >= NO_RETURN_AT).astype(jnp.float32)
    return jnp.stack([jnp.ones_like(ev), first, ev, ev3, signal, first * signal], axis=-1)


def return_probability(features, coefficients):
    """P(the pixel holds a return) = sigmoid(features . coefficients): (..., F) -> (...) float32 in [0, 1]."""
    z = jnp.einsum("...f,f->...", features, jnp.asarray(coefficients, features.dtype))
    return jax.nn.sigmoid(z).astype(jnp.float32)


def std_features(maps: dict, hr_depth, bins_per_unit):
    """(H, W, len(STD_FEATURES)) features of the depth's standard deviation: log of the centre of mass's std (one
    frame, summed), bilinear at HR, and of the output's spread (the std over the 3 x 3 HR pixels around, in bins:
    `bins_per_unit` bins per normalised unit, K for the trained gate)."""
    scale = hr_depth.shape[-1] // maps["com_std"].shape[-1]
    one, summed = (_at_hr(jnp.log(maps[name]), scale) for name in ("com_std", "com_std_summed"))
    d = jnp.clip(jnp.nan_to_num(hr_depth, nan=1.0), 0.0, 1.0) * bins_per_unit
    padded = jnp.pad(d, 1, mode="edge")
    h, w = d.shape
    around = jnp.stack([padded[i:i + h, j:j + w] for i in range(3) for j in range(3)])
    spread = jnp.std(around, axis=0)
    return jnp.stack([jnp.ones_like(one), one, summed, jnp.log(spread + _SPREAD_FLOOR)], axis=-1)


def depth_std_bins(features, coefficients):
    """The depth's standard deviation in bins, exp(features . coefficients): (..., F) -> (...)."""
    z = jnp.einsum("...f,f->...", features, jnp.asarray(coefficients, features.dtype))
    return jnp.exp(jnp.clip(z, -20.0, 20.0)).astype(jnp.float32)


@functools.partial(jax.jit, static_argnames=("sensor", "head"))
def _frame(window, hr_depth, head_logit, probability, std, bins_per_unit, sensor, head):
    maps = evidence_maps(window, sensor)
    p = return_probability(return_features(maps, hr_depth, head_logit if head else None), probability)
    sigma = depth_std_bins(std_features(maps, hr_depth, bins_per_unit), std)
    return p, sigma


def confidence_frame(window, hr_depth, coefficients: ConfidenceCoefficients, sensor: Sensor = Sensor(),
                     *, head_logit=None, bins_per_unit=None):
    """One frame's confidence: (P(return) (H, W) float32 in [0, 1], depth std in bins (H, W) float32).

    window: (F, h, w, K) histograms centred on the frame (F = `EVIDENCE_FRAMES`; zeros beyond the sequence);
    hr_depth: (H, W) the network's normalised depth (before any no-return decision); head_logit: (H, W) the
    no-return logit of a model with a head (required where `coefficients` are a head's, refused otherwise);
    bins_per_unit: bins per normalised depth unit (default K: the gate spans the depth scale). Raises ValueError
    for NaN or negative counts and shapes that do not fit."""
    window = np.asarray(window, np.float32)
    if window.ndim != 4 or window.shape[-1] != sensor.bins:
        raise ValueError(f"confidence_frame: expected a window (F, h, w, {sensor.bins}) of histograms, got shape "
                         f"{window.shape}")
    if not np.all(np.isfinite(window)) or window.min(initial=0.0) < 0:
        raise ValueError("confidence_frame: counts must be finite and >= 0 photons")
    hr_depth = np.asarray(hr_depth, np.float32)
    h, w = window.shape[1:3]
    if hr_depth.ndim != 2 or hr_depth.shape[0] % h or hr_depth.shape[1] % w or (
            hr_depth.shape[0] // h != hr_depth.shape[1] // w) or hr_depth.shape[0] < h:
        raise ValueError(f"confidence_frame: hr_depth must be (r h, r w) for the window's (h, w) = {(h, w)}, got "
                         f"{hr_depth.shape}")
    head = coefficients.features == HEAD_FEATURES
    if head != (head_logit is not None):
        raise ValueError("confidence_frame: give head_logit exactly when the coefficients are a no-return head's")
    logit = np.zeros_like(hr_depth) if head_logit is None else np.asarray(head_logit, np.float32)
    if logit.shape != hr_depth.shape:
        raise ValueError(f"confidence_frame: head_logit {logit.shape} and hr_depth {hr_depth.shape} differ")
    per_unit = float(sensor.bins if bins_per_unit is None else bins_per_unit)
    p, sigma = _frame(window, hr_depth, logit, jnp.asarray(coefficients.probability, jnp.float32),
                      jnp.asarray(coefficients.std, jnp.float32), jnp.float32(per_unit), sensor, head)
    return np.asarray(p), np.asarray(sigma)


def no_return_logit_of(probability):
    """The logit of P(no return) = 1 - `probability`: log((1 - p) / p), +-inf at 0 and 1 (the scale the
    no-return threshold, `--no-return-logit`, is set on)."""
    p = np.asarray(probability, np.float64)
    with np.errstate(divide="ignore"):
        return (np.log1p(-p) - np.log(p)).astype(np.float32)


def no_return_by_probability(hr_depth, probability, threshold: float = 0.0) -> np.ndarray:
    """HR depth with no return (1.0) where the logit of P(no return), log((1 - p) / p), is above `threshold`
    (a logit; 0: where the return's probability is below one half): the no-return decision of `jaxsr upscale`'s
    --no-return-logit on the confidence. (..., H, W) depth and probability of one shape."""
    hr_depth, probability = np.asarray(hr_depth, np.float32), np.asarray(probability, np.float32)
    if hr_depth.shape != probability.shape:
        raise ValueError(f"no_return_by_probability: depth {hr_depth.shape} and probability {probability.shape} "
                         "differ; expected one shape")
    return np.where(no_return_logit_of(probability) > np.float32(threshold), np.float32(1.0), hr_depth)


def iter_count_windows(counts: Iterable, frames: int = EVIDENCE_FRAMES) -> Iterator[np.ndarray]:
    """(frames, h, w, K) float32 windows of a stream of (h, w, K) histogram frames, one per frame, centred on it,
    zeros beyond the sequence (as `iter_ambient_only` sums them); frame t comes once frame t + frames // 2 has been
    read. Holds `frames` frames at a time."""
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1 or frames % 2 == 0:
        raise ValueError(f"iter_count_windows: frames must be an odd integer >= 1, got {frames!r}")
    r = frames // 2
    held: deque = deque()
    first = t = 0

    def window():
        zero = np.zeros_like(held[0])
        return np.stack([held[k - first] if 0 <= k - first < len(held) else zero for k in range(t - r, t + r + 1)])

    for i, c in enumerate(counts):
        c = np.asarray(c, np.float32)
        if held and c.shape != held[-1].shape:
            raise ValueError(f"iter_count_windows: frame {i} has shape {c.shape}, expected {held[-1].shape}")
        held.append(c)
        if i == t + r:
            yield window()
            t += 1
            if len(held) > 2 * r:
                held.popleft()
                first += 1
    while held and t <= first + len(held) - 1:
        yield window()
        t += 1
