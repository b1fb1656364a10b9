"""Scores: PSNR, SSIM, temporal coherence, and intervals for differences between methods on the same frames.

The experiments' tools are submodules, imported on first use (`from jaxsr.eval import scoring` or
`jaxsr.eval.scoring`), not with `jaxsr`: `scoring` (models scored on the fixed test clips; importing it exposes the
host's CPU cores as JAX devices), `reports` (result files: header, tables, figures), `score_cache` (per-frame
scores kept between scorings) and `runs` (training runs on disk).
"""

import importlib as _importlib

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

# imported on first use: `scoring` sets up JAX's devices on import, and these pull in training and inference
_SUBMODULES = ("scoring", "reports", "score_cache", "runs")


def __getattr__(name):
    if name in _SUBMODULES:
        return _importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
