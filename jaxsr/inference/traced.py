"""Super-resolution as one traced function of arrays, for a user's own `jax.jit`, `jax.vmap` and `jax.grad`.

`super_resolve` and its kin run on the host: they check every frame, stream batches through a compiled network
in bounded memory and return NumPy. `apply_sequence` and `apply_histograms` are the same network over a whole
sequence as a pure JAX function: the result is a (traced) array, differentiable with respect to the input and the
model's weights, and nothing is checked that needs concrete values. The whole sequence and the network's
features are held at once, so they suit sequences that fit the device, as in training or a differentiable
pipeline.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..config import Sensor
from ..nn.duf import apply_model_sequence
from ..nn.inputs import network_inputs
from ..nn.model import Model
from ..temporal import windows
from .forms import DEFAULT_FORM, DEFAULT_PRECISION, check_precision, in_form
from .units import check_units, lr_to_network, network_to_units

__all__ = ["apply_sequence", "apply_histograms", "network_over_sequence", "refuse_tracing"]


def refuse_tracing(x, who: str, instead: str) -> None:
    """Raise a TypeError naming the traced route when `x` (an array or a pytree of them) is traced: `who` runs on
    the host and would fail with JAX's TracerArrayConversionError."""
    if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x)):
        raise TypeError(f"{who} runs on the host (it checks frames and streams batches through a compiled network) "
                        f"and cannot run inside jax.jit, jax.vmap or jax.grad; there, use {instead}, a traced "
                        "function of arrays")


def _model(model, who: str, form: str, precision: str) -> Model:
    if not isinstance(model, Model):
        raise TypeError(f"{who}: expected a jaxsr.Model (e.g. jaxsr.load_model('tr4')), got {type(model).__name__}")
    check_precision(model, precision, who)
    return in_form(model, form, who)


def apply_sequence(model: Model, lr_seq, *, units: str = "normalised", sensor: Sensor | None = None,
                   form: str = DEFAULT_FORM, conv3d_impl: str = "auto", precision: str = DEFAULT_PRECISION):
    """The network over a whole LR sequence: (T, h, w) LR normalised depth (1.0 or NaN = no return; (T, h, w, C)
    channels for a model reading photons too, `jaxsr.nn.network_inputs`) -> (T, h r, w r) HR normalised depth, a
    JAX array, not clipped. jit-, vmap- (over leading sequences) and grad-compatible; equal to `super_resolve` on
    the same sequence to float32 rounding. Each frame reads its temporal neighbours, the ends edge-replicated, in
    the form `form` picks (`jaxsr.inference.in_form`: "auto" as `super_resolve` runs it). NaN input reads as no
    return; values outside [0, 1] are clipped (a host-side function would refuse them). units: "normalised"
    (default) or "m": radial metres in and out on `sensor`'s depth scale, as `super_resolve` takes them (the
    gradient flows through the conversion). conv3d_impl, precision: as for `jaxsr.nn.apply_model`."""
    model = _model(model, "apply_sequence", form, precision)
    sensor = check_units("apply_sequence", units, sensor, depth_input=True)
    if model.reads_histograms:
        raise ValueError(f"apply_sequence: a {model.kind} model reads photon histograms; use apply_histograms")
    lr = jnp.asarray(lr_seq, jnp.float32)
    channels = len(model.channels)
    if lr.ndim != (3 if channels == 1 else 4) or (channels > 1 and lr.shape[-1] != channels):
        want = "(T, h, w)" if channels == 1 else f"(T, h, w, {channels})"
        raise ValueError(f"apply_sequence: expected an LR sequence {want} for a model reading {model.channels}, got "
                         f"shape {lr.shape}")
    lr = lr_to_network(lr, units, sensor, channels=channels > 1)
    depth = lr[..., 0] if channels > 1 else lr
    depth = jnp.clip(jnp.where(jnp.isnan(depth), 1.0, depth), 0.0, 1.0)
    hr = network_over_sequence(model, depth if channels == 1 else lr.at[..., 0].set(depth),
                               conv3d_impl=conv3d_impl, precision=precision)
    return network_to_units(hr, units, sensor)


def network_over_sequence(model: Model, lr, *, conv3d_impl: str = "auto", precision: str = DEFAULT_PRECISION):
    """`apply_sequence`'s network on input taken as it is (no NaN or range handling, so that a gradient through it
    is the network's alone), in the model's own form: (T, h, w[, C]) -> (T, h r, w r)."""
    conv = {"conv3d_impl": conv3d_impl} | ({} if precision == "default" else {"precision": precision})
    cfg, arch = model.config, model.architecture
    if model.sequence_form:
        return apply_model_sequence(model.params, model.state, lr[None], cfg, **conv)[0]
    return arch.apply(model.params, model.state, windows(lr, arch.input_radius(cfg)), cfg, **conv)


def apply_histograms(model: Model, counts, sensor: Sensor = Sensor(), *, units: str = "normalised", intensity=None,
                     form: str = DEFAULT_FORM, conv3d_impl: str = "auto", precision: str = DEFAULT_PRECISION):
    """The network over a whole sequence of photon histograms: (T, h, w, K) counts (finite, >= 0; K =
    `sensor.bins` over its gate) -> (T, h r, w r) HR depth in `units` ("normalised" on the sensor's depth scale, or
    "m": radial metres, inf = no return), a JAX array; jit-, vmap- and grad-compatible (the gradient flows
    through the centre of mass and the photon channels to the counts). A model reading depth (and photon channels) gets
    `jaxsr.nn.network_inputs(counts, sensor, model.channels)` (`apply_sequence`); one reading histograms (HistNet)
    gets the counts with `intensity` (T, h r, w r), which it needs. Equal to `super_resolve_histograms` without its
    no-return tests (`ambient_alpha`, `keep_returns`) to float32 rounding."""
    model = _model(model, "apply_histograms", form, precision)
    sensor = check_units("apply_histograms", units, sensor, depth_input=False)
    counts = jnp.asarray(counts, jnp.float32)
    if counts.ndim != 4:
        raise ValueError(f"apply_histograms: expected counts (T, h, w, K), got shape {counts.shape}")
    if model.reads_histograms:
        if intensity is None:
            raise ValueError(f"apply_histograms: a {model.kind} model reads the HR intensity (T, h r, w r) too: give "
                             "intensity")
        hr = model.architecture.apply(model.params, model.state, (counts, jnp.asarray(intensity, jnp.float32)),
                                      model.config, conv3d_impl=conv3d_impl)
        return network_to_units(hr, units, sensor)
    if counts.shape[-1] != sensor.bins:
        raise ValueError(f"apply_histograms: counts have {counts.shape[-1]} bins, the sensor's gate {sensor.bins}")
    lr = network_inputs(counts, sensor, model.channels)
    hr = apply_sequence(model, lr, form="model", conv3d_impl=conv3d_impl, precision=precision)
    return network_to_units(hr, units, sensor)
