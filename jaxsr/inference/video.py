"""Super-resolution of depth video, as one module: the names of `forms` (temporal form and precision), `frames`
(windowed and sequence-form super-resolution of LR frames), `photons` (photon histograms and the decisions on no
return) and `stream` (live input), for code that imports them from here.
"""

from __future__ import annotations

from .forms import DEFAULT_FORM, DEFAULT_PRECISION, FORM_TOLERANCE_DB, FORMS, check_precision, in_form
from .frames import (DEFAULT_ACCELERATOR_BATCH_SIZE, DEFAULT_BATCH_SIZE, DEFAULT_SEQUENCE_CHUNK, DEFAULT_TILE,
                     _batch_sharding, _check_frame, _infer_chunk, _require_model, default_batch_size,
                     iter_super_resolve, measure_form_equivalence, super_resolve, tile_spans)
from .photons import (check_keep_returns, iter_ambient_only, iter_centre_of_mass, iter_network_inputs,
                      iter_returns_kept, lr_blocks, no_return_where, overrule_no_return, super_resolve_histograms)
from .stream import Stream

_default_batch_size = default_batch_size  # the name recording.py imports
# What "auto" once read from the recording's length and the TR; no longer used by inference (the form is the
# model's: `in_form`, `Model.equivalent_forms`), kept only for jaxsr/cli/upscale.py's help text until it is rewritten.
SEQUENCE_FORM_TRS = (3, 4)
SEQUENCE_FORM_MIN_FRAMES = 32

__all__ = [
    "DEFAULT_ACCELERATOR_BATCH_SIZE", "DEFAULT_BATCH_SIZE", "DEFAULT_FORM", "DEFAULT_PRECISION",
    "DEFAULT_SEQUENCE_CHUNK", "DEFAULT_TILE", "FORMS", "FORM_TOLERANCE_DB", "SEQUENCE_FORM_MIN_FRAMES",
    "SEQUENCE_FORM_TRS", "Stream",
    "_batch_sharding", "_check_frame", "_default_batch_size", "_infer_chunk", "_require_model", "check_keep_returns",
    "check_precision", "default_batch_size", "in_form", "iter_ambient_only", "iter_centre_of_mass",
    "iter_network_inputs", "iter_returns_kept", "iter_super_resolve", "lr_blocks", "measure_form_equivalence",
    "no_return_where", "overrule_no_return", "super_resolve", "super_resolve_histograms", "tile_spans",
]
