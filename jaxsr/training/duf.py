"""The DUF network's training: its jitted train step (data simulated inside it), its validation, its recipe.

The data come from a source `make_batch(key) -> (windows, gt)` of `jaxsr.training.data` (default `scene_batches`),
run inside the jitted step; a sequence-form model (`ModelConfig(temporal="sequence")`) trains on clips instead,
`make_batch(key) -> (clips (B, L, h, w), gt (B, L, H, W))` (default `scene_clips`), with the loss on the L - 2R
frames whose inputs lie inside the clip and BN statistics over the clip. Data parallelism: a
`jax.sharding.Mesh` with a "data" axis splits the batch and replicates the parameters. `jaxsr.training.fit`
drives it through the recipe registered at the end.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from ..config import ModelConfig, Sensor, TrainConfig
from ..eval.metrics import huber_loss, psnr
from ..inference.frames import super_resolve
from ..io.checkpoint import config_to_dict, load_model
from ..nn.duf import (DUF, apply_model, apply_model_sequence_train, apply_model_train, grow_tr, init_model,
                      merge_no_return, sequence_radius, with_photon_inputs)
from ..sensor.peaks import NO_RETURN
from ..nn.model import Model
from .data import scene_batches, scene_clips, validation_set
from .optim import adam_init, adam_update, lr_schedule
from .recipes import Recipe, register_recipe

__all__ = [
    "data_mesh",
    "make_train_step",
    "model_loss",
    "no_return_cross_entropy",
    "sequence_loss",
    "evaluate",
    "evaluate_sequences",
    "default_data",
    "initial_weights",
]


def data_mesh(devices=None) -> Mesh:
    """A 1-D mesh with axis "data" over `devices` (default: all devices of all processes)."""
    devices = jax.devices() if devices is None else devices
    return Mesh(np.asarray(devices), ("data",))


def make_train_step(model_cfg: ModelConfig, train_cfg: TrainConfig, make_batch, *, mesh: Mesh | None = None,
                    conv3d_impl: str = "auto"):
    """The jitted train step: step(params, state, opt_state, key, step) -> (params, state, opt_state, metrics).

    Inside one jit: make_batch(key) -> network with BN in training mode (its convolutions at
    `train_cfg.precision`) -> Huber loss -> gradients -> Adam with lr = `lr_schedule(train_cfg)(step)`. The
    network runs in `model_cfg.temporal`'s form (see `sequence_loss` for the sequence form's batches). metrics: {"loss", "psnr" (mean over the batch, prediction
    clipped), "lr"}. With a `mesh`, the batch is sharded over its "data" axis and params/state/optimiser
    state are replicated (batch statistics and gradients are reduced over the mesh).
    conv3d_impl: how the network's convolutions run (see `apply_model`). `step.jitted(params, state, opt_state,
    key, lr)` is the jitted function underneath (for `.lower`), which takes the learning rate itself.
    make_batch None: the step is fed batches drawn ahead of it (`jaxsr.training.data.draw_batches`), its 4th
    argument the batch (inputs, gt) in place of the key; given the same batches, it computes what the step
    drawing them inside does.
    """
    # the compiled step does not read the seed, the length of the run, the stopping rule or the learning rate
    # (an argument, from the schedule): runs that differ only in those (other seeds, more epochs on resume,
    # another rate or decay) share one compiled step
    step_cfg = dataclasses.replace(train_cfg, seed=0, epochs=1, patience=1, lr=1.0, lr_decay=1.0, decay_epochs=1,
                                   examples_per_epoch=train_cfg.batch_size)
    compiled = _train_step(model_cfg, step_cfg, make_batch, mesh, conv3d_impl)
    schedule = lr_schedule(train_cfg)

    def step(params, state, opt_state, key, i):
        return compiled(params, state, opt_state, key, jnp.asarray(schedule(i), jnp.float32))

    step.jitted = compiled  # the compiled step itself, which takes the learning rate in place of the step index
    return step


@functools.lru_cache(maxsize=16)
def _train_step(model_cfg, train_cfg, make_batch, mesh, conv3d_impl):
    # cached: fitting again with the same configs and data source (e.g. a resume) does not recompile

    def constrain(tree, spec):
        if mesh is None:
            return tree
        return jax.lax.with_sharding_constraint(tree, NamedSharding(mesh, spec))

    def step_fn(params, state, opt_state, key, lr):
        # make_batch None: `key` is the batch itself, drawn ahead of the step
        windows, gt = constrain(key if make_batch is None else make_batch(key), P("data"))

        def loss_fn(p):
            if DUF.sequence_form(model_cfg):
                return sequence_loss(p, state, windows, gt, model_cfg, conv3d_impl=conv3d_impl, train_cfg=train_cfg)
            out, new_state = apply_model_train(p, state, windows, model_cfg, conv3d_impl=conv3d_impl,
                                               precision=train_cfg.precision)
            return model_loss(out, gt, model_cfg, train_cfg), (new_state, merge_no_return(out, model_cfg), gt)

        (loss, (new_state, hr, gt)), grads = jax.value_and_grad(loss_fn, has_aux=True)(params)
        params, opt_state = adam_update(
            grads, opt_state, params, lr=lr, b1=train_cfg.adam_b1, b2=train_cfg.adam_b2, eps=train_cfg.adam_eps
        )
        params, new_state, opt_state = constrain((params, new_state, opt_state), P())
        metrics = {"loss": loss, "psnr": jnp.mean(psnr(hr, gt)), "lr": lr}
        return params, new_state, opt_state, metrics

    donate = (0, 1, 2) if jax.default_backend() != "cpu" else ()
    return jax.jit(step_fn, donate_argnums=donate)


def model_loss(out, gt, cfg: ModelConfig, train_cfg: TrainConfig = TrainConfig()):
    """The training loss of the network's raw output `out` (`apply_model_train`'s) against gt (normalised, 1.0 =
    no return): the mean Huber loss (`train_cfg.huber_delta`) of the depth. With a no-return head the head
    alone answers for the pixels without a return: the depth's loss counts the returns only (a depth pulled
    towards 1.0 on sky learns to push far, faint surfaces there too), plus `train_cfg.no_return_weight` x the
    mean binary cross-entropy of the logits against gt >= 1.0. A scalar."""
    if not cfg.no_return_head:
        return huber_loss(out, gt, delta=train_cfg.huber_delta)
    depth, logit = out[..., 0], out[..., 1]
    no_return = gt >= NO_RETURN
    returns_only = jnp.where(no_return, gt, depth)  # no error, and no gradient, where there is no return
    return (huber_loss(returns_only, gt, delta=train_cfg.huber_delta)
            + train_cfg.no_return_weight * no_return_cross_entropy(logit, no_return))


def no_return_cross_entropy(logit, no_return):
    """The mean binary cross-entropy of no-return logits against the truth `no_return` (bool, same shape): the
    head's term of `model_loss`. log(1 + e^x) - y x, without overflow at large |x|."""
    return jnp.mean(jax.nn.softplus(logit) - no_return.astype(logit.dtype) * logit)


def sequence_loss(params, state, clips, gt, cfg: ModelConfig, *, delta: float = 0.01, conv3d_impl: str = "auto",
                  train_cfg: TrainConfig | None = None):
    """The sequence form's training loss: mean Huber loss over the frames of each clip whose inputs all lie
    inside it, BN with the statistics of the whole batch of clips (`apply_model_sequence_train`, "valid").

    clips: (B, L, h, w) LR normalised depth (or (B, L, h, w, C), as `cfg.inputs`), L >= 2R + 1 (R = 3 + tr);
    gt: `(B, L, h*r, w*r)` the ground truth of every frame. The loss is `model_loss` with `train_cfg` (default:
    `TrainConfig(huber_delta=delta)`). Returns (loss (scalar), (new BN state, hr `(B, L - 2R, h*r, w*r)`, gt of
    those frames)).
    """
    train_cfg = TrainConfig(huber_delta=delta) if train_cfg is None else train_cfg
    r = sequence_radius(cfg)
    if gt.ndim != 4 or gt.shape[:2] != clips.shape[:2]:
        raise ValueError(f"sequence_loss: expected gt (B, L, H, W) for clips {clips.shape}, got {gt.shape}")
    out, new_state = apply_model_sequence_train(params, state, clips, cfg, padding="valid", conv3d_impl=conv3d_impl,
                                                precision=train_cfg.precision)
    gt = gt[:, r : gt.shape[1] - r]
    return model_loss(out, gt, cfg, train_cfg), (new_state, merge_no_return(out, cfg), gt)


@functools.partial(jax.jit, static_argnames=("cfg", "delta", "conv3d_impl"))
def _eval_chunk(params, state, windows, gt, cfg, delta, conv3d_impl):
    hr = apply_model(params, state, windows, cfg, conv3d_impl=conv3d_impl)
    return huber_loss(hr, gt, delta=delta, axis=(-2, -1)), psnr(hr, gt)


def evaluate(params, state, windows, gt, cfg: ModelConfig, *, delta: float = 0.01, batch_size: int = 8,
             conv3d_impl: str = "auto") -> dict:
    """Validation with BN in inference mode: {"loss": mean Huber, "psnr": mean per-frame PSNR (dB)}.

    windows: (N, 2tr+1, h, w); gt: `(N, h*r, w*r)`. Runs in chunks of `batch_size` frames (the last padded);
    conv3d_impl: see `apply_model`. Returns the dict of two Python floats.
    """
    n = windows.shape[0]
    pad = (-n) % batch_size
    if pad:
        windows = jnp.concatenate([windows, jnp.repeat(windows[-1:], pad, 0)])
        gt = jnp.concatenate([gt, jnp.repeat(gt[-1:], pad, 0)])
    losses, psnrs = [], []
    for i in range(0, n + pad, batch_size):
        l, p = _eval_chunk(params, state, windows[i : i + batch_size], gt[i : i + batch_size], cfg, delta,
                           conv3d_impl)
        losses.append(l)
        psnrs.append(p)
    return {"loss": float(jnp.concatenate(losses)[:n].mean()), "psnr": float(jnp.concatenate(psnrs)[:n].mean())}


@jax.jit
def _frame_scores(hr, gt, delta):
    return huber_loss(hr, gt, delta=delta, axis=(-2, -1)), psnr(hr, gt)


def evaluate_sequences(params, state, lr, gt, cfg: ModelConfig, *, lengths=None, delta: float = 0.01,
                       conv3d_impl: str = "auto") -> dict:
    """Validation in the sequence form, BN in inference mode: {"loss": mean Huber, "psnr": mean per-frame PSNR}.

    lr: (N, h, w) LR normalised depth in [0, 1] (checked as by `super_resolve`) of one or more sequences end
    to end, `lengths` frames each (None: one sequence);
    gt: `(N, h*r, w*r)`. Each sequence is super-resolved whole, its ends edge-padded (`super_resolve` of the
    sequence-form model, in chunks). Returns the dict of two Python floats.
    """
    lengths = [lr.shape[0]] if lengths is None else list(lengths)
    if sum(lengths) != lr.shape[0] or gt.shape[0] != lr.shape[0]:
        raise ValueError(f"evaluate_sequences: lengths {lengths} must add up to the frames of lr {lr.shape} and "
                         f"gt {gt.shape}")
    model = Model(params, state, dataclasses.replace(cfg, temporal="sequence"))
    losses, psnrs, start = [], [], 0
    for n in lengths:
        hr = super_resolve(model, np.asarray(lr[start : start + n]), conv3d_impl=conv3d_impl)
        l, p = _frame_scores(jnp.asarray(hr), jnp.asarray(gt[start : start + n]), delta)
        losses.append(l)
        psnrs.append(p)
        start += n
    return {"loss": float(jnp.concatenate(losses).mean()), "psnr": float(jnp.concatenate(psnrs).mean())}


def initial_weights(k_init, model_cfg: ModelConfig, init) -> tuple[dict, dict]:
    """(params, state) to start from: drawn with `k_init`, or those of `init` (a `Model` or a checkpoint
    path), which must have `model_cfg`'s architecture (its temporal form may differ: fine-tuning a windowed
    model into the sequence form) or that of a smaller TR (a warm start: `grow_tr` to `model_cfg.tr`, the
    added blocks drawn with `k_init`); an `init` that reads fewer inputs (or has no no-return head) is widened
    to `model_cfg`'s inputs and head (`with_photon_inputs`). Its no-return decision threshold
    (`ModelConfig.no_return_logit`, not part of the architecture) may differ too: the run's is `model_cfg`'s."""
    if init is None:
        return init_model(k_init, model_cfg)
    model = init if isinstance(init, Model) else load_model(init)
    if model.architecture is not DUF:
        raise ValueError(f"fit: init holds a {model.kind} model; the DUF network starts from DUF weights")
    if set(model.channels) <= set(model_cfg.inputs) and (
            model.channels != model_cfg.inputs or model_cfg.no_return_head and not model.has_no_return_head):
        # the added inputs and the no-return head start from the trained model's function
        model = with_photon_inputs(k_init, model, model_cfg.inputs, no_return_head=model_cfg.no_return_head)
    if model.config.tr < model_cfg.tr:
        model = grow_tr(k_init, model, model_cfg.tr)
    if dataclasses.replace(model.config, temporal=model_cfg.temporal,
                           no_return_logit=model_cfg.no_return_logit) != model_cfg:
        differ = [k for k, v in config_to_dict(model_cfg).items()
                  if k not in ("temporal", "no_return_logit") and getattr(model.config, k) != v]
        raise ValueError("fit: the init model's architecture differs from the model to train: "
                         + ", ".join(f"{k} {getattr(model.config, k)!r} (training {getattr(model_cfg, k)!r})"
                                     for k in differ))
    return jax.tree_util.tree_map(jnp.asarray, (model.params, model.state))


def default_data(model_cfg: ModelConfig, train_cfg: TrainConfig, sensor: Sensor = Sensor()):
    """`fit`'s data source when none is given: rendered scenes, as windows of 2tr+1 frames (window form,
    `scene_batches`) or clips of `train_cfg.clip_length` frames (sequence form, `scene_clips`).
    Returns make_batch: key -> (inputs, gt) of that source."""
    if DUF.sequence_form(model_cfg):
        return scene_clips(train_cfg.clip_length(model_cfg), train_cfg, sensor=sensor, inputs=model_cfg.inputs)
    return scene_batches(model_cfg.tr, train_cfg, sensor=sensor, inputs=model_cfg.inputs)


def _init(key, cfg: ModelConfig, init=None) -> dict:
    params, state = initial_weights(key, cfg, init)
    return {"params": params, "state": state, "opt": adam_init(params)}


def _step(cfg: ModelConfig, train_cfg: TrainConfig, make_batch, *, sensor=None, mesh=None, conv3d_impl="auto",
          pretrain_steps=0):
    if pretrain_steps:
        raise ValueError("fit: pretrain_epochs is iSeeBetter's (a generator trained alone before its GAN)")
    step = make_train_step(cfg, train_cfg, make_batch, mesh=mesh, conv3d_impl=conv3d_impl)

    def run(ts, key, i):
        params, state, opt, metrics = step(ts["params"], ts["state"], ts["opt"], key, i)
        return {"params": params, "state": state, "opt": opt}, metrics
    return run


def _validation(key, cfg: ModelConfig, train_cfg: TrainConfig, sensor: Sensor) -> dict:
    return validation_set(key, cfg.tr, train_cfg, sensor=sensor, inputs=cfg.inputs)


def _evaluate(model: Model, validation: dict, train_cfg: TrainConfig, *, sensor=None, conv3d_impl="auto") -> dict:
    """`evaluate` (window form) or `evaluate_sequences` (sequence form) of the model."""
    cfg = model.config
    if model.sequence_form:
        return evaluate_sequences(model.params, model.state, validation["lr"], validation["gt"], cfg,
                                  lengths=validation.get("lengths"), delta=train_cfg.huber_delta,
                                  conv3d_impl=conv3d_impl)
    return evaluate(model.params, model.state, validation["windows"], validation["gt"], cfg,
                    delta=train_cfg.huber_delta, conv3d_impl=conv3d_impl)


register_recipe("duf", Recipe(init=_init, step=_step, data=lambda cfg, train_cfg, sensor: default_data(
    cfg, train_cfg, sensor), validation=_validation, evaluate=_evaluate, data_parallel=True))
