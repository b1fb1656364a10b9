"""One model interface for every network: `Model` (params, state, config) and the registry of architectures.

A network is an `Architecture`: a name, its config type and two pure functions, init(key, cfg) -> (params, state)
and apply(params, state, inputs, cfg) -> HR normalised depth, plus what its inputs are ("depth": windows of
centre-of-mass depth, or "histograms": LR photon histograms with the HR intensity). The DUF network of the paper
registers itself as "duf" (`jaxsr.nn.duf`), the learned baselines as "histnet" and "iseebetter"
(`jaxsr.baselines`). A `Model` finds its architecture from the type of its config, so saving, loading,
super-resolving and training take any model the same way, and a new network joins by `register_architecture`.
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

    def __post_init__(self):
        if self.inputs not in INPUT_KINDS:
            raise ValueError(f"Architecture {self.name!r}: inputs must be one of {INPUT_KINDS}, got {self.inputs!r}")

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
    hashable). Any registered architecture: the config's type says which (`model.architecture`)."""

    params: dict
    state: dict
    config: object

    @property
    def architecture(self) -> Architecture:
        """The registered `Architecture` of this model's config."""
        return architecture(self.config)

    @property
    def kind(self) -> str:
        """The architecture's name: "duf", "histnet" or "iseebetter"."""
        return self.architecture.name

    def __call__(self, inputs):
        """Inference on one batch: (B, frames, h, w) LR windows, or (counts, intensity) for a histogram
        network -> `(B, h*r, w*r)` HR normalised depth (not clipped)."""
        return self.architecture.apply(self.params, self.state, inputs, self.config)


jax.tree_util.register_dataclass(Model, data_fields=["params", "state"], meta_fields=["config"])
