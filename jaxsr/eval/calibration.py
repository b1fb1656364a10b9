"""How well a confidence is calibrated: expected calibration error, the area under the ROC curve and the coverage
of intervals. NumPy functions of arrays (scores of millions of pixels, on the host)."""

from __future__ import annotations

import numpy as np

__all__ = ["ECE_BINS", "reliability", "expected_calibration_error", "auroc", "interval_coverage"]

ECE_BINS = 15


def _pairs(probability, outcome, who: str):
    p = np.asarray(probability, np.float64).ravel()
    y = np.asarray(outcome).ravel().astype(np.float64)
    if p.shape != y.shape or p.size == 0:
        raise ValueError(f"{who}: expected probabilities and outcomes of one shape, not empty; got {p.size} and "
                         f"{y.size} values")
    if not np.all(np.isfinite(p)) or p.min() < 0 or p.max() > 1:
        raise ValueError(f"{who}: probabilities must be finite and in [0, 1]")
    return p, y


def reliability(probability, outcome, bins: int = ECE_BINS) -> dict:
    """The reliability diagram's bins (equal widths over [0, 1]): {"edges": (bins + 1,), "mean_probability",
    "frequency" (the outcomes' mean), "count": (bins,)}; NaN in an empty bin."""
    p, y = _pairs(probability, outcome, "reliability")
    edges = np.linspace(0.0, 1.0, bins + 1)
    idx = np.clip(np.searchsorted(edges, p, side="right") - 1, 0, bins - 1)
    count = np.bincount(idx, minlength=bins).astype(np.float64)
    with np.errstate(invalid="ignore"):
        mean_p = np.bincount(idx, weights=p, minlength=bins) / count
        freq = np.bincount(idx, weights=y, minlength=bins) / count
    return {"edges": edges, "mean_probability": mean_p, "frequency": freq, "count": count}


def expected_calibration_error(probability, outcome, bins: int = ECE_BINS) -> float:
    """sum over bins of (share of pixels) |mean probability - frequency of the outcome| (`reliability`'s bins)."""
    r = reliability(probability, outcome, bins)
    used = r["count"] > 0
    return float(np.sum(r["count"][used] * np.abs(r["mean_probability"][used] - r["frequency"][used]))
                 / r["count"].sum())


def auroc(score, outcome) -> float:
    """The area under the ROC curve of `score` for the outcome (the chance that a positive scores above a negative,
    ties counted half); NaN where either class is absent."""
    s = np.asarray(score, np.float64).ravel()
    y = np.asarray(outcome).ravel().astype(bool)
    if s.shape != y.shape or not np.all(np.isfinite(s)):
        raise ValueError("auroc: expected finite scores and outcomes of one shape")
    n_pos, n_neg = int(y.sum()), int((~y).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    order = np.argsort(s, kind="mergesort")
    ranks = np.empty(s.size, np.float64)
    sorted_s = s[order]
    # average ranks over ties
    starts = np.r_[0, np.flatnonzero(np.diff(sorted_s)) + 1]
    ends = np.r_[starts[1:], s.size]
    mean_rank = (starts + ends + 1) / 2.0
    ranks[order] = np.repeat(mean_rank, ends - starts)
    return float((ranks[y].sum() - n_pos * (n_pos + 1) / 2.0) / (n_pos * n_neg))


def interval_coverage(estimate, truth, std, z: float = 1.6448536) -> float:
    """The share of the finite pairs whose truth lies within estimate +- z std (z = 1.645: 90 % intervals)."""
    e, t, s = (np.asarray(a, np.float64).ravel() for a in (estimate, truth, std))
    keep = np.isfinite(e) & np.isfinite(t) & np.isfinite(s)
    if not keep.any():
        return float("nan")
    return float(np.mean(np.abs(e[keep] - t[keep]) <= z * s[keep]))
