"""Super-resolution of recordings (windows, sequences, streams), scene-adaptive TR and the whole pipeline as
one differentiable metric.
"""

from .video import (
    DEFAULT_BATCH_SIZE,
    DEFAULT_ACCELERATOR_BATCH_SIZE,
    DEFAULT_SEQUENCE_CHUNK,
    DEFAULT_TILE,
    tile_spans,
    iter_super_resolve,
    super_resolve,
    iter_centre_of_mass,
    iter_network_inputs,
    super_resolve_histograms,
    Stream,
)
from .adaptive import (
    STUDY_TABLE,
    SEARCH_RADIUS,
    LAGS,
    MIN_MOVING,
    BORDER,
    MotionEstimate,
    estimate_motion,
    TRChoice,
    load_study,
    choose_tr,
    resolve_model,
)
from .pipeline import (
    METRICS,
    pipeline_metric,
)
from .recording import (
    DEFAULT_MODELS,
    UpscaleJob,
    UpscaleResult,
    prepare_upscale,
    write_upscaled,
    upscale,
    upscale_memory,
)

__all__ = [
    "DEFAULT_BATCH_SIZE",
    "DEFAULT_ACCELERATOR_BATCH_SIZE",
    "DEFAULT_SEQUENCE_CHUNK",
    "DEFAULT_TILE",
    "tile_spans",
    "iter_super_resolve",
    "super_resolve",
    "iter_centre_of_mass",
    "iter_network_inputs",
    "super_resolve_histograms",
    "Stream",
    "STUDY_TABLE",
    "SEARCH_RADIUS",
    "LAGS",
    "MIN_MOVING",
    "BORDER",
    "MotionEstimate",
    "estimate_motion",
    "TRChoice",
    "load_study",
    "choose_tr",
    "resolve_model",
    "METRICS",
    "pipeline_metric",
    "UpscaleJob",
    "UpscaleResult",
    "DEFAULT_MODELS",
    "prepare_upscale",
    "write_upscaled",
    "upscale",
    "upscale_memory",
]
