"""The engine: super-resolution of frame sequences (windows, sequences, streams, photon streams), scene-adaptive TR
and the whole pipeline as one differentiable metric. Reading and writing recordings is the application's
(`jaxsr.app`).
"""

from .forms import (
    DEFAULT_PRECISION,
    DEFAULT_FORM,
    FORMS,
    FORM_TOLERANCE_DB,
    check_precision,
    in_form,
)
from .frames import (
    DEFAULT_BATCH_SIZE,
    DEFAULT_ACCELERATOR_BATCH_SIZE,
    DEFAULT_SEQUENCE_CHUNK,
    DEFAULT_TILE,
    default_batch_size,
    tile_spans,
    iter_super_resolve,
    super_resolve,
    measure_form_equivalence,
)
from .photons import (
    check_keep_returns,
    iter_returns_kept,
    iter_centre_of_mass,
    iter_network_inputs,
    iter_ambient_only,
    no_return_where,
    overrule_no_return,
    lr_blocks,
    super_resolve_histograms,
)
from .stream import Stream
from .traced import apply_sequence, apply_histograms
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
    ModelPick,
    load_model_table,
    choose_photon_model,
    resolve_model,
)
from .pipeline import (
    METRICS,
    pipeline_metric,
)

__all__ = [
    "apply_sequence",
    "apply_histograms",
    "DEFAULT_BATCH_SIZE",
    "DEFAULT_ACCELERATOR_BATCH_SIZE",
    "DEFAULT_SEQUENCE_CHUNK",
    "DEFAULT_TILE",
    "DEFAULT_PRECISION",
    "DEFAULT_FORM",
    "FORMS",
    "FORM_TOLERANCE_DB",
    "check_precision",
    "in_form",
    "measure_form_equivalence",
    "default_batch_size",
    "check_keep_returns",
    "iter_returns_kept",
    "tile_spans",
    "iter_super_resolve",
    "super_resolve",
    "iter_centre_of_mass",
    "iter_network_inputs",
    "iter_ambient_only",
    "no_return_where",
    "overrule_no_return",
    "lr_blocks",
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
    "ModelPick",
    "load_model_table",
    "choose_photon_model",
    "resolve_model",
    "METRICS",
    "pipeline_metric",
]
