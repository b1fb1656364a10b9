"""Train steps of the learned baselines (HistNet, iSeeBetter) and the data source HistNet needs.

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
import json
import math
import platform
import time
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..io.files import write_text_atomic
from ..io.checkpoint import config_from_dict, config_to_dict, load_tree, read_metadata, resolve_model_path, save_tree
from ..config import SensorConfig, TrainConfig
from .data import log_uniform, run_keys, scene_batches, validation_set
from ..baselines.histnet import HistNetConfig, apply_histnet, init_histnet
from ..eval.metrics import psnr
from .optim import AdamState, adam_init, adam_update, lr_schedule
from ..baselines.rbpn import (
    RBPNConfig,
    apply_discriminator,
    apply_rbpn,
    discriminator_loss,
    generator_loss,
    init_discriminator,
    init_rbpn,
)
from ..scenes import test_sequences, training_clip
from ..sensor.forward import normalise_depth, simulate_histograms
from ..temporal import windows as temporal_windows

__all__ = [
    "BASELINES",
    "BaselineModel",
    "baseline_schedule",
    "baseline_template",
    "baseline_train_step",
    "baseline_validation_set",
    "default_baseline_data",
    "evaluate_baseline",
    "fit_baseline",
    "histogram_batches",
    "init_adam_pair",
    "load_baseline",
    "make_histnet_train_step",
    "make_iseebetter_train_step",
    "make_rbpn_train_step",
    "resolve_baseline_path",
    "save_baseline",
    "super_resolve_baseline",
]
_SENSOR = SensorConfig()  # the default sensor


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


def histogram_batches(train_cfg: TrainConfig, *, sensor: SensorConfig = _SENSOR):
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


def make_histnet_train_step(cfg: HistNetConfig, make_batch, *, schedule, sensor: SensorConfig = _SENSOR):
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
    make_batch: key -> (windows (B, frames, h, w), gt (B, h r, w r)), e.g. `jaxsr.training.data.scene_batches(cfg.frames //
    2, train_cfg)`; the flows are computed once per batch (`rbpn_flows`). schedule: step -> lr for both.
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

BASELINES = ("histnet", "iseebetter")
_CONFIGS = {"histnet": HistNetConfig, "iseebetter": RBPNConfig}


class BaselineModel(NamedTuple):
    """A trained learned baseline: `kind` ("histnet" or "iseebetter"), the network's params (iSeeBetter: the
    generator only; its discriminator serves training alone) and its config (`HistNetConfig` / `RBPNConfig`)."""

    kind: str
    params: dict
    config: HistNetConfig | RBPNConfig


def _check_kind(kind: str, who: str) -> None:
    if kind not in BASELINES:
        raise ValueError(f"{who}: unknown baseline {kind!r}; expected one of {', '.join(BASELINES)}")


def baseline_template(kind: str, cfg):
    """Shapes and dtypes of the network parameters of baseline `kind` with config `cfg`, computing nothing."""
    _check_kind(kind, "baseline_template")
    init = init_histnet if kind == "histnet" else init_rbpn
    return jax.eval_shape(lambda k: init(k, cfg), jax.random.key(0))


def save_baseline(path, model: BaselineModel, *, card: dict | None = None, storage_dtype: str = "float32") -> Path:
    """Save a `BaselineModel` to `path` (.npz, atomically): arrays `params/...` and metadata {kind: "baseline",
    baseline, config, card, storage_dtype}. storage_dtype "float16" halves the file (`load_baseline` returns
    float32); raises ValueError for a value beyond float16's range. Returns the path."""
    _check_kind(model.kind, "save_baseline")
    tree = {"params": jax.tree_util.tree_map(lambda x: np.asarray(x, np.float32), model.params)}
    if storage_dtype == "float16":
        if any(np.any(np.abs(v) > np.finfo(np.float16).max) for v in jax.tree_util.tree_leaves(tree)):
            raise ValueError("save_baseline: weights beyond float16's range; store as float32")
        tree = jax.tree_util.tree_map(lambda x: x.astype(np.float16), tree)
    elif storage_dtype != "float32":
        raise ValueError(f"save_baseline: storage_dtype must be 'float32' or 'float16', got {storage_dtype!r}")
    meta = {"kind": "baseline", "baseline": model.kind, "config": config_to_dict(model.config), "card": card or {},
            "storage_dtype": storage_dtype}
    return save_tree(path, tree, meta)


def resolve_baseline_path(path) -> Path:
    """`path` if it is a file, else `path` + ".npz", else the bundled weights of that name
    (`jaxsr/weights/histnet.npz` for "histnet"). Raises FileNotFoundError saying where it looked and how the
    bundled ones are made."""
    try:
        return resolve_model_path(path)
    except FileNotFoundError:
        raise FileNotFoundError(
            f"no trained baseline at {str(path)!r} (nor {str(path)!r}.npz, nor bundled weights "
            f"jaxsr/weights/{Path(path).name}.npz); train one with `python experiments/train_baselines.py "
            f"{Path(path).name if Path(path).name in BASELINES else 'histnet|iseebetter'} --bundle`") from None


def load_baseline(path) -> BaselineModel:
    """Load a `BaselineModel` written by `save_baseline` (or the best weights `fit_baseline` keeps).

    path: a file, a file without its `.npz`, or a bundled name ("histnet", "iseebetter"). Every array is checked
    against the shapes of the stored config. Raises FileNotFoundError for a missing file, ValueError for a file
    that is not a trained baseline (e.g. a TR model), an unknown kind or config, a missing/extra array or a
    shape/dtype mismatch. Returns params float32 in memory.
    """
    path = resolve_baseline_path(path)
    meta = read_metadata(path)
    if meta.get("kind") != "baseline":
        raise ValueError(f"{str(path)!r} does not hold a trained learned baseline (kind {meta.get('kind')!r}; a "
                         "TR model loads with jaxsr.load_model)")
    kind = meta.get("baseline")
    if kind not in BASELINES:
        raise ValueError(f"{str(path)!r}: unknown baseline {kind!r}; expected one of {', '.join(BASELINES)}")
    try:
        cfg = config_from_dict(_CONFIGS[kind], meta["config"])
    except (KeyError, TypeError, AttributeError, ValueError) as e:
        raise ValueError(f"{str(path)!r}: unreadable {kind} config {meta.get('config')!r}: {e}") from e
    tree, _ = load_tree(path, {"params": baseline_template(kind, cfg)})
    return BaselineModel(kind, jax.tree_util.tree_map(jnp.asarray, tree["params"]), cfg)


@functools.partial(jax.jit, static_argnames=("cfg", "sensor"))
def _histnet_chunk(params, counts, intensity, cfg, sensor):
    return apply_histnet(params, counts, intensity, cfg, sensor=sensor)


@functools.partial(jax.jit, static_argnames=("cfg",))
def _rbpn_chunk(params, windows, cfg):
    return apply_rbpn(params, windows, cfg)


def _chunked(fn, n: int, batch_size: int, *arrays):
    """fn over the leading axis in chunks of batch_size, the last one padded (one compilation per size)."""
    outs = []
    for i in range(0, n, batch_size):
        chunk = [a[i : i + batch_size] for a in arrays]
        pad = batch_size - chunk[0].shape[0]
        if pad:
            chunk = [jnp.concatenate([c, jnp.repeat(c[-1:], pad, 0)]) for c in chunk]
        outs.append(np.asarray(fn(*chunk))[: batch_size - pad])
    return np.concatenate(outs)


def super_resolve_baseline(model: BaselineModel, *, counts=None, intensity=None, lr=None, batch_size: int = 4,
                           sensor: SensorConfig = _SENSOR) -> np.ndarray:
    """A trained baseline over a sequence, as our `super_resolve`: (T, ...) in, (T, H, W) HR normalised depth out
    (NumPy float32, not clipped).

    HistNet: counts (T, h, w, K) LR photon histograms and intensity (T, 4h, 4w) HR intensity in [0, 1], frame by
    frame. iSeeBetter: lr (T, h, w) LR normalised depth (centre of mass); windows of `config.frames` frames,
    edge-replicated at the ends (`jaxsr.temporal.windows`). Returns the (T, 4h, 4w) HR frames.
    """
    if model.kind == "histnet":
        if counts is None or intensity is None:
            raise ValueError("super_resolve_baseline: HistNet needs counts (T, h, w, K) and intensity (T, H, W)")
        counts, intensity = jnp.asarray(counts, jnp.float32), jnp.asarray(intensity, jnp.float32)
        if counts.ndim != 4 or intensity.shape != (counts.shape[0], *(sensor.scale * s for s in counts.shape[1:3])):
            raise ValueError(f"super_resolve_baseline: expected counts (T, h, w, K) and intensity (T, {sensor.scale}h, "
                             f"{sensor.scale}w), got {counts.shape} and {intensity.shape}")
        fn = functools.partial(_histnet_chunk, model.params, cfg=model.config, sensor=sensor)
        return _chunked(fn, counts.shape[0], batch_size, counts, intensity)
    if lr is None:
        raise ValueError("super_resolve_baseline: iSeeBetter needs lr (T, h, w) LR normalised depth")
    lr = jnp.asarray(lr, jnp.float32)
    if lr.ndim != 3:
        raise ValueError(f"super_resolve_baseline: expected lr (T, h, w), got {lr.shape}")
    windows = temporal_windows(lr, model.config.frames // 2)
    return _chunked(functools.partial(_rbpn_chunk, model.params, cfg=model.config), lr.shape[0], batch_size, windows)


def baseline_validation_set(key, kind: str, cfg, train_cfg: TrainConfig, *, sensor: SensorConfig = _SENSOR) -> dict:
    """The validation frames of `jaxsr.training.data.validation_set` (the first `val_frames` of each validation sequence at
    its own SNR, `val_mean_signal`, the same noise for the same key) with what each baseline reads: "counts"
    (N, h, w, K) and "intensity" (N, H, W) for HistNet, "windows" (N, frames, h, w) for iSeeBetter; plus "gt"
    (N, H, W), "lr" (N, h, w), "names", "lengths"."""
    _check_kind(kind, "baseline_validation_set")
    seqs = test_sequences(n_frames=train_cfg.val_frames, names=train_cfg.val_sequences or None, sensor=sensor)
    tr = cfg.frames // 2 if kind == "iseebetter" else 0
    out = validation_set(key, tr, train_cfg, sensor=sensor, sequences=seqs)
    if kind == "histnet":  # the counts behind validation_set's centre of mass: the same keys, the same draws
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


def evaluate_baseline(model: BaselineModel, validation: dict, *, sensor: SensorConfig = _SENSOR) -> dict:
    """Validation of a baseline: {"loss": its training content loss (HistNet mean |hr - gt|, iSeeBetter MSE),
    "psnr": mean per-frame PSNR (dB) of the clipped output}, Python floats. validation: `baseline_validation_set`.
    """
    if model.kind == "histnet":
        hr = super_resolve_baseline(model, counts=validation["counts"], intensity=validation["intensity"],
                                    sensor=sensor)
    else:
        hr = _chunked(functools.partial(_rbpn_chunk, model.params, cfg=model.config), validation["gt"].shape[0], 4,
                      validation["windows"])
    gt = np.asarray(validation["gt"])
    loss = np.mean(np.abs(hr - gt)) if model.kind == "histnet" else np.mean((hr - gt) ** 2)
    return {"loss": float(loss), "psnr": float(np.mean(np.asarray(psnr(jnp.clip(hr, 0, 1), gt))))}


def _init_train_state(key, kind: str, cfg) -> dict:
    """The arrays a baseline's train step updates: its params and Adam state (iSeeBetter: also the
    discriminator's params, batch-norm state and Adam state)."""
    if kind == "histnet":
        params = init_histnet(key, cfg)
        return {"params": params, "opt": adam_init(params)}
    k_g, k_d = jax.random.split(key)
    g = init_rbpn(k_g, cfg)
    d, d_state = init_discriminator(k_d, cfg)
    g_opt, d_opt = init_adam_pair(g, d)
    return {"params": g, "disc": d, "disc_state": d_state, "opt": g_opt, "disc_opt": d_opt}


# The learning rate of a baseline's run: the same step decay as our networks' (`jaxsr.training.optim.lr_schedule`)
baseline_schedule = lr_schedule


def baseline_train_step(kind: str, cfg, train_cfg: TrainConfig, make_batch, sensor: SensorConfig = _SENSOR, *,
                        pretrain_steps: int = 0):
    """One jitted train step of baseline `kind` on the dict of `_init_train_state`: run(train_state, key, step) ->
    (train_state, metrics). Cached, so a resumed or repeated run does not compile again. The dict's arrays are
    donated: copy what must outlive the step (`jax.device_get`). iSeeBetter: steps below `pretrain_steps` train
    the generator alone on its content loss (`make_rbpn_train_step`; the discriminator waits), the rest are GAN
    steps; `step` must then be a concrete integer (the phase is chosen in Python)."""
    _check_kind(kind, "baseline_train_step")
    if pretrain_steps < 0 or (pretrain_steps and kind != "iseebetter"):
        raise ValueError(f"baseline_train_step: pretrain_steps is iSeeBetter's (>= 0), got {pretrain_steps} for {kind}")
    # the step does not read the seed or the stopping rule: runs that differ only in those share one compilation
    return _baseline_train_step(kind, cfg, dataclasses.replace(train_cfg, seed=0, epochs=1, patience=1), make_batch,
                                sensor, pretrain_steps)


@functools.lru_cache(maxsize=8)
def _baseline_train_step(kind: str, cfg, train_cfg: TrainConfig, make_batch, sensor: SensorConfig,
                         pretrain_steps: int = 0):
    schedule = baseline_schedule(train_cfg)
    if kind == "histnet":
        step = make_histnet_train_step(cfg, make_batch, schedule=schedule, sensor=sensor)

        def run(ts, key, i):
            params, opt, metrics = step(ts["params"], ts["opt"], key, i)
            return {"params": params, "opt": opt}, metrics
        return run
    step = make_iseebetter_train_step(cfg, make_batch, schedule=schedule)
    pretrain = make_rbpn_train_step(cfg, make_batch, schedule=schedule) if pretrain_steps else None

    def run(ts, key, i):
        if pretrain is not None and int(i) < pretrain_steps:
            g, g_opt, metrics = pretrain(ts["params"], ts["opt"], key, i)
            return {**ts, "params": g, "opt": g_opt}, metrics
        (g, d, d_state), (g_opt, d_opt), metrics = step((ts["params"], ts["disc"], ts["disc_state"]),
                                                        (ts["opt"], ts["disc_opt"]), key, i)
        return {"params": g, "disc": d, "disc_state": d_state, "opt": g_opt, "disc_opt": d_opt}, metrics
    return run


def default_baseline_data(kind: str, cfg, train_cfg: TrainConfig, *, sensor: SensorConfig = _SENSOR):
    """The data our networks train on, in each baseline's form: `histogram_batches` (HistNet) or
    `jaxsr.training.data.scene_batches` with tr = frames // 2 (iSeeBetter); same clips, SNR and signal ranges, crops."""
    _check_kind(kind, "default_baseline_data")
    if kind == "histnet":
        return histogram_batches(train_cfg, sensor=sensor)
    return scene_batches(cfg.frames // 2, train_cfg, sensor=sensor)


BASELINE_RUN_FILES = ("metrics.jsonl", "last.npz", "best.npz")


def _baseline_settings(kind: str, cfg, train_cfg: TrainConfig, pretrain_epochs: int = 0) -> dict:
    # JSON round trip: tuples become lists, as they read back from a file
    return json.loads(json.dumps({"baseline": kind, "config": config_to_dict(cfg),
                                  "train_config": config_to_dict(train_cfg), "pretrain_epochs": pretrain_epochs}))


def _check_same_run(path: Path, saved: dict, wanted: dict) -> None:
    """ValueError naming each setting (but the epoch budget) in which the run at `path` differs from `wanted`."""
    def flat(s):
        out = {"baseline": s["baseline"], "pretrain_epochs": s.get("pretrain_epochs", 0),
               **{f"config.{k}": v for k, v in s["config"].items()}}
        out.update({f"train.{k}": v for k, v in s["train_config"].items() if k != "epochs"})
        return out

    a, b = flat(saved), flat(wanted)
    differ = sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))
    if differ:
        raise ValueError(f"fit_baseline: cannot resume {str(path)!r}: it was trained with other settings: "
                         + ", ".join(f"{k} {a.get(k)!r} (now {b.get(k)!r})" for k in differ))


def fit_baseline(kind: str, cfg, train_cfg: TrainConfig, *, out, make_batch=None, validation: dict | None = None,
                 sensor: SensorConfig = _SENSOR, resume: bool = False, callback=None, card_extra: dict | None = None,
                 pretrain_epochs: int = 0):
    """Train a learned baseline as `jaxsr.fit` trains our networks; returns (best `BaselineModel`, history).

    Epochs of `train_cfg.steps_per_epoch` steps (rate `baseline_schedule`), each followed by validation
    (`evaluate_baseline` on `validation`, default `baseline_validation_set`), early stopping after `patience`
    epochs without a lower validation loss, and atomic writes into folder `out`: `best.npz` (the best epoch's
    weights, `load_baseline` reads it, with a training card), `last.npz` (everything needed to resume) and
    `metrics.jsonl`. `resume=True` continues from `last.npz` (refused if any setting but `epochs` differs); a
    folder holding a run is refused (FileExistsError) without it. make_batch: default `default_baseline_data`.
    callback(record) after each epoch's files are written; card_extra: entries added to the card (e.g. the budget).
    pretrain_epochs (iSeeBetter): epochs of generator-only training on the content loss before the GAN epochs.
    """
    _check_kind(kind, "fit_baseline")
    if not isinstance(cfg, _CONFIGS[kind]):
        raise TypeError(f"fit_baseline: {kind} needs a {_CONFIGS[kind].__name__}, got {type(cfg).__name__}")
    out = Path(out)
    held = [n for n in BASELINE_RUN_FILES if (out / n).exists()]
    if held and not resume:
        raise FileExistsError(f"{out} holds a training run ({', '.join(held)}); pass resume=True to continue it")
    out.mkdir(parents=True, exist_ok=True)
    k_init, k_data, k_val = run_keys(train_cfg.seed)  # as `fit` derives them
    make_batch = default_baseline_data(kind, cfg, train_cfg, sensor=sensor) if make_batch is None else make_batch
    if validation is None:
        validation = baseline_validation_set(k_val, kind, cfg, train_cfg, sensor=sensor)
    settings = _baseline_settings(kind, cfg, train_cfg, pretrain_epochs)
    state_t = jax.eval_shape(lambda k: _init_train_state(k, kind, cfg), jax.random.key(0))
    template = {"train": state_t, "best": state_t["params"],
                "key": jax.eval_shape(lambda: jax.random.key_data(jax.random.key(0)))}
    last = out / "last.npz"
    if resume and last.is_file():
        meta = read_metadata(last)
        if meta.get("kind") != "baseline_train_state":
            raise ValueError(f"fit_baseline: {str(last)!r} is not a baseline training state")
        _check_same_run(last, meta["settings"], settings)
        tree, _ = load_tree(last, template)
        tree = jax.tree_util.tree_map(jnp.asarray, tree)
        ts, best, k_data = tree["train"], tree["best"], jax.random.wrap_key_data(tree["key"])
        ts["opt"] = AdamState(*ts["opt"])
        if "disc_opt" in ts:
            ts["disc_opt"] = AdamState(*ts["disc_opt"])
        run = dict(meta["run"])
    else:
        ts = _init_train_state(k_init, kind, cfg)
        best = jax.device_get(ts["params"])
        run = {"epoch": 0, "step": 0, "best_loss": math.inf, "best_epoch": -1, "bad_epochs": 0, "wall_time_s": 0.0,
               "history": []}
    spe = train_cfg.steps_per_epoch
    step_fn = baseline_train_step(kind, cfg, train_cfg, make_batch, sensor, pretrain_steps=pretrain_epochs * spe)
    while run["bad_epochs"] < train_cfg.patience and run["epoch"] < train_cfg.epochs:
        t0 = time.perf_counter()
        sums = {}
        for i in range(spe):
            step = run["epoch"] * spe + i
            ts, m = step_fn(ts, jax.random.fold_in(k_data, step), jnp.int32(step))
            for k, v in jax.device_get(m).items():
                sums[k] = sums.get(k, 0.0) + float(v)
        train_time = time.perf_counter() - t0
        val = evaluate_baseline(BaselineModel(kind, ts["params"], cfg), validation, sensor=sensor)
        run["epoch"] += 1
        run["step"] = run["epoch"] * spe
        record = {"epoch": run["epoch"], "step": run["step"], **{f"train_{k}": v / spe for k, v in sums.items()},
                  "val_loss": val["loss"], "val_psnr": val["psnr"], "examples_per_s": spe * train_cfg.batch_size / train_time}
        if val["loss"] < run["best_loss"]:
            run.update(best_loss=val["loss"], best_epoch=run["epoch"] - 1, bad_epochs=0)
            best = jax.device_get(ts["params"])
        else:
            run["bad_epochs"] += 1
        run["wall_time_s"] += time.perf_counter() - t0
        record["wall_time_s"] = run["wall_time_s"]
        run["history"] = [*run["history"], record]
        card = {"data": getattr(make_batch, "description", "user-supplied make_batch"), "steps": run["step"],
                "epochs": run["epoch"], "examples": run["step"] * train_cfg.batch_size,
                "best_epoch": run["best_epoch"], "wall_time_s": run["wall_time_s"],
                "hardware": {"backend": jax.default_backend(), "devices": jax.device_count(),
                             "host": platform.platform(), "jax": jax.__version__},
                "validation": {"sequences": list(validation.get("names", [])), "frames": int(validation["gt"].shape[0]),
                               "loss": run["best_loss"], "psnr": run["history"][run["best_epoch"]]["val_psnr"]},
                "train_config": settings["train_config"], "seed": train_cfg.seed,
                **({"pretrain_epochs": pretrain_epochs} if pretrain_epochs else {}), **(card_extra or {})}
        # best first, then last: a kill between the two resumes from the previous epoch and rewrites both
        if run["best_epoch"] == run["epoch"] - 1:
            save_baseline(out / "best.npz", BaselineModel(kind, best, cfg), card=card)
        tree = {"train": ts, "best": best, "key": jax.random.key_data(k_data)}
        save_tree(last, tree, {"kind": "baseline_train_state", "settings": settings, "run": run, "card": card})
        write_text_atomic(out / "metrics.jsonl", "".join(json.dumps(r) + "\n" for r in run["history"]))
        if callback is not None:
            callback(record)
    return BaselineModel(kind, jax.tree_util.tree_map(jnp.asarray, best), cfg), list(run["history"])
