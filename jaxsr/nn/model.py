"""One model interface for every network: `Model` (params, state, config) and the registry of architectures.

A network is an `Architecture`: a name, its config type and two pure functions, init(key, cfg) -> (params, state)
and apply(params, state, inputs, cfg) -> HR normalised depth, plus what its inputs are ("depth": windows of
centre-of-mass depth, or "histograms": LR photon histograms with the HR intensity). The DUF network of the paper
registers itself as "duf" (`jaxsr.nn.duf`), the learned baselines as "histnet" and "iseebetter"
(`jaxsr.baselines`). A `Model` finds its architecture from the type of its config, so saving, loading,
super-resolving and training take any model the same way, and a new network joins by `register_architecture`.

The architecture answers every question the rest of the library asks of a network: what it reads
(`reads_histograms`, `channels`), whether it marks no return (`no_return_head`), which temporal forms it runs
(`forms`, `form`, `with_form`) and how its arithmetic may run (`precisions`). Nothing outside `jaxsr.nn` compares
an architecture's name or a config's fields.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import jax

__all__ = ["Architecture", "Model", "architecture", "architectures", "register_architecture"]

INPUT_KINDS = ("depth", "histograms")


@dataclasses.dataclass(frozen=True)
class Architecture:
    """A kind of network, as the registry holds it.

    name: how files and the CLI name it ("duf", "histnet", "iseebetter"). config_type: its frozen, hashable config
    dataclass (one type per architecture). init(key, cfg) -> (params, state): pytrees of arrays (state: e.g.
    batch-norm averages; {} when there is none). apply(params, state, inputs, cfg) -> (B, H, W) HR normalised
    depth, inference mode; inputs as `inputs` says: "depth" reads windows (B, frames, h, w) of LR normalised
    depth, "histograms" reads a pair (counts (B, h, w, K), HR intensity (B, H, W)); apply also takes the keyword
    conv3d_impl (how 3D convolutions run; networks without them accept and ignore it). frames(cfg): LR frames per
    output frame. scale(cfg): the upscaling factor. input_radius(cfg): output t reads frames t - R .. t + R.
    sequence_form(cfg): True when the network runs on whole sequences (the DUF sequence form) rather than on one
    window per output frame; this is the one place inference and training ask which. receptive_radius(cfg): LR
    pixels an output pixel reads around itself (None: unknown or the whole frame, so inference does not cut frames
    into tiles).
    describe(cfg, lr_shape) -> dict of extra facts for `jaxsr.io.model_info`.
    channels(cfg): what the network reads per LR pixel, depth first (`jaxsr.config.MODEL_INPUTS`; ("depth",) for
    a network of centre-of-mass depth alone). no_return_head(cfg): True when its output carries a per-pixel
    no-return logit beside the depth. forms: the temporal forms it can run in (`jaxsr.config.TEMPORAL_FORMS`; ()
    for a network with a single form of its own); form(cfg): the one `cfg` runs in (None without forms);
    with_form(cfg, form): `cfg` in another of its forms (the same parameters). precisions: the
    `jaxsr.config.PRECISIONS` its convolutions can take ("default" only for a network that takes none).
    feature_bytes(cfg, batch_size): bytes the network holds per LR pixel of a tile and output frame while it runs
    in inference, batch_size outputs at a time (None: unknown; memory estimates then count it as the DUF TR4).
    """

    name: str
    config_type: type
    init: Callable
    apply: Callable
    inputs: str = "depth"
    frames: Callable = lambda cfg: cfg.frames
    scale: Callable = lambda cfg: cfg.scale
    input_radius: Callable = lambda cfg: cfg.frames // 2
    sequence_form: Callable = lambda cfg: False
    receptive_radius: Callable = lambda cfg: None
    describe: Callable = lambda cfg, lr_shape: {}
    channels: Callable = lambda cfg: ("depth",)
    no_return_head: Callable = lambda cfg: False
    forms: tuple = ()
    form: Callable = lambda cfg: None
    with_form: Callable | None = None
    precisions: tuple = ("default",)
    feature_bytes: Callable | None = None

    def __post_init__(self):
        if self.inputs not in INPUT_KINDS:
            raise ValueError(f"Architecture {self.name!r}: inputs must be one of {INPUT_KINDS}, got {self.inputs!r}")
        if self.forms and self.with_form is None:
            raise ValueError(f"Architecture {self.name!r}: forms {self.forms} need with_form(cfg, form)")

    @property
    def reads_histograms(self) -> bool:
        """True when the network reads LR photon histograms with the HR intensity, not windows of LR frames."""
        return self.inputs == "histograms"

    def reads_photons(self, cfg) -> bool:
        """True when the network needs more than centre-of-mass depth: histograms, or photon channels."""
        return self.reads_histograms or tuple(self.channels(cfg)) != ("depth",)

    def template(self, cfg):
        """Shapes and dtypes of (params, state) for `cfg`, computing nothing."""
        return jax.eval_shape(lambda k: self.init(k, cfg), jax.random.key(0))


_REGISTRY: dict[str, Architecture] = {}


def register_architecture(arch: Architecture) -> Architecture:
    """Add `arch` to the registry (its name and config type must be new, or belong to the same entry).
    Returns `arch`."""
    for other in _REGISTRY.values():
        if other.name != arch.name and other.config_type is arch.config_type:
            raise ValueError(f"register_architecture: {arch.config_type.__name__} already belongs to {other.name!r}")
    _REGISTRY[arch.name] = arch
    return arch


def architectures() -> tuple[str, ...]:
    """The names of the registered architectures, e.g. ("duf", "histnet", "iseebetter")."""
    return tuple(_REGISTRY)


def architecture(which) -> Architecture:
    """The registered `Architecture` of `which`: its name, a config of its type, or a `Model`.
    Raises ValueError naming the registered ones for anything else."""
    if isinstance(which, Model):
        which = which.config
    if isinstance(which, str):
        if which in _REGISTRY:
            return _REGISTRY[which]
    else:
        for arch in _REGISTRY.values():
            if type(which) is arch.config_type:
                return arch
    raise ValueError(f"no registered architecture for {which!r}; registered: {', '.join(_REGISTRY)}")


@dataclasses.dataclass(frozen=True)
class Model:
    """A network with its weights: `params` and `state` (pytrees of arrays, the leaves) and its `config` (static,
    hashable). Any registered architecture: the config's type says which (`model.architecture`).

    equivalent_forms (static): the temporal forms these weights were measured to run in as accurately as in the
    form they were trained in (`jaxsr.inference.measure_form_equivalence`; `jaxsr.io.load_model` reads them from
    the card's "forms"); () when none was measured. `jaxsr.inference.in_form(model, "auto")` runs a windowed
    model in the sequence form only when "sequence" is among them."""

    params: dict
    state: dict
    config: object
    equivalent_forms: tuple = ()

    def __post_init__(self):  # a static field: hashable, whatever sequence it was given as
        object.__setattr__(self, "equivalent_forms", tuple(self.equivalent_forms))

    @property
    def architecture(self) -> Architecture:
        """The registered `Architecture` of this model's config."""
        return architecture(self.config)

    @property
    def kind(self) -> str:
        """The architecture's name: "duf", "histnet" or "iseebetter"."""
        return self.architecture.name

    @property
    def channels(self) -> tuple[str, ...]:
        """What the network reads per LR pixel, depth first (`Architecture.channels`)."""
        return tuple(self.architecture.channels(self.config))

    @property
    def reads_histograms(self) -> bool:
        """True when the network reads photon histograms with the HR intensity (`Architecture.reads_histograms`)."""
        return self.architecture.reads_histograms

    @property
    def reads_photons(self) -> bool:
        """True when depth frames alone cannot feed it: it reads histograms or photon channels."""
        return self.architecture.reads_photons(self.config)

    @property
    def has_no_return_head(self) -> bool:
        """True when the network marks no return itself (`Architecture.no_return_head`)."""
        return bool(self.architecture.no_return_head(self.config))

    @property
    def forms(self) -> tuple[str, ...]:
        """The temporal forms the network can run in (() for a network with a single form of its own)."""
        return tuple(self.architecture.forms)

    @property
    def form(self) -> str | None:
        """The temporal form the model runs in now ("window", "sequence"; None without forms)."""
        return self.architecture.form(self.config)

    @property
    def sequence_form(self) -> bool:
        """True when it runs on whole sequences rather than one window per output frame."""
        return bool(self.architecture.sequence_form(self.config))

    def in_form(self, form: str) -> "Model":
        """The same weights in temporal form `form` (one of `forms`); itself when it runs in it already. Raises
        ValueError for a form the architecture does not run."""
        if form not in self.forms:
            raise ValueError(f"form {form!r} applies to networks with temporal forms; a {self.kind} model runs in "
                             + (f"one of {self.forms}" if self.forms else "its own form only"))
        if self.form == form:
            return self
        return dataclasses.replace(self, config=self.architecture.with_form(self.config, form))

    def __call__(self, inputs):
        """Inference on one batch: (B, frames, h, w) LR windows, or (counts, intensity) for a histogram
        network -> `(B, h*r, w*r)` HR normalised depth (not clipped)."""
        return self.architecture.apply(self.params, self.state, inputs, self.config)


jax.tree_util.register_dataclass(Model, data_fields=["params", "state"], meta_fields=["config", "equivalent_forms"])
