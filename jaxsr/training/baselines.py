"""How the learned baselines (HistNet, iSeeBetter) train: their jitted steps, the data source HistNet needs and
their recipes for `jaxsr.training.fit`.

- iSeeBetter takes LR depth windows like our network: `jaxsr.training.data.scene_batches(tr=cfg.frames // 2, train_cfg)`
  (or `sequence_batches`) feeds `make_iseebetter_train_step` as it is.
- HistNet takes the LR photon histograms and the HR intensity of one frame: `histogram_batches` renders
  `jaxsr.scenes.training_clip` scenes (one frame), simulates histograms with the same SNR / mean-signal ranges and
  crops as `scene_batches`, and returns (counts, HR intensity, HR normalised depth).

Each step is one jitted function: data simulated inside it, forward, loss, gradients, `jaxsr.training.optim.adam_update`
with lr = schedule(step) (iSeeBetter / RBPN: Adam lr 1e-4, /10 at half the epochs; HistNet's code: Adam or
proximal Adagrad, L1 loss).
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ..baselines.histnet import HistNetConfig, apply_histnet, init_histnet
from ..baselines.rbpn import (
    RBPNConfig,
    apply_discriminator,
    apply_rbpn,
    discriminator_loss,
    generator_loss,
    init_discriminator,
    init_rbpn,
)
from ..config import Sensor, TrainConfig
from ..eval.metrics import psnr
from ..inference.frames import super_resolve
from ..inference.photons import super_resolve_histograms
from ..io.checkpoint import load_model, resolve_model_path, save_model
from ..nn.model import Model, architecture
from ..scenes import test_sequences, training_clip
from ..sensor.forward import normalise_depth, simulate_histograms
from .data import log_uniform, scene_batches, validation_set
from .optim import adam_init, adam_update, lr_schedule
from .recipes import Recipe, recipe, register_recipe

__all__ = [
    "BASELINES",
    "baseline_validation_set",
    "evaluate_baseline",
    "histogram_batches",
    "init_adam_pair",
    "make_histnet_train_step",
    "make_iseebetter_train_step",
    "make_rbpn_train_step",
    # deprecated: the one model interface and loop do their work
    "BaselineModel",
    "fit_baseline",
    "load_baseline",
    "save_baseline",
    "super_resolve_baseline",
]

_SENSOR = Sensor()  # the default sensor


def _crop(key, counts, intensity, gt, patch, scale):
    """The same random LR crop of counts (h, w, K) and of the HR intensity and depth (h r, w r)."""
    if patch is None:
        return counts, intensity, gt
    ph, pw = patch
    h, w, k = counts.shape
    if ph > h or pw > w or ph % 4 or pw % 4:
        raise ValueError(f"histogram_batches: patch {patch} must fit the LR frame {(h, w)} and be divisible by 4")
    ky, kx = jax.random.split(key)
    y0 = jax.random.randint(ky, (), 0, h - ph + 1)
    x0 = jax.random.randint(kx, (), 0, w - pw + 1)
    counts = jax.lax.dynamic_slice(counts, (y0, x0, 0), (ph, pw, k))
    hr = lambda a: jax.lax.dynamic_slice(a, (y0 * scale, x0 * scale), (ph * scale, pw * scale))
    return counts, hr(intensity), hr(gt)


def histogram_batches(train_cfg: TrainConfig, *, sensor: Sensor = _SENSOR):
    """HistNet's data source: `make_batch(key)` with `batch_size` random single-frame scenes.

    Per example: `jaxsr.scenes.training_clip` (1 frame) -> SNR and mean signal log-uniform in the config's ranges
    -> `simulate_histograms`; an optional random crop (`patch`, LR pixels, divisible by 4). Returns make_batch:
    key -> (counts (B, h, w, K), intensity (B, h r, w r) rendered HR intensity in [0, 1], gt (B, h r, w r) HR
    normalised depth).
    """
    def example(key):
        k_scene, k_snr, k_sig, k_noise, k_crop = jax.random.split(key, 5)
        depth, intensity = training_clip(k_scene, 1, sensor=sensor, shift_range=train_cfg.motion_range)
        snr = log_uniform(k_snr, *train_cfg.snr_range)
        mean_signal = log_uniform(k_sig, *train_cfg.mean_signal_range)
        counts = simulate_histograms(k_noise, depth, intensity, sensor, snr=snr, mean_signal=mean_signal)
        return _crop(k_crop, counts[0], intensity[0], normalise_depth(depth, sensor)[0], train_cfg.patch, sensor.scale)

    def make_batch(key):
        return jax.vmap(example)(jax.random.split(key, train_cfg.batch_size))

    make_batch.description = "jaxsr.scenes.training_clip (1 frame) -> simulate_histograms; rendered HR intensity"
    return make_batch


def make_histnet_train_step(cfg: HistNetConfig, make_batch, *, schedule, sensor: Sensor = _SENSOR):
    """The jitted HistNet train step: step(params, opt_state, key, step) -> (params, opt_state, metrics).

    make_batch: key -> (counts (B, h, w, K), intensity (B, H, W), gt (B, H, W)), e.g. `histogram_batches`;
    schedule: step -> lr (e.g. `jaxsr.training.step_decay(1e-4, factor=0.1, every=...)`). Loss: mean |hr - gt| (the
    published code's L1). Returns the step; metrics {"loss", "psnr" (prediction clipped to [0, 1]), "lr"}.
    """
    def step_fn(params, opt_state, key, step):
        counts, intensity, gt = make_batch(key)

        def loss_fn(p):
            hr = apply_histnet(p, counts, intensity, cfg, sensor=sensor)
            return jnp.mean(jnp.abs(hr - gt)), hr

        (loss, hr), grads = jax.value_and_grad(loss_fn, has_aux=True)(params)
        lr = schedule(step)
        params, opt_state = adam_update(grads, opt_state, params, lr=lr, eps=1e-8)
        return params, opt_state, {"loss": loss, "psnr": jnp.mean(psnr(jnp.clip(hr, 0, 1), gt)), "lr": lr}

    return jax.jit(step_fn, donate_argnums=(0, 1))


def init_adam_pair(g_params, d_params):
    """Adam states of the generator and the discriminator, for `make_iseebetter_train_step`.

    g_params, d_params: pytrees of arrays of any shape. Returns (AdamState of g_params, AdamState of d_params).
    """
    return adam_init(g_params), adam_init(d_params)


def make_iseebetter_train_step(cfg: RBPNConfig, make_batch, *, schedule, adversarial: float = 1e-3,
                               tv: float = 2e-8, charbonnier: bool = False):
    """The jitted iSeeBetter train step (one discriminator update, then one generator update, as iSeeBetter).

    step((g_params, d_params, d_state), (g_opt, d_opt), key, step) -> (same, same, metrics).
    make_batch: key -> (windows (B, frames, h, w), gt (B, h r, w r)), e.g.
    `jaxsr.training.data.scene_batches(cfg.frames // 2, train_cfg)`; the flows are computed once per batch
    (`rbpn_flows`). schedule: step -> lr for both.
    Losses: `discriminator_loss`, `generator_loss` (MSE + adversarial + tv; no VGG term). Returns the step;
    metrics {"d_loss", "g_loss", "content", "adversarial", "psnr", "lr"}.
    """
    def step_fn(nets, opts, key, step):
        g_params, d_params, d_state = nets
        g_opt, d_opt = opts
        windows, gt = make_batch(key)
        lr = schedule(step)
        # one generator forward pass serves both updates; its pullback gives the generator's gradient
        hr, pullback = jax.vjp(lambda gp: apply_rbpn(gp, windows, cfg), g_params)

        def d_loss_fn(dp):
            real, st = apply_discriminator(dp, d_state, gt, cfg, train=True)
            fake, st = apply_discriminator(dp, st, hr, cfg, train=True)
            return discriminator_loss(real, fake), st

        (d_loss, d_state), d_grads = jax.value_and_grad(d_loss_fn, has_aux=True)(d_params)
        d_params, d_opt = adam_update(d_grads, d_opt, d_params, lr=lr, eps=1e-8)

        def g_loss_fn(out):  # against the updated discriminator, as iSeeBetter's trainer
            fake, _ = apply_discriminator(d_params, d_state, out, cfg, train=True)
            loss, parts = generator_loss(out, gt, fake, adversarial=adversarial, tv=tv, charbonnier=charbonnier)
            return loss, parts

        (g_loss, parts), d_hr = jax.value_and_grad(g_loss_fn, has_aux=True)(hr)
        (g_grads,) = pullback(d_hr)
        g_params, g_opt = adam_update(g_grads, g_opt, g_params, lr=lr, eps=1e-8)
        out = hr
        metrics = {"d_loss": d_loss, "g_loss": g_loss, "content": parts["content"],
                   "adversarial": parts["adversarial"], "psnr": jnp.mean(psnr(jnp.clip(out, 0, 1), gt)), "lr": lr}
        return (g_params, d_params, d_state), (g_opt, d_opt), metrics

    return jax.jit(step_fn, donate_argnums=(0, 1))


def make_rbpn_train_step(cfg: RBPNConfig, make_batch, *, schedule):
    """The jitted generator-only step of iSeeBetter's pre-training (RBPN trained on its content loss, MSE; the
    iSeeBetter authors start the GAN from such a generator): step(g_params, g_opt, key, step) -> (g_params, g_opt,
    metrics {"g_loss", "content", "psnr", "lr"}). make_batch and schedule as `make_iseebetter_train_step`.
    """
    def step_fn(g_params, g_opt, key, step):
        windows, gt = make_batch(key)

        def loss_fn(gp):
            hr = apply_rbpn(gp, windows, cfg)
            return jnp.mean((hr - gt) ** 2), hr

        (content, hr), grads = jax.value_and_grad(loss_fn, has_aux=True)(g_params)
        lr = schedule(step)
        g_params, g_opt = adam_update(grads, g_opt, g_params, lr=lr, eps=1e-8)
        return g_params, g_opt, {"g_loss": content, "content": content,
                                 "psnr": jnp.mean(psnr(jnp.clip(hr, 0, 1), gt)), "lr": lr}

    return jax.jit(step_fn, donate_argnums=(0, 1))


# --- trained baselines: files, inference, validation, the resumable fit loop ------------------------------------

BASELINES = ("histnet", "iseebetter")  # the names the deprecated functions of jaxsr 0.1 take


def _check_kind(kind: str, who: str) -> None:
    if kind not in BASELINES:
        raise ValueError(f"{who}: unknown baseline {kind!r}; expected one of {', '.join(BASELINES)}")


def baseline_validation_set(key, kind: str, cfg, train_cfg: TrainConfig, *, sensor: Sensor = _SENSOR) -> dict:
    """The validation frames of `jaxsr.training.data.validation_set` (the first `val_frames` of each validation
    sequence at its own SNR, `val_mean_signal`, the same noise for the same key) with what each baseline reads:
    "counts" (N, h, w, K) and "intensity" (N, H, W) for HistNet, "windows" (N, frames, h, w) for iSeeBetter; plus
    "gt" (N, H, W), "lr" (N, h, w), "names", "lengths". ValueError for a `cfg` of another kind."""
    _check_kind(kind, "baseline_validation_set")
    if architecture(cfg) is not architecture(kind):
        raise ValueError(f"baseline_validation_set: a {type(cfg).__name__} is not a {kind} config")
    return _validation(key, cfg, train_cfg, sensor)


def _validation(key, cfg, train_cfg: TrainConfig, sensor: Sensor) -> dict:
    """`baseline_validation_set` for the baseline of `cfg`, as its recipe's validation: what it reads, as its
    architecture says (windows of its input radius, or histograms with the HR intensity)."""
    arch = architecture(cfg)
    seqs = test_sequences(n_frames=train_cfg.val_frames, names=train_cfg.val_sequences or None, sensor=sensor)
    out = validation_set(key, arch.input_radius(cfg), train_cfg, sensor=sensor, sequences=seqs)
    if arch.reads_histograms:  # the counts behind validation_set's centre of mass: the same keys, the same draws
        counts, intensity = [], []
        for i, name in enumerate(out["names"]):
            depth = jnp.asarray(seqs[name].depth)[: train_cfg.val_frames]
            inten = jnp.asarray(seqs[name].intensity)[: train_cfg.val_frames]
            counts.append(simulate_histograms(jax.random.fold_in(key, i), depth, inten, sensor,
                                              snr=float(seqs[name].snr), mean_signal=train_cfg.val_mean_signal))
            intensity.append(inten)
        out.update(counts=jnp.concatenate(counts), intensity=jnp.concatenate(intensity))
        del out["windows"]
    return out


@functools.partial(jax.jit, static_argnames=("cfg",))
def _rbpn_windows(params, windows, cfg):
    return apply_rbpn(params, windows, cfg)


def evaluate_baseline(model: Model, validation: dict, *, sensor: Sensor = _SENSOR) -> dict:
    """Validation of a learned baseline: {"loss": its training content loss (HistNet mean |hr - gt|, iSeeBetter
    MSE), "psnr": mean per-frame PSNR (dB) of the clipped output}, Python floats. validation:
    `baseline_validation_set`."""
    if model.reads_histograms:
        hr = super_resolve_histograms(model, validation["counts"], sensor, intensity=validation["intensity"],
                                      batch_size=4)
        loss = np.mean(np.abs(hr - np.asarray(validation["gt"])))
    else:  # the validation windows themselves: frames of several sequences lie end to end
        windows = jnp.asarray(validation["windows"])
        n, pad = windows.shape[0], (-windows.shape[0]) % 4  # chunks of 4, the last padded: one compilation
        windows = jnp.concatenate([windows, jnp.repeat(windows[-1:], pad, 0)])
        hr = np.concatenate([np.asarray(_rbpn_windows(model.params, windows[i : i + 4], model.config))
                             for i in range(0, n + pad, 4)])[:n]
        loss = np.mean((hr - np.asarray(validation["gt"])) ** 2)
    gt = np.asarray(validation["gt"])
    return {"loss": float(loss), "psnr": float(np.mean(np.asarray(psnr(jnp.clip(hr, 0, 1), gt))))}


# --- the recipes `jaxsr.training.fit` reads ------------------------------------------------------------------


def _no_warm_start(name: str, init) -> None:
    if init is not None:
        raise ValueError(f"fit: init (a warm start) is the DUF network's; {name} starts from random weights")


def _shared_step(train_cfg: TrainConfig) -> TrainConfig:
    # the step does not read the seed or the stopping rule: runs that differ only in those share one compilation
    return dataclasses.replace(train_cfg, seed=0, epochs=1, patience=1)


def _evaluate(model, validation, train_cfg, *, sensor=_SENSOR, conv3d_impl="auto") -> dict:
    return evaluate_baseline(model, validation, sensor=sensor)


# HistNet: its params and one Adam, an L1 step on histograms + HR intensity


def _histnet_init(key, cfg: HistNetConfig, init=None) -> dict:
    _no_warm_start("histnet", init)
    params = init_histnet(key, cfg)
    return {"params": params, "state": {}, "opt": adam_init(params)}


def _histnet_step(cfg, train_cfg: TrainConfig, make_batch, *, sensor: Sensor = _SENSOR, mesh=None,
                  conv3d_impl="auto", pretrain_steps: int = 0):
    if pretrain_steps:
        raise ValueError("fit: pretrain_epochs is iSeeBetter's (a generator trained alone before its GAN), not "
                         "histnet's")
    return _histnet_run(cfg, _shared_step(train_cfg), make_batch, sensor)


@functools.lru_cache(maxsize=4)
def _histnet_run(cfg, train_cfg: TrainConfig, make_batch, sensor: Sensor):
    step = make_histnet_train_step(cfg, make_batch, schedule=lr_schedule(train_cfg), sensor=sensor)

    def run(ts, key, i):
        params, opt, metrics = step(ts["params"], ts["opt"], key, i)
        return {**ts, "params": params, "opt": opt}, metrics
    return run


register_recipe("histnet", Recipe(
    init=_histnet_init, step=_histnet_step,
    data=lambda cfg, train_cfg, sensor: histogram_batches(train_cfg, sensor=sensor),
    validation=_validation, evaluate=_evaluate, published=HistNetConfig()))


# iSeeBetter: a generator and a discriminator, each with its own Adam, in one train state


def _iseebetter_init(key, cfg: RBPNConfig, init=None) -> dict:
    _no_warm_start("iseebetter", init)
    k_g, k_d = jax.random.split(key)
    g = init_rbpn(k_g, cfg)
    d, d_state = init_discriminator(k_d, cfg)
    g_opt, d_opt = init_adam_pair(g, d)
    return {"params": g, "state": {}, "opt": g_opt, "disc": d, "disc_state": d_state, "disc_opt": d_opt}


def _iseebetter_step(cfg, train_cfg: TrainConfig, make_batch, *, sensor: Sensor = _SENSOR, mesh=None,
                     conv3d_impl="auto", pretrain_steps: int = 0):
    """run(ts, key, step) -> (ts, metrics): steps below `pretrain_steps` train the generator alone on its content
    loss (`make_rbpn_train_step`; the discriminator waits), the rest are GAN steps (`make_iseebetter_train_step`);
    `step` must then be a concrete integer (the phase is chosen in Python)."""
    return _iseebetter_run(cfg, _shared_step(train_cfg), make_batch, pretrain_steps)


@functools.lru_cache(maxsize=4)
def _iseebetter_run(cfg, train_cfg: TrainConfig, make_batch, pretrain_steps: int):
    schedule = lr_schedule(train_cfg)
    gan = make_iseebetter_train_step(cfg, make_batch, schedule=schedule)
    pretrain = make_rbpn_train_step(cfg, make_batch, schedule=schedule) if pretrain_steps else None

    def run(ts, key, i):
        if pretrain is not None and int(i) < pretrain_steps:
            g, g_opt, metrics = pretrain(ts["params"], ts["opt"], key, i)
            return {**ts, "params": g, "opt": g_opt}, metrics
        (g, d, d_state), (g_opt, d_opt), metrics = gan((ts["params"], ts["disc"], ts["disc_state"]),
                                                       (ts["opt"], ts["disc_opt"]), key, i)
        return {**ts, "params": g, "disc": d, "disc_state": d_state, "opt": g_opt, "disc_opt": d_opt}, metrics
    return run


register_recipe("iseebetter", Recipe(
    init=_iseebetter_init, step=_iseebetter_step,
    data=lambda cfg, train_cfg, sensor: scene_batches(cfg.frames // 2, train_cfg, sensor=sensor),
    validation=_validation, evaluate=_evaluate, published=RBPNConfig()))


# --- deprecated: the names of jaxsr 0.1, each now a call of the one model interface or the one loop -------------


def _deprecated(old: str, new: str):
    warnings.warn(f"{old} is deprecated: use {new}", DeprecationWarning, stacklevel=3)


def BaselineModel(kind: str, params, config) -> Model:  # noqa: N802 (the class name it replaces)
    """Deprecated: `jaxsr.nn.Model(params, {}, config)`, the one model interface.

    Returns that `Model` (its `kind` is `kind`; a dataclass now, not the NamedTuple of jaxsr 0.1: no tuple
    unpacking or `_replace`); raises ValueError for an unknown kind or another kind's config."""
    _deprecated("BaselineModel(kind, params, config)", "jaxsr.nn.Model(params, {}, config)")
    _check_kind(kind, "BaselineModel")
    if architecture(config) is not architecture(kind):
        raise ValueError(f"BaselineModel: a {type(config).__name__} is not a {kind} config")
    return Model(params, {}, config)


def save_baseline(path, model: Model, *, card: dict | None = None, storage_dtype: str = "float32") -> Path:
    """Deprecated: `jaxsr.save_model`, which saves every architecture (the same file and card).

    Returns the path written."""
    _deprecated("save_baseline", "jaxsr.save_model")
    return save_model(path, model, card=card, storage_dtype=storage_dtype)


def load_baseline(path) -> Model:
    """Deprecated: `jaxsr.load_model`, which loads every architecture (and baselines saved by jaxsr 0.1).
    Returns the `Model`; raises ValueError if the file holds no learned baseline."""
    _deprecated("load_baseline", "jaxsr.load_model")
    try:
        resolve_model_path(path)
    except FileNotFoundError:
        raise FileNotFoundError(
            f"no trained baseline at {str(path)!r} (nor {str(path)!r}.npz, nor bundled weights "
            f"jaxsr/weights/{Path(path).name}.npz); train one with `python experiments/paper/train_baselines.py "
            f"{Path(path).name if Path(path).name in BASELINES else 'histnet|iseebetter'} --bundle`") from None
    model = load_model(path)
    if not _is_baseline(model):
        raise ValueError(f"{str(path)!r} does not hold a trained learned baseline ({model.kind}; a TR model loads "
                         "with jaxsr.load_model)")
    return model


def _is_baseline(model: Model) -> bool:
    """Whether `model` is a learned baseline: its recipe trains it at a published size (`Recipe.published`)."""
    try:
        return recipe(model).published is not None
    except ValueError:  # an architecture without a recipe
        return False


def super_resolve_baseline(model: Model, *, counts=None, intensity=None, lr=None, batch_size: int = 4,
                           sensor: Sensor = _SENSOR) -> np.ndarray:
    """Deprecated: `jaxsr.super_resolve(model, lr)` (iSeeBetter) or `jaxsr.super_resolve_histograms(model, counts,
    intensity=intensity)` (HistNet). Returns (T, H, W) HR normalised depth for (T, ...) inputs (NumPy, not
    clipped)."""
    _deprecated("super_resolve_baseline", "jaxsr.super_resolve / jaxsr.super_resolve_histograms")
    if model.reads_histograms:
        if counts is None or intensity is None:
            raise ValueError("super_resolve_baseline: HistNet needs counts (T, h, w, K) and intensity (T, H, W)")
        return super_resolve_histograms(model, counts, sensor, intensity=intensity, batch_size=batch_size)
    if lr is None:
        raise ValueError("super_resolve_baseline: iSeeBetter needs lr (T, h, w) LR normalised depth")
    return super_resolve(model, lr, batch_size=batch_size)


def fit_baseline(kind: str, cfg, train_cfg: TrainConfig, *, out, make_batch=None, validation: dict | None = None,
                 sensor: Sensor = _SENSOR, resume: bool = False, callback=None, card_extra: dict | None = None,
                 pretrain_epochs: int = 0):
    """Deprecated: `jaxsr.fit`, which trains every architecture in one loop (the same file names; the card and
    the per-epoch keys are `fit`'s, and run folders begun by jaxsr 0.1's fit_baseline are refused on resume).

    Returns (best `Model`, history)."""
    _deprecated("fit_baseline", "jaxsr.fit")
    _check_kind(kind, "fit_baseline")
    config_type = architecture(kind).config_type
    if not isinstance(cfg, config_type):
        raise TypeError(f"fit_baseline: {kind} needs a {config_type.__name__}, got {type(cfg).__name__}")
    from .loop import fit  # the loop imports this package's recipes

    return fit(cfg, train_cfg, out=out, make_batch=make_batch, validation=validation, sensor=sensor, resume=resume,
               callback=callback, card_extra=card_extra, pretrain_epochs=pretrain_epochs, progress=False)
