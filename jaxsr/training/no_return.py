"""Calibrating a photon model's no-return decision: the logit above which its output says "no return"
(`ModelConfig.no_return_logit`, used by `jaxsr.nn.merge_no_return`).

The head is trained with a cross-entropy whose natural threshold, logit 0 (p = 0.5), weighs a return dropped and
a no-return pixel output as depth alike. They do not cost alike: a dropped return counts at its distance. The
calibration draws a set of clips with regions of no return, photon levels log-uniform from 3 to 1000
(`no_return_set`), runs the model once (`no_return_outputs`: depth and logit before the decision), sweeps
candidate thresholds on those logits (`no_return_table`: per band of photon levels the share of no-return pixels
output as depth and of true returns dropped) and picks one (`choose_no_return_logit`): the smallest worst-band
share "as depth" among thresholds keeping the worst-band share "dropped" at or below a target, over the bands
from `min_photons` (3) up.
`calibrate_no_return` does all three. experiments/studies/no_return_threshold.py runs it on a model and saves
the calibrated copy.

Pixels are read as the benchmark reads them (experiments/studies/photon_regimes.py): an output at or above
`NO_RETURN_AT` (0.99 normalised) or NaN is "no return"; a pixel with no return is one whose ground truth is 1.0.
Both shares are monotone in the threshold: raising it calls fewer pixels no return, so "as depth" can only grow
and "dropped" only shrink.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..config import PhotonRegime, Sensor, TrainConfig
from ..nn.duf import apply_model_raw
from ..nn.model import Model
from .data import regime_batches, regime_draws

__all__ = [
    "NO_RETURN_AT",
    "CALIBRATION_PHOTONS",
    "CALIBRATION_SEED",
    "MIN_PHOTONS",
    "PHOTON_EDGES",
    "DEFAULT_THRESHOLDS",
    "TARGET_DROPPED",
    "no_return_set",
    "no_return_outputs",
    "no_return_table",
    "choose_no_return_logit",
    "calibrate_no_return",
]

NO_RETURN_AT = 0.99  # a normalised output at or above it reads as "no return" (the benchmark's reading)
# Photon levels (mean signal photons per LR pixel with a return) the calibration draws from, log-uniform: those of
# the goals (3 and above; the benchmark's no-return test measures 3, 14, 100 and 1000)
CALIBRATION_PHOTONS = (3.0, 1000.0)
MIN_PHOTONS = 3.0  # the rule counts the bands from this level up
# Bands of photon levels the shares are reported in (a level at 3 photons is worse than one at 9)
PHOTON_EDGES = (0.5, 1.0, 3.0, 5.0, 10.0, 30.0, 100.0, 300.0, 1000.0)
# The calibration draws' root key, jax.random.key(CALIBRATION_SEED): apart from the benchmark's (key(seed),
# key(seed + 1), key(10_000 + ...) for small seeds), the regime validation's (key(2**31 - 1)) and a training run's
# (`run_keys(seed)`), so that neither the benchmark nor model selection ever sees the calibration's clips.
CALIBRATION_SEED = 2**31 - 2
# Candidate thresholds: logits -8 .. 8 in steps of 0.25 (p = 0.0003 .. 0.9997)
DEFAULT_THRESHOLDS = tuple(float(t) for t in np.arange(-32, 33) / 4)
TARGET_DROPPED = 2.0  # % of true returns dropped, at most (the no-return goal, docs/results/photon-regimes.md)


def no_return_set(tr: int, *, draws: int, photon_range=CALIBRATION_PHOTONS, regime: PhotonRegime = PhotonRegime(),
                  snr_range=None, sensor: Sensor = Sensor(), inputs=("depth", "signal", "background"),
                  key=None, batch: int = 8, patch=None) -> dict:
    """A fixed calibration set: `draws` windows of 2tr+1 frames drawn by `regime_batches` from `regime` with the
    photon level log-uniform in `photon_range` (mean signal photons per LR pixel with a return), no-return
    regions on every clip (no_return_prob 1: a share of the HR pixels uniform in `regime.no_return_fraction`, on
    top of the scene's own sky), no clip of the paper's regime, and the SNR log-uniform in `snr_range` (default
    the regime's); every other effect as the regime draws it. Whole frames of `sensor.hr_shape` unless `patch`
    (LR rows, cols). Batch j of `batch` windows is drawn with fold_in(key, j), key default
    jax.random.key(CALIBRATION_SEED); each window's photon level and SNR come from `regime_draws` (one compilation
    for the whole range).

    Returns {"windows": (N, 2tr+1, h, w, C), "gt": (N, H, W) normalised depth (1.0 = no return), "photons": (N,),
    "snr": (N,)}, N = draws, as NumPy arrays.
    """
    for name, value in (("draws", draws), ("batch", batch)):
        if not (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
            raise ValueError(f"no_return_set: {name} must be an integer >= 1, got {value!r}")
    key = jax.random.key(CALIBRATION_SEED) if key is None else key
    regime = dataclasses.replace(regime, signal_range=tuple(float(p) for p in photon_range), no_return_prob=1.0,
                                 paper_prob=0.0, **({} if snr_range is None else {"snr_range": tuple(snr_range)}))
    train_cfg = dataclasses.replace(TrainConfig(), batch_size=min(batch, draws), patch=patch)
    make_batch = jax.jit(regime_batches(tr, train_cfg, regime, sensor=sensor, inputs=inputs))
    drawn_with = jax.jit(functools.partial(regime_draws, batch_size=train_cfg.batch_size, regime=regime))
    parts = {"windows": [], "gt": [], "photons": [], "snr": []}
    for j in range(-(-draws // train_cfg.batch_size)):
        k = jax.random.fold_in(key, j)
        w, g = make_batch(k)
        p = drawn_with(k)
        take = min(draws - j * train_cfg.batch_size, w.shape[0])
        for name, value in (("windows", w), ("gt", g), ("photons", p["mean_signal"]), ("snr", p["snr"])):
            parts[name].append(np.asarray(value[:take]))
    return {name: np.concatenate(v) for name, v in parts.items()}


@functools.partial(jax.jit, static_argnames=("cfg", "conv3d_impl", "precision"))
def _raw(params, state, windows, cfg, conv3d_impl, precision):
    return apply_model_raw(params, state, windows, cfg, conv3d_impl=conv3d_impl, precision=precision)


def no_return_outputs(model: Model, windows, *, batch: int = 8, conv3d_impl: str = "auto",
                      precision: str = "default") -> tuple[np.ndarray, np.ndarray]:
    """One forward pass of `model` (a DUF model with a no-return head, window form, BN in inference mode) over
    `windows` (N, 2tr+1, h, w, C), `batch` windows at a time. Returns (depth (N, H, W), logit (N, H, W)) as
    NumPy arrays: the upsampled depth and the no-return logit before any decision (`jaxsr.nn.apply_model_raw`)."""
    if not model.has_no_return_head:
        raise ValueError("no_return_outputs: the model has no no-return head (ModelConfig.no_return_head): there "
                         "is no decision to calibrate")
    if not (isinstance(batch, int) and not isinstance(batch, bool) and batch >= 1):
        raise ValueError(f"no_return_outputs: batch must be an integer >= 1, got {batch!r}")
    cfg = model.in_form("window").config  # windows of 2tr+1 frames, whatever form the model records
    windows = np.asarray(windows, np.float32)
    n = windows.shape[0]
    depth, logit = [], []
    for s in range(0, n, batch):
        chunk = windows[s:s + batch]
        if chunk.shape[0] < batch and n > batch:  # the last batch padded to the others' size: one compilation
            chunk = np.concatenate([chunk, np.repeat(chunk[-1:], batch - chunk.shape[0], axis=0)])
        out = np.asarray(_raw(model.params, model.state, jnp.asarray(chunk), cfg, conv3d_impl, precision))
        keep = min(batch, n - s)
        depth.append(out[:keep, ..., 0])
        logit.append(out[:keep, ..., 1])
    return np.concatenate(depth), np.concatenate(logit)


def _check_thresholds(thresholds) -> np.ndarray:
    t = np.asarray(thresholds, np.float64).ravel()
    if t.size == 0 or not np.all(np.isfinite(t)):
        raise ValueError(f"no_return_table: thresholds must be one or more finite logits, got {thresholds!r}")
    return np.unique(t)


def _shares(depth, logit, gt, thresholds, at):
    """(% no-return pixels output as depth, % true returns dropped), each (K,), for one group of pixels."""
    depth, logit, gt = (np.asarray(a, np.float64).ravel() for a in (depth, logit, gt))
    sky = gt >= 1.0
    reads_depth = depth < at  # False for NaN: the depth itself reads as no return
    # the decision flags a pixel where logit > t; a NaN logit flags none (as in merge_no_return)
    logit = np.where(np.isnan(logit), -np.inf, logit)

    def flagged(mask):  # (K,) number of pixels in mask whose logit is above each threshold
        s = np.sort(logit[mask])
        return s.size - np.searchsorted(s, thresholds, side="right")

    n_sky, n_ret = int(sky.sum()), int((~sky).sum())
    as_depth = (np.sum(sky & reads_depth) - flagged(sky & reads_depth)) / max(n_sky, 1)
    dropped = (np.sum(~sky & ~reads_depth) + flagged(~sky & reads_depth)) / max(n_ret, 1)
    nan = np.full(thresholds.shape, np.nan)
    return (100.0 * as_depth if n_sky else nan), (100.0 * dropped if n_ret else nan), n_sky, n_ret


def no_return_table(depth, logit, gt, photons, thresholds=DEFAULT_THRESHOLDS, *, edges=PHOTON_EDGES,
                    at: float = NO_RETURN_AT) -> dict:
    """The two shares for each candidate threshold in each band of photon levels.

    depth, logit, gt: (N, H, W) (`no_return_outputs` and the set's ground truth); photons: (N,) the photon level
    of each window, grouped into the bands [edges[i], edges[i+1]) (the last one closed); windows outside every
    band, and bands without a window, are left out. For a threshold t the output is 1.0 where logit > t, else the
    depth (`merge_no_return`); a pixel with no return (gt >= 1) counts as "as depth" where that output is below
    `at`, a true return as "dropped" where it is at or above `at` (or NaN).

    Returns {"thresholds": (K,) sorted, "bands": (L, 2) [lo, hi) photons, "windows": (L,), "as_depth": (L, K) %,
    "dropped": (L, K) % (NaN where a band has no pixel of the kind), "no_return_pixels": (L,), "return_pixels":
    (L,)}; along K "as depth" never falls and "dropped" never rises.
    """
    thresholds = _check_thresholds(thresholds)
    depth, logit, gt = np.asarray(depth), np.asarray(logit), np.asarray(gt)
    photons = np.asarray(photons, np.float64).ravel()
    if not (depth.shape == logit.shape == gt.shape and depth.ndim >= 1 and depth.shape[0] == photons.size):
        raise ValueError(f"no_return_table: depth, logit and gt must have one shape (N, ...) with N = len(photons), "
                         f"got {depth.shape}, {logit.shape}, {gt.shape} and {photons.size} levels")
    edges = np.asarray(edges, np.float64)
    if edges.ndim != 1 or edges.size < 2 or not np.all(np.diff(edges) > 0):
        raise ValueError(f"no_return_table: edges must be two or more increasing photon levels, got {edges!r}")
    level = photons * (1 + 1e-6)  # a float32 draw at an edge (3 photons as 2.9999998) in the band above it
    band = np.searchsorted(edges, level, side="right") - 1
    band[(band == edges.size - 1) & (photons <= edges[-1] * (1 + 1e-6))] = edges.size - 2  # the last band closed
    rows, bands, windows = [], [], []
    for b in range(edges.size - 1):
        pick = band == b
        if pick.any():
            rows.append(_shares(depth[pick], logit[pick], gt[pick], thresholds, at))
            bands.append((edges[b], edges[b + 1]))
            windows.append(int(pick.sum()))
    if not rows:
        raise ValueError(f"no_return_table: no window's photon level lies in the bands {list(edges)}")
    return {"thresholds": thresholds, "bands": np.array(bands), "windows": np.array(windows),
            "as_depth": np.stack([r[0] for r in rows]), "dropped": np.stack([r[1] for r in rows]),
            "no_return_pixels": np.array([r[2] for r in rows]), "return_pixels": np.array([r[3] for r in rows])}


def choose_no_return_logit(table: dict, *, target_dropped: float = TARGET_DROPPED,
                           min_photons: float = MIN_PHOTONS) -> dict:
    """The rule: over the bands of photon levels at or above `min_photons` (lower edge), each threshold's worst
    (largest) share "as depth" and worst share "dropped"; among the thresholds whose worst "dropped" is at most
    `target_dropped` (%), the one with the smallest worst "as depth" (ties: the smaller "dropped", then the smaller
    threshold). When no threshold keeps "dropped" within the target, the one with the smallest worst "dropped"
    (ties: the smaller "as depth"), and "met" is False.

    Returns {"no_return_logit", "as_depth", "dropped" (the worst bands' %, at it), "met", "target_dropped",
    "min_photons", "bands" (those counted, [lo, hi) photons)}."""
    if not (0.0 <= float(target_dropped) <= 100.0):
        raise ValueError(f"choose_no_return_logit: target_dropped must be a share in [0, 100] %, got "
                         f"{target_dropped!r}")
    bands = np.asarray(table["bands"])
    counted = bands[:, 0] >= min_photons
    if not counted.any():
        raise ValueError(f"choose_no_return_logit: no band of photon levels from {min_photons:g} up in the table "
                         f"(bands {bands.tolist()})")
    worst_as_depth = _worst(np.asarray(table["as_depth"])[counted])
    worst_dropped = _worst(np.asarray(table["dropped"])[counted])
    t = np.asarray(table["thresholds"])
    feasible = worst_dropped <= target_dropped
    if feasible.any():
        i = np.lexsort((t, worst_dropped, np.where(feasible, worst_as_depth, np.inf)))[0]
    else:
        i = np.lexsort((t, worst_as_depth, worst_dropped))[0]
    return {"no_return_logit": float(t[i]), "as_depth": float(worst_as_depth[i]), "dropped": float(worst_dropped[i]),
            "met": bool(feasible.any()), "target_dropped": float(target_dropped), "min_photons": float(min_photons),
            "bands": bands[counted].tolist()}


def _worst(shares):
    """The largest share over the rows (bands) of (L, K), NaN rows (no pixel of the kind) left out: (K,)."""
    shares = np.where(np.isnan(shares), -np.inf, shares).max(axis=0)
    return np.where(np.isinf(shares), np.nan, shares)


def calibrate_no_return(model: Model, validation: dict, thresholds=DEFAULT_THRESHOLDS, *,
                        target_dropped: float = TARGET_DROPPED, min_photons: float = MIN_PHOTONS,
                        edges=PHOTON_EDGES, at: float = NO_RETURN_AT, batch: int = 8, conv3d_impl: str = "auto",
                        precision: str = "default") -> dict:
    """Calibrate `model`'s no-return decision on `validation` ({"windows", "gt", "photons"}, as `no_return_set`
    gives it): one forward pass (`no_return_outputs`), the shares for each of `thresholds` in each band of photon
    levels (`no_return_table` with `edges`) and the rule's pick (`choose_no_return_logit`). Pure: the model is not
    changed; the caller saves a copy with `dataclasses.replace(model.config, no_return_logit=...)` of the choice.

    Returns {"table": no_return_table's dict, "choice": choose_no_return_logit's dict, "current": {"no_return_logit",
    "as_depth", "dropped"}: the worst levels' shares at the model's own threshold, for comparison}."""
    depth, logit = no_return_outputs(model, validation["windows"], batch=batch, conv3d_impl=conv3d_impl,
                                     precision=precision)
    gt, photons = np.asarray(validation["gt"]), np.asarray(validation["photons"])
    table = no_return_table(depth, logit, gt, photons, thresholds, edges=edges, at=at)
    choice = choose_no_return_logit(table, target_dropped=target_dropped, min_photons=min_photons)
    own = no_return_table(depth, logit, gt, photons, [model.config.no_return_logit], edges=edges, at=at)
    keep = own["bands"][:, 0] >= min_photons
    current = {"no_return_logit": model.config.no_return_logit,
               "as_depth": float(_worst(own["as_depth"][keep])[0]), "dropped": float(_worst(own["dropped"][keep])[0])}
    return {"table": table, "choice": choice, "current": current}
