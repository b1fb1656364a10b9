"""Scores: PSNR, SSIM, temporal coherence, and intervals for differences between methods on the same frames.
"""

from .metrics import (
    psnr,
    huber_loss,
    ssim,
    ssim_global,
    TemporalCoherence,
    temporal_coherence,
)
from .stats import (
    Interval,
    paired_interval,
    ratio_interval,
)

__all__ = [
    "psnr",
    "huber_loss",
    "ssim",
    "ssim_global",
    "TemporalCoherence",
    "temporal_coherence",
    "Interval",
    "paired_interval",
    "ratio_interval",
]
