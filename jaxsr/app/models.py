"""Which model `jaxsr upscale` runs (`ModelChoice`), resolved in two steps: `plan_model` before the recording is
read (a named model loaded and checked, the bundled files of "default" and "auto" looked up, so a missing or bad
model is said before a long pass over the input), and `finish_model` once the recording's kind and first frames are
known (the default of that kind, or the TR "auto" picks from the motion; then the no-return threshold, the form
and the precision). Nothing here asks a model's kind: the model answers (`jaxsr.nn.Model`).
"""

from __future__ import annotations

import os
from typing import Callable, NamedTuple

import numpy as np

from ..config import PhotonRegime
from ..inference import check_precision, choose_photon_model, choose_tr, in_form
from ..inference.adaptive import MODEL_TABLE, load_model_table
from ..io.checkpoint import load_model, read_metadata, resolve_model_path, stored_architecture
from ..nn.duf import with_no_return_logit
from ..nn.model import Model
from .specs import ModelChoice

__all__ = ["DEFAULT_MODELS", "DEPTH_ENSEMBLE", "DepthEnsemble", "BUNDLED_USES", "PlannedModel", "ChosenModel",
           "plan_model", "finish_model", "trained_snr_range", "heads", "bundled_models"]

# model="default": the bundled model that fits the input. Depth gives only the centre of mass, which the paper's
# TR4 reads; histograms and time tags also give the photons behind it, which tr4-ambient reads: ahead of TR4 in
# every simulated regime and by 2 dB on average on two real recordings (docs/results/photon-regimes.md, the default)
DEFAULT_MODELS = {"depth": "tr4", "histograms": "tr4-ambient"}


class DepthEnsemble(NamedTuple):
    """What model="default" adds for histograms and time tags at a high photon level: where the default model and
    `model` both output a return, the mean of their depths, when the recording shows `min_signal` signal photons
    per LR pixel and frame or more at a frame SNR of `min_snr` or more (`jaxsr.app.photon_levels`)."""

    model: str
    min_signal: float
    min_snr: float

    def applies(self, signal: float, snr: float) -> bool:
        """Whether a recording measuring `signal` photons at `snr` reaches both bounds (NaN, none measured: no)."""
        return bool(signal >= self.min_signal and snr >= self.min_snr)


# At 100 and 1000 photons and SNR 1.3 and 5 the two networks err in different places: the paper's TR4 places
# third-party indoor rooms better than tr4-ambient (by 0.1-2.0 dB on the held-out mean), tr4-ambient the test
# scenes (by 0.5-0.8 dB) and a real building's edges (at 51 photons 34.90 dB, the paper's TR4 alone 32.76). Their
# mean keeps most of each: +0.6 to +1.5 dB over tr4-ambient's depth held-out, +0.02 to +0.09 dB on the test scenes,
# -0.34 dB on the real building. At 14 photons, or 100 photons and SNR 0.1, the paper's TR4 reads the centre of mass
# of dim pixels' few photons, or of the ambient light, as depth and the mean loses 1.6-6.6 dB held-out (at 1000 and
# SNR 0.1 it is level); the bounds lie between those levels (docs/results/photon-regimes.md, "Whose depth the
# returns take")
DEPTH_ENSEMBLE = DepthEnsemble("paper-tr4", min_signal=50.0, min_snr=0.5)
AUTO_TRS = tuple(f"tr{k}" for k in range(5))  # what model="auto" picks among for depth frames
# and for histograms and time tags: every bundled model the model table scores (photon models included)
# The bundled models and when to use each (`jaxsr models`); the weights are in jaxsr/weights
BUNDLED_USES = {
    "tr0": "the paper's network from one frame: the fastest",
    "tr1": "the paper's network from 3 frames (--model auto picks a model by the measured motion and photons)",
    "tr2": "the paper's network from 5 frames",
    "tr3": "the paper's network from 7 frames",
    "tr4": "the paper's network from 9 frames",
    "tr4-ambient": "photon histograms and time tags, at a few photons and in ambient light too",
    "tr0-ambient": "as tr4-ambient from one frame: faster, for fast motion",
    "tr4-photons": "as tr4-ambient without the ambient channel (tr4-ambient serves better at a few photons)",
    "tr0-photons": "as tr4-photons from one frame",
    "histnet": "the HistNet baseline of the paper's comparison (with the HR intensity)",
    "iseebetter": "the iSeeBetter baseline of the paper's comparison",
}


class PlannedModel(NamedTuple):
    """`plan_model`'s result: the model when it is named (loaded and checked), else None ("default", "auto"),
    and its name as people read it."""

    model: Model | None
    name: str


def plan_model(choice: ModelChoice) -> PlannedModel:
    """The first step, before the recording is read: load a named model and check the choice's precision, form
    and no-return threshold on it; for "default" and "auto", check that their bundled files are there and that
    a threshold applies to at least one model they may pick."""
    if choice.is_default or choice.is_auto:
        name = "default" if choice.is_default else "auto"
        for path in picks(name) + ([DEPTH_ENSEMBLE.model] if choice.is_default else []):
            resolve_model_path(path)
        if choice.is_auto and choice.no_return_logit is not None:
            raise ValueError("no_return_logit (--no-return-logit) applies to models with a no-return head; --model "
                             "auto may pick one without (tr0..tr4): name one that has, such as tr4-ambient")
        if choice.no_return_logit is not None and not any(heads(name)):
            raise ValueError(f"no_return_logit (--no-return-logit) applies to models with a no-return head; --model "
                             f"{name} picks {' or '.join(picks(name))}, which have none: name one that has, such as "
                             "tr4-ambient")
        return PlannedModel(None, name)
    model = choice.model if isinstance(choice.model, Model) else load_model(choice.model)
    check_precision(model, choice.precision, "precision (--precision)")
    in_form(model, choice.form, "form (--form)")
    if choice.no_return_logit is not None:
        with_no_return_logit(model, choice.no_return_logit)  # raises for a model without the head
    return PlannedModel(model, "model" if isinstance(choice.model, Model) else str(choice.model))


class ChosenModel(NamedTuple):
    """`finish_model`'s result: the model; its name, which `--model` takes back (a bundled name or the path given;
    "model" for a `Model` given loaded); a sentence on how it was chosen and set; and the second network whose
    depth is averaged with the model's on the returns (`DEPTH_ENSEMBLE`), None where the model runs alone."""

    model: Model
    name: str
    description: str
    ensemble_model: Model | None = None


def finish_model(choice: ModelChoice, planned: PlannedModel, kind: str, lr_head: Callable[[], np.ndarray],
                 signal: float = float("nan"), snr: float = float("nan")) -> ChosenModel:
    """The second step, once the recording is open: the model for input of `kind` ("depth" or "histograms"), with
    `lr_head()` the recording's first LR frames where "auto" measures the motion, `signal` the signal photons per
    LR pixel and frame of histograms and `snr` their frame SNR (`jaxsr.app.photon_levels`); at the choice's no-return threshold, in its form,
    its precision checked. "auto" picks, for depth frames, the TR that `choose_tr` finds best at the motion; for
    histograms, the bundled model `choose_photon_model` finds best at the motion and signal. "default" for
    histograms at `DEPTH_ENSEMBLE`'s photon level or above also returns its network, whose depth is averaged with
    the model's on the returns, in the same form and precision."""
    model, name = planned
    if choice.is_default:
        name = DEFAULT_MODELS[kind]
        model = load_model(name)
    elif choice.is_auto and kind == "histograms":
        picked = choose_photon_model(lr_head(), signal, min_fps=choice.min_fps)
        model, name = load_model(picked.model), picked.model
    elif choice.is_auto:
        picked = choose_tr(lr_head(), min_fps=choice.min_fps)
        model, name = load_model(f"tr{picked.tr}"), f"tr{picked.tr}"
    description = f"{name} (auto: {picked.reason})" if choice.is_auto else name
    if choice.no_return_logit is not None:
        model = with_no_return_logit(model, choice.no_return_logit)
        description = f"{description} at no-return logit {float(choice.no_return_logit):g}"
    ensemble_model = None
    if choice.is_default and kind == "histograms" and DEPTH_ENSEMBLE.applies(signal, snr):
        ensemble_model = in_form(load_model(DEPTH_ENSEMBLE.model), choice.form, "form (--form)")
        check_precision(ensemble_model, choice.precision, "precision (--precision)")
    model = in_form(model, choice.form, "form (--form)")
    check_precision(model, choice.precision, "precision (--precision)")
    return ChosenModel(model, name, description, ensemble_model)


def picks(name: str, kind: str | None = None) -> list[str]:
    """The bundled models that "auto" or "default" may pick (for input of `kind`, where given)."""
    if name == "auto":
        return list(AUTO_TRS) if kind == "depth" else list(dict.fromkeys(AUTO_TRS + auto_photon_models()))
    return [DEFAULT_MODELS[kind]] if kind else sorted(set(DEFAULT_MODELS.values()))


def auto_photon_models() -> tuple[str, ...]:
    """The bundled models "auto" picks among for histograms and time tags: those the model table scores (none
    where the table is missing: `plan_model` then says so)."""
    return tuple(load_model_table()["psnr"]) if MODEL_TABLE.is_file() else ()


def heads(name: str, kind: str | None = None) -> list[bool]:
    """Whether each bundled model that "auto" or "default" may pick (for input of `kind`) has a no-return head,
    read from the files' metadata (nothing is loaded)."""
    return [read_metadata(resolve_model_path(p))["config"].get("no_return_head", False) for p in picks(name, kind)]


def has_head(choice: ModelChoice, planned: PlannedModel, kind: str | None = None) -> bool:
    """True when the model chosen (for input of `kind`) surely has a no-return head: a named model's own answer,
    or every model "auto" or "default" may pick."""
    if planned.model is not None:
        return planned.model.has_no_return_head
    return all(heads(planned.name, kind))


def trained_snr_range(choice: ModelChoice, kind: str) -> tuple[float, float]:
    """The frame SNRs the model chosen for input of `kind` was trained on: its card's regime where the model was
    named by a file or a bundled name whose card has a valid one (a model given loaded has no card here), else the
    wide photon regime's (`jaxsr.config.PhotonRegime`), the bundled models'."""
    default = tuple(PhotonRegime().snr_range)
    spec = DEFAULT_MODELS[kind] if choice.is_default else choice.model
    if not isinstance(spec, (str, os.PathLike)):
        return default
    card = read_metadata(resolve_model_path(spec)).get("card")
    regime = card.get("regime") if isinstance(card, dict) else None
    found = regime.get("snr_range") if isinstance(regime, dict) else None
    try:
        lo, hi = (float(x) for x in found)
    except (TypeError, ValueError):  # absent or malformed: a card is metadata, not a reason to fail
        return default
    return (lo, hi) if 0 < lo <= hi < float("inf") else default


def bundled_models() -> list[dict]:
    """The bundled models, one dict each: name, architecture, reads ("depth", or the photon channels, or
    "histograms"), tr (None for a baseline), marks_no_return, default_for (the input kinds it is the default of),
    use (`BUNDLED_USES`). Read from the files' metadata: nothing is loaded."""
    rows = []
    for name, use in BUNDLED_USES.items():
        path = resolve_model_path(name)
        meta = read_metadata(path)
        cfg, arch = meta.get("config", {}), stored_architecture(meta, path)
        reads = "histograms" if arch.reads_histograms else "+".join(cfg.get("inputs", ["depth"]))
        rows.append({"name": name, "architecture": arch.name, "reads": reads,
                     "tr": cfg.get("tr") if arch.forms else None,
                     "marks_no_return": bool(cfg.get("no_return_head", False)),
                     "default_for": [kind for kind, default in DEFAULT_MODELS.items() if default == name],
                     "use": use})
    return rows
