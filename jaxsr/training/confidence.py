"""Fitting the confidence (`jaxsr.inference.confidence`) on simulated clips: the return probability's logistic
(Platt) coefficients and the depth std's scale, from training-style draws that neither the test scenes nor any
held-out data enter.

`confidence_set` draws clips of a `PhotonRegime` (static and moving, dim and bright, 1-1000 photons, SNR 0.1-5, with
regions of no return) as `regime_clips` does, keeps their histograms, runs the model once and returns the features
of every HR pixel of each clip's centre frame with its truth; `fit_logistic` (Newton's method on the L2-penalised
log-loss) and `fit_depth_std` (the Laplace log-likelihood by Newton steps, then the 90 % interval's scale from the
errors' quantile) fit them. experiments/studies/confidence_fit.py runs it all and writes jaxsr/weights/
confidence.json.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..config import PhotonRegime, Sensor, TrainConfig
from ..inference.confidence import (EVIDENCE_FRAMES, INTERVAL_Z, NO_RETURN_AT, evidence_maps, return_features,
                                    std_features)
from ..nn.duf import apply_model_raw
from ..nn.inputs import network_inputs
from ..nn.model import Model
from ..scenes import training_clip
from ..sensor.effects import dark_counts, dead_pixels, hot_pixels, with_irf_sigma
from ..sensor.forward import calibrate, calibrated_rates, normalise_depth
from ..sensor.poisson import sample_poisson
from .data import _crop_origin, _regime_example_keys, _regime_no_return, regime_parameters

__all__ = ["CONFIDENCE_SEED", "CONFIDENCE_REGIME", "confidence_clips", "confidence_set", "set_features",
           "fit_logistic", "fit_depth_std"]

# apart from the benchmark's keys, training runs' and the no-return calibration's (CALIBRATION_SEED = 2**31 - 2)
CONFIDENCE_SEED = 2**31 - 3
# the draws: the training regime's effects, 1-1000 photons, SNR 0.1-5, half the clips static, half with added regions
# of no return, none of the paper's regime (its clips are among the others' levels)
CONFIDENCE_REGIME = PhotonRegime(signal_range=(1.0, 1000.0), snr_range=(0.1, 5.0), static_prob=0.5,
                                 no_return_prob=0.5, paper_prob=0.0)


def confidence_clips(key, *, frames: int, regime: PhotonRegime = CONFIDENCE_REGIME,
                     sensor: Sensor = Sensor(), patch=None):
    """One simulated clip as `jaxsr.training.regime_clips` draws it, its histograms kept: (counts (frames, h, w, K),
    gt (frames, H, W) normalised, parameters dict). patch: (rows, cols) LR, a random crop (None: whole frames).
    jit-able with frames, regime, sensor and patch static."""
    k_scene, k_par, k_sky, k_hot, k_dead, k_noise, k_crop = _regime_example_keys(key)
    depth, intensity = training_clip(k_scene, frames, sensor=sensor, motion=regime.motion,
                                     shift_range=TrainConfig().motion_range)
    p = regime_parameters(k_par, regime)
    depth, intensity = (jnp.where(p["static"], jnp.broadcast_to(x[frames // 2], x.shape), x) for x in (depth, intensity))
    depth = _regime_no_return(k_sky, depth, p, regime)
    gt = normalise_depth(depth, sensor)
    clip_sensor = with_irf_sigma(sensor, p["irf_sigma"])
    alpha, beta = calibrate(depth, intensity, clip_sensor, snr=p["snr"], mean_signal=p["mean_signal"])
    if patch is not None:
        r = sensor.scale
        y0, x0 = _crop_origin(k_crop, (depth.shape[1] // r, depth.shape[2] // r), patch, "confidence_clips")
        cut = functools.partial(jax.lax.dynamic_slice, start_indices=(0, y0 * r, x0 * r),
                                slice_sizes=(frames, patch[0] * r, patch[1] * r))
        depth, intensity, gt = cut(depth), cut(intensity), cut(gt)
    rates = calibrated_rates(depth, intensity, alpha, beta, clip_sensor)
    rates = dark_counts(rates, rate_per_bin=p["dark"])
    rates = hot_pixels(k_hot, rates, fraction=p["hot_fraction"], rate=p["hot_level"] * p["mean_signal"] / sensor.bins)
    rates = dead_pixels(k_dead, rates, fraction=p["dead_fraction"])
    return sample_poisson(k_noise, rates), gt, p


def confidence_set(model: Model, *, draws: int, key=None, regime: PhotonRegime = CONFIDENCE_REGIME,
                   sensor: Sensor = Sensor(), patch=None, log=None) -> dict:
    """What the confidence is fitted on: `draws` clips (`confidence_clips`, whole frames or LR crops of `patch`; key default
    jax.random.key(CONFIDENCE_SEED), clip i from fold_in(key, i)), the model (window form) run once on each clip's
    centre frame.

    Returns NumPy arrays {"maps": {name: (N, h, w)} (`evidence_maps` of the centre frame), "depth": (N, H, W) the
    network's depth before any decision, "logit": (N, H, W) its no-return logit (None without a head), "gt": (N, H,
    W) normalised truth (1.0: no return), "photons", "snr", "static": (N,) the clips' draws}, N = draws."""
    for name, value in (("draws", draws),):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"confidence_set: {name} must be an integer >= 1, got {value!r}")
    key = jax.random.key(CONFIDENCE_SEED) if key is None else key
    model = model.in_form("window")
    tr, head = int(model.config.tr), bool(model.has_no_return_head)
    frames = max(2 * tr + 1, EVIDENCE_FRAMES)
    mid = frames // 2
    inputs = tuple(model.channels)

    @jax.jit
    def one(k):
        counts, gt, p = confidence_clips(k, frames=frames, regime=regime, sensor=sensor, patch=patch)
        x = network_inputs(counts, sensor, inputs)[mid - tr:mid + tr + 1]
        raw = apply_model_raw(model.params, model.state, x[None], model.config)[0]
        lo = mid - EVIDENCE_FRAMES // 2
        return evidence_maps(counts[lo:lo + EVIDENCE_FRAMES], sensor), raw, gt[mid], p

    parts = {name: [] for name in ("maps", "depth", "logit", "gt", "photons", "snr", "static")}
    for i in range(draws):
        maps, raw, gt, p = jax.device_get(one(jax.random.fold_in(key, i)))
        parts["maps"].append(maps)
        parts["depth"].append(raw[..., 0] if head else raw)
        parts["logit"].append(raw[..., 1] if head else None)
        parts["gt"].append(gt)
        parts["photons"].append(float(p["mean_signal"]))
        parts["snr"].append(float(p["snr"]))
        parts["static"].append(bool(p["static"]))
        if log is not None and (i + 1) % 16 == 0:
            log(f"confidence_set: {i + 1} / {draws} clips")
    out = {name: np.asarray(v) for name, v in parts.items() if name not in ("maps", "logit")}
    out["maps"] = {name: np.stack([m[name] for m in parts["maps"]]) for name in parts["maps"][0]}
    out["logit"] = np.stack(parts["logit"]) if head else None
    return out


def set_features(data: dict, sensor: Sensor = Sensor(), *, bins_per_unit=None) -> dict:
    """Per HR pixel of a `confidence_set`: {"probability": (M, 6) `return_features`, "std": (M, 4) `std_features`,
    "returns": (M,) bool truth, "error_bins": (M,) |depth - truth| in bins where both hold a return (NaN
    elsewhere), "clip": (M,) the clip's index}, M = N H W."""
    per_unit = float(sensor.bins if bins_per_unit is None else bins_per_unit)
    head = data["logit"] is not None

    @jax.jit
    def one(maps, depth, logit):
        return return_features(maps, depth, logit if head else None), std_features(maps, depth, per_unit)

    fp, fs = [], []
    for i in range(len(data["gt"])):
        maps = {name: v[i] for name, v in data["maps"].items()}
        a, b = one(maps, data["depth"][i], data["logit"][i] if head else data["depth"][i])
        fp.append(np.asarray(a).reshape(-1, a.shape[-1]))
        fs.append(np.asarray(b).reshape(-1, b.shape[-1]))
    gt, depth = np.asarray(data["gt"]), np.asarray(data["depth"])
    both = (gt < 1.0) & (depth < NO_RETURN_AT)
    return {"probability": np.concatenate(fp), "std": np.concatenate(fs), "returns": gt.ravel() < 1.0,
            "error_bins": np.where(both, np.abs(depth - gt) * per_unit, np.nan).ravel(),
            "clip": np.repeat(np.arange(gt.shape[0]), gt[0].size)}


@functools.partial(jax.jit, static_argnames=("steps",))
def _newton_logistic(x, y, w, l2, steps):
    def step(beta, _):
        z = x @ beta
        p = jax.nn.sigmoid(z)
        grad = x.T @ (w * (p - y)) + l2 * beta
        hess = (x * (w * p * (1 - p))[:, None]).T @ x + l2 * jnp.eye(x.shape[1])
        return beta - jnp.linalg.solve(hess, grad), None

    beta, _ = jax.lax.scan(step, jnp.zeros(x.shape[1], x.dtype), None, length=steps)
    return beta


def fit_logistic(features, labels, *, weights=None, l2: float = 1e-3, steps: int = 30) -> np.ndarray:
    """Platt scaling: the coefficients beta minimising sum w [-y log sigmoid(x beta) - (1 - y) log(1 - sigmoid(x
    beta))] + l2 |beta|^2 / 2 by Newton's method (`steps` steps, float32).
    features: (N, F); labels: (N,) 0/1; weights: (N,) (default 1). Returns (F,) float64."""
    x = np.asarray(features, np.float64)
    y = np.asarray(labels, np.float64)
    if x.ndim != 2 or y.shape != (x.shape[0],) or not np.all(np.isfinite(x)):
        raise ValueError(f"fit_logistic: expected finite features (N, F) and labels (N,), got {x.shape}, {y.shape}")
    w = np.ones_like(y) if weights is None else np.asarray(weights, np.float64)
    w = w * (len(w) / w.sum())  # the penalty's weight independent of the pixels' count
    beta = _newton_logistic(jnp.asarray(x, jnp.float32), jnp.asarray(y, jnp.float32), jnp.asarray(w, jnp.float32),
                            jnp.float32(l2 * len(w)), steps)
    return np.asarray(beta, np.float64)


@functools.partial(jax.jit, static_argnames=("steps",))
def _laplace_fit(x, e, steps):
    """log sigma = x beta minimising sum log sigma + |e| / sigma (Newton, the Hessian's expectation: x^T x)."""
    def step(beta, _):
        z = x @ beta
        r = e * jnp.exp(-z)
        grad = x.T @ (1.0 - r)
        hess = (x * r[:, None]).T @ x + 1e-6 * jnp.eye(x.shape[1])
        return beta - jnp.linalg.solve(hess, grad), None

    beta0 = jnp.zeros(x.shape[1], x.dtype).at[0].set(jnp.log(jnp.mean(e)))
    beta, _ = jax.lax.scan(step, beta0, None, length=steps)
    return beta


def fit_depth_std(features, errors, *, coverage: float = 0.9, steps: int = 30) -> np.ndarray:
    """The depth std's coefficients: log sigma = features . beta fitted to the absolute errors `errors` (N,) (bins)
    by the Laplace likelihood, then shifted so that +- INTERVAL_Z sigma holds the share `coverage` of the errors
    (their quantile of |e| / sigma): a 90 % interval from the std holds 90 % of the fitted errors. NaN errors
    (no return on either side) are left out. Returns (F,) float64."""
    x = np.asarray(features, np.float64)
    e = np.asarray(errors, np.float64)
    keep = np.isfinite(e) & np.all(np.isfinite(x), axis=1)
    x, e = x[keep], np.maximum(e[keep], 1e-4)
    if x.shape[0] < x.shape[1]:
        raise ValueError(f"fit_depth_std: {x.shape[0]} finite errors for {x.shape[1]} coefficients")
    beta = np.asarray(_laplace_fit(jnp.asarray(x, jnp.float32), jnp.asarray(e, jnp.float32), steps), np.float64)
    ratio = e / np.exp(x @ beta)
    beta[0] += np.log(np.quantile(ratio, coverage) / INTERVAL_Z)
    return beta
