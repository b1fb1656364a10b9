"""How inference runs a network: the temporal form (`form`) and the convolutions' precision (`precision`).

The DUF network runs in two temporal forms with the same weights: the window form (the paper: one window of
2 tr + 1 frames per output frame) and the sequence form (each frame's features computed once over the whole
sequence; `jaxsr.nn.apply_model_sequence`). Weights trained in one form run in the other at an accuracy of their
own, so `form="auto"` moves a windowed model into the sequence form only where that accuracy was measured
(`measure_form_equivalence`) and recorded in its card (`Model.equivalent_forms`). The choice depends on the model
alone, never on the recording: a recording, any part of it and a stream of it run in the same form.
"""

from __future__ import annotations

from ..config import PRECISIONS
from ..nn.model import Model

# How inference runs the network's convolutions when the caller does not say (`precision`, `jaxsr.config.PRECISIONS`):
# the backend's own products, float32 on CPU (TF32 for float32 operands on NVIDIA GPUs since Ampere, unchanged).
# bfloat16 kept the bundled models' PSNR within 0.05 dB on the test sequences but ran no faster on XLA:CPU here,
# on a CPU with AVX512-BF16, since XLA:CPU converts the convolutions' bfloat16 operands back to float32
# (experiments/results/inference_forms.md); it is not the default on an accelerator either, where it was not
# measured.
DEFAULT_PRECISION = "default"
# The form `super_resolve` and `super_resolve_histograms` (whole arrays) run a model in when the caller does not say.
DEFAULT_FORM = "auto"
# The temporal forms inference can run a model in (`form`): "model" (as its config says), "window", "sequence" (any
# DUF weights run in either form), or "auto": the sequence form for windowed weights measured to keep their accuracy
# in it (`Model.equivalent_forms`), else the model's own form.
FORMS = ("auto", "model", "window", "sequence")
# How close, in dB of mean PSNR, the sequence form must keep windowed weights to their window form, over all the
# frames measured and over the first and last R frames alone (where the two forms pad the sequence differently),
# for the two forms to count as equivalent: the bundled TR3 and TR4 were within it on the test sequences
# (experiments/results/inference_forms.md: -0.04 and +0.02 dB), TR2 was not at the edges (-0.10), TR0 and TR1
# not at all (-0.4 to -0.6).
FORM_TOLERANCE_DB = 0.1


def check_precision(model: Model, precision, who: str = "super_resolve") -> str:
    """`precision` if it is one of `PRECISIONS` and `model`'s convolutions take it (`Architecture.precisions`: all
    of them for the DUF network, only "default" for a network that takes none, such as the baselines). Raises
    ValueError naming the choices."""
    if not isinstance(precision, str) or precision not in PRECISIONS:
        raise ValueError(f"{who}: precision must be one of {', '.join(map(repr, PRECISIONS))}, got {precision!r}")
    if precision not in model.architecture.precisions:
        raise ValueError(f"{who}: precision {precision!r} applies to the DUF network's convolutions; a "
                         f"{model.kind} model runs with precision 'default'")
    return precision


def in_form(model: Model, form: str = "auto", who: str = "super_resolve", *, frames: int | None = None) -> Model:
    """`model` in the temporal form `form` asks for (`FORMS`): "model" leaves it as it is; "window" and "sequence"
    run the same weights in that form (`Model.in_form`; refused for a network without temporal forms); "auto" runs
    windowed weights in the sequence form when the two forms were measured equivalent for them ("sequence" in
    `model.equivalent_forms`, from their card), and leaves any other model in its own form: a model whose config
    says "sequence" runs in it, weights without the measurement (a user's own) in the window form.
    frames: ignored (the form never depends on the recording's length); accepted for callers that still pass it.
    Returns a `Model` (the same one when nothing changes); raises ValueError for an unknown form."""
    del frames  # the same form for a recording, any part of it and a stream of it
    if not isinstance(form, str) or form not in FORMS:
        raise ValueError(f"{who}: form must be one of {', '.join(map(repr, FORMS))}, got {form!r}")
    if form in ("window", "sequence"):
        if form not in model.forms:
            raise ValueError(f"{who}: form {form!r} applies to the DUF network (window or sequence form); a "
                             f"{model.kind} model runs in its own form ('auto' or 'model')")
        return model.in_form(form)
    if form == "auto" and model.form == "window" and "sequence" in model.equivalent_forms:
        return model.in_form("sequence")
    return model
