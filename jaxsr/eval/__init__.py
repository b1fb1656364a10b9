"""Scores: PSNR, SSIM, temporal coherence, and intervals for differences between methods on the same frames.

Pure functions of arrays: this stage imports no other stage of the pipeline. The experiments' harness that scores
models on the test clips and writes result files is in the repository's experiments/harness, not in the package.
"""

from .metrics import (
    psnr,
    huber_loss,
    ssim,
    ssim_global,
    TemporalCoherence,
    temporal_coherence,
)
from .calibration import (
    ECE_BINS,
    reliability,
    expected_calibration_error,
    auroc,
    interval_coverage,
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
    "ECE_BINS",
    "reliability",
    "expected_calibration_error",
    "auroc",
    "interval_coverage",
]
