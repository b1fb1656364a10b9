"""Training: the jitted train step (data simulated inside it), validation, and `fit`.

The data come from a source `make_batch(key) -> (windows, gt)` of `jaxsr.training.data` (default `scene_batches`), run
inside the jitted step; a sequence-form model (`ModelConfig(temporal="sequence")`) trains on clips instead,
`make_batch(key) -> (clips (B, L, h, w), gt (B, L, H, W))` (default `scene_clips`), with the loss on the L - 2R
frames whose inputs lie inside the clip and BN statistics over the clip. `fit` runs epochs of
`TrainConfig.steps_per_epoch` steps with step decay, validates with BN in inference mode, logs to `metrics.jsonl`,
writes `best.npz` (a `Model`) and `last.npz` (everything needed to resume) after every epoch, `resume.npz` (the
same, inside an epoch) every `checkpoint_every_s` seconds of training, and stops early. Data parallelism: pass a
`jax.sharding.Mesh` with a "data" axis (default: all devices); the batch is split over it and the parameters are
replicated.
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
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from ..io.files import write_text_atomic
from ..baselines.interpolation import bicubic
from ..io.checkpoint import (
    config_from_dict,
    config_to_dict,
    load_model,
    load_tree,
    model_template,
    read_metadata,
    save_model,
    save_tree,
)
from ..config import ModelConfig, SensorConfig, TrainConfig
from .data import run_keys, scene_batches, scene_clips, validation_set
from ..inference.super_resolve import super_resolve
from ..eval.metrics import huber_loss, psnr
from ..nn.duf import (Model, apply_model, apply_model_sequence_train, apply_model_train, grow_tr, init_model,
                    sequence_radius)
from .optim import AdamState, adam_init, adam_update, lr_schedule

__all__ = [
    "huber_loss",  # defined in jaxsr.eval.metrics, the training loss
    "lr_schedule",  # defined in jaxsr.training.optim, shared with the baselines' training
    "make_train_step",
    "evaluate",
    "evaluate_sequences",
    "data_mesh",
    "choose_mesh",
    "replicate",
    "fit",
    "resume_config",
]


def data_mesh(devices=None) -> Mesh:
    """A 1-D mesh with axis "data" over `devices` (default: all devices of all processes)."""
    devices = jax.devices() if devices is None else devices
    return Mesh(np.asarray(devices), ("data",))


def make_train_step(model_cfg: ModelConfig, train_cfg: TrainConfig, make_batch, *, mesh: Mesh | None = None,
                    conv3d_impl: str = "auto"):
    """The jitted train step: step(params, state, opt_state, key, step) -> (params, state, opt_state, metrics).

    Inside one jit: make_batch(key) -> network with BN in training mode -> Huber loss -> gradients -> Adam
    with lr = `lr_schedule(train_cfg)(step)`. The network runs in `model_cfg.temporal`'s form (see
    `sequence_loss` for the sequence form's batches). metrics: {"loss", "psnr" (mean over the batch, prediction
    clipped), "lr"}. With a `mesh`, the batch is sharded over its "data" axis and params/state/optimiser
    state are replicated (batch statistics and gradients are reduced over the mesh).
    conv3d_impl: how the network's convolutions run (see `apply_model`).
    """
    # the step does not read the seed, the length of the run or the stopping rule: runs that differ only in
    # those (other seeds, more epochs on resume) share one compiled step
    step_cfg = dataclasses.replace(train_cfg, seed=0, epochs=1, patience=1)
    return _train_step(model_cfg, step_cfg, make_batch, mesh, conv3d_impl)


@functools.lru_cache(maxsize=16)
def _train_step(model_cfg, train_cfg, make_batch, mesh, conv3d_impl):
    # cached: fitting again with the same configs and data source (e.g. a resume) does not recompile
    schedule = lr_schedule(train_cfg)

    def constrain(tree, spec):
        if mesh is None:
            return tree
        return jax.lax.with_sharding_constraint(tree, NamedSharding(mesh, spec))

    def step_fn(params, state, opt_state, key, step):
        windows, gt = constrain(make_batch(key), P("data"))

        def loss_fn(p):
            if model_cfg.temporal == "sequence":
                return sequence_loss(p, state, windows, gt, model_cfg, delta=train_cfg.huber_delta,
                                     conv3d_impl=conv3d_impl)
            hr, new_state = apply_model_train(p, state, windows, model_cfg, conv3d_impl=conv3d_impl)
            return huber_loss(hr, gt, delta=train_cfg.huber_delta), (new_state, hr, gt)

        (loss, (new_state, hr, gt)), grads = jax.value_and_grad(loss_fn, has_aux=True)(params)
        lr = schedule(step)
        params, opt_state = adam_update(
            grads, opt_state, params, lr=lr, b1=train_cfg.adam_b1, b2=train_cfg.adam_b2, eps=train_cfg.adam_eps
        )
        params, new_state, opt_state = constrain((params, new_state, opt_state), P())
        metrics = {"loss": loss, "psnr": jnp.mean(psnr(hr, gt)), "lr": lr}
        return params, new_state, opt_state, metrics

    donate = (0, 1, 2) if jax.default_backend() != "cpu" else ()
    return jax.jit(step_fn, donate_argnums=donate)


def sequence_loss(params, state, clips, gt, cfg: ModelConfig, *, delta: float = 0.01, conv3d_impl: str = "auto"):
    """The sequence form's training loss: mean Huber loss over the frames of each clip whose inputs all lie
    inside it, BN with the statistics of the whole batch of clips (`apply_model_sequence_train`, "valid").

    clips: (B, L, h, w) LR normalised depth, L >= 2R + 1 (R = 3 + tr); gt: (B, L, h*r, w*r) the ground truth of
    every frame. Returns (loss (scalar), (new BN state, hr (B, L - 2R, h*r, w*r), gt of those frames)).
    """
    r = sequence_radius(cfg)
    if gt.ndim != 4 or gt.shape[:2] != clips.shape[:2]:
        raise ValueError(f"sequence_loss: expected gt (B, L, H, W) for clips {clips.shape}, got {gt.shape}")
    hr, new_state = apply_model_sequence_train(params, state, clips, cfg, padding="valid", conv3d_impl=conv3d_impl)
    gt = gt[:, r : gt.shape[1] - r]
    return huber_loss(hr, gt, delta=delta), (new_state, hr, gt)


@functools.partial(jax.jit, static_argnames=("cfg", "delta", "conv3d_impl"))
def _eval_chunk(params, state, windows, gt, cfg, delta, conv3d_impl):
    hr = apply_model(params, state, windows, cfg, conv3d_impl=conv3d_impl)
    return huber_loss(hr, gt, delta=delta, axis=(-2, -1)), psnr(hr, gt)


def evaluate(params, state, windows, gt, cfg: ModelConfig, *, delta: float = 0.01, batch_size: int = 8,
             conv3d_impl: str = "auto") -> dict:
    """Validation with BN in inference mode: {"loss": mean Huber, "psnr": mean per-frame PSNR (dB)}.

    windows: (N, 2tr+1, h, w); gt: (N, h*r, w*r). Runs in chunks of `batch_size` frames (the last padded);
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
    gt: (N, h*r, w*r). Each sequence is super-resolved whole, its ends edge-padded (`super_resolve` of the
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


def _validate(ts, validation: dict, model_cfg: ModelConfig, train_cfg: TrainConfig, conv3d_impl: str) -> dict:
    """`evaluate` (window form) or `evaluate_sequences` (sequence form) of the current weights."""
    if model_cfg.temporal == "sequence":
        return evaluate_sequences(ts.params, ts.state, validation["lr"], validation["gt"], model_cfg,
                                  lengths=validation.get("lengths"), delta=train_cfg.huber_delta,
                                  conv3d_impl=conv3d_impl)
    return evaluate(ts.params, ts.state, validation["windows"], validation["gt"], model_cfg,
                    delta=train_cfg.huber_delta, conv3d_impl=conv3d_impl)


def _hardware() -> dict:
    devs = jax.devices()
    return {
        "backend": jax.default_backend(),
        "devices": len(devs),
        "device_kind": devs[0].device_kind,
        "processes": jax.process_count(),
        "host": platform.platform(),
        "jax": jax.__version__,
    }


class _TrainState(NamedTuple):
    """The arrays of a run, as `last.npz` holds them (the key as raw key data there): what the train step
    updates (params, BN state, Adam state), the best epoch's {"params", "state"} (on the host), and the data
    key (step s draws its batch with fold_in(key, s))."""

    params: dict
    state: dict
    opt: AdamState
    best: dict
    key: jax.Array


@dataclasses.dataclass(frozen=True)
class _Run:
    """Where a run stands after `epoch` finished epochs and `step` steps; saved as the "run" metadata of `last.npz`
    (at an epoch's end) and `resume.npz` (inside one).

    best_loss / best_epoch (0-based, -1 before the first) / bad_epochs (epochs since the best) drive early
    stopping; history holds the per-epoch records of `metrics.jsonl`. Inside epoch `epoch` (0-based: step >
    epoch * steps_per_epoch), the sums of its train loss and PSNR so far and its training time are kept, so that
    the resumed epoch logs what an uninterrupted one would; they are 0 at an epoch's end.
    """

    epoch: int = 0
    step: int = 0
    epoch_loss_sum: float = 0.0
    epoch_psnr_sum: float = 0.0
    epoch_train_s: float = 0.0
    best_loss: float = math.inf
    best_epoch: int = -1
    bad_epochs: int = 0
    wall_time_s: float = 0.0
    finished: bool = False
    history: tuple = ()


def _train_state_template(model_cfg: ModelConfig):
    params_t, state_t = model_template(model_cfg)
    return {
        "params": params_t,
        "state": state_t,
        "opt": jax.eval_shape(adam_init, params_t),
        "best": {"params": params_t, "state": state_t},
        "key": jax.eval_shape(lambda: jax.random.key_data(jax.random.key(0))),
    }


def choose_mesh(mesh, batch_size: int) -> Mesh | None:
    """`fit`'s mesh argument resolved: "auto" shards over all devices when there are several that divide the
    batch evenly."""
    if mesh != "auto":
        return mesh
    n = jax.device_count()
    return data_mesh() if n > 1 and batch_size % n == 0 else None


def replicate(tree, mesh: Mesh | None):
    """`tree` with a copy on every device of `mesh`, as a sharded train step expects its carry (params, state,
    Adam state: the step shards only the batch), so that its first calls do not compile again for another
    placement; unchanged when `mesh` is None."""
    return tree if mesh is None else jax.device_put(tree, NamedSharding(mesh, P()))


def _bicubic_psnr(validation: dict, scale: int) -> float | None:
    """Mean PSNR (dB) of bicubic upsampling of the validation set's centre frames (None without "lr"): the
    baseline every epoch's validation PSNR is logged beside."""
    if "lr" not in validation:
        return None
    return float(jnp.mean(psnr(bicubic(validation["lr"], scale=scale), validation["gt"])))


def _settings(model_cfg: ModelConfig, train_cfg: TrainConfig) -> dict:
    """{"config", "train_config"} as a checkpoint's metadata holds them."""
    # JSON round trip: tuples become lists, as they are when read back from a checkpoint
    return json.loads(json.dumps({"config": config_to_dict(model_cfg), "train_config": config_to_dict(train_cfg)}))


def _check_resumable(path: Path, meta: dict, settings: dict):
    """Raise ValueError naming every setting in which the run saved at `path` differs from `settings`.

    Everything must match except `epochs`: extending a finished run is a resume, not a new run (the schedule
    depends on decay_epochs and patience, not on the epoch budget). Fields older versions kept in the model
    config (`checkpoint.LEGACY_FIELDS`) are ignored, fields they lacked take their defaults.
    """
    def flat(model, train):
        return dict(model, **{f"train.{k}": v for k, v in train.items() if k != "epochs"})

    saved = flat(config_to_dict(config_from_dict(ModelConfig, meta["config"])), meta["train_config"])
    wanted = flat(settings["config"], settings["train_config"])
    differ = sorted(k for k in saved.keys() | wanted.keys() if saved.get(k) != wanted.get(k))
    if differ:
        raise ValueError(
            f"fit: cannot resume {str(path)!r}: it was trained with other settings: "
            + ", ".join(f"{k} {saved.get(k)!r} (now {wanted.get(k)!r})" for k in differ)
        )


def resume_config(out, train_cfg: TrainConfig) -> TrainConfig:
    """`train_cfg` with the validation sequences of the run saved in folder `out`, so that `fit(resume=True)`
    continues it: runs begun before 2026-11-24 validate on val1_street and val3_courtyard, which the presets
    dropped, and fit refuses to resume under other settings. Every other setting is left for fit to check. A
    folder without a run (no last.npz or resume.npz) gives `train_cfg` unchanged."""
    saved_run = _latest_state(Path(out))
    if saved_run is None:
        return train_cfg
    saved = read_metadata(saved_run).get("train_config", {}).get("val_sequences")
    return train_cfg if saved is None else dataclasses.replace(train_cfg, val_sequences=tuple(saved))


def _initial_weights(k_init, model_cfg: ModelConfig, init) -> tuple[dict, dict]:
    """(params, state) to start from: drawn with `k_init`, or those of `init` (a `Model` or a checkpoint
    path), which must have `model_cfg`'s architecture (its temporal form may differ: fine-tuning a windowed
    model into the sequence form) or that of a smaller TR (a warm start: `grow_tr` to `model_cfg.tr`, the
    added blocks drawn with `k_init`)."""
    if init is None:
        return init_model(k_init, model_cfg)
    model = init if isinstance(init, Model) else load_model(init)
    if model.config.tr < model_cfg.tr:
        model = grow_tr(k_init, model, model_cfg.tr)
    if dataclasses.replace(model.config, temporal=model_cfg.temporal) != model_cfg:
        differ = [k for k, v in config_to_dict(model_cfg).items()
                  if k != "temporal" and getattr(model.config, k) != v]
        raise ValueError("fit: the init model's architecture differs from the model to train: "
                         + ", ".join(f"{k} {getattr(model.config, k)!r} (training {getattr(model_cfg, k)!r})"
                                     for k in differ))
    return jax.tree_util.tree_map(jnp.asarray, (model.params, model.state))


def default_data(model_cfg: ModelConfig, train_cfg: TrainConfig, sensor: SensorConfig = SensorConfig()):
    """`fit`'s data source when none is given: rendered scenes, as windows of 2tr+1 frames (window form,
    `scene_batches`) or clips of `train_cfg.clip_length` frames (sequence form, `scene_clips`).
    Returns make_batch: key -> (inputs, gt) of that source."""
    if model_cfg.temporal == "sequence":
        return scene_clips(train_cfg.clip_length(model_cfg), train_cfg, sensor=sensor)
    return scene_batches(model_cfg.tr, train_cfg, sensor=sensor)


def _latest_state(out: Path) -> Path | None:
    """The train state to resume the run in folder `out` from: `resume.npz` (inside an epoch) when it is ahead of
    `last.npz` (an epoch's end; ahead of it when a kill fell between writing it and removing resume.npz), None
    when neither exists."""
    saved = [p for p in (out / "last.npz", out / RESUME_FILE) if p.is_file()]
    return max(saved, key=lambda p: read_metadata(p).get("run", {}).get("step", 0), default=None)


def _start_or_resume(out: Path, model_cfg: ModelConfig, train_cfg: TrainConfig, settings: dict, *,
                     k_init, k_data, resume: bool, init=None) -> tuple[_TrainState, _Run]:
    """The run saved in folder `out` (`_latest_state`) when resuming one, else a fresh one (weights from `init` or
    drawn with `k_init`, data from `k_data`)."""
    path = _latest_state(out) if resume else None
    if path is None:
        params, state = _initial_weights(k_init, model_cfg, init)
        best = jax.device_get({"params": params, "state": state})
        return _TrainState(params, state, adam_init(params), best, k_data), _Run()
    _check_resumable(path, read_metadata(path), settings)
    tree, meta = load_tree(path, _train_state_template(model_cfg))
    tree = jax.tree_util.tree_map(jnp.asarray, tree)
    ts = _TrainState(tree["params"], tree["state"], AdamState(*tree["opt"]), tree["best"],
                     jax.random.wrap_key_data(tree["key"]))
    saved = meta["run"]
    # A run that used up its epoch budget continues when given more; an early-stopped run stays stopped.
    run = _Run(**dict(saved, history=tuple(saved["history"]), finished=saved["bad_epochs"] >= train_cfg.patience))
    return ts, run


def _run_epoch(step_fn, ts: _TrainState, run: _Run, train_cfg: TrainConfig, *, progress: bool,
               save=None, every_s: float | None = None):
    """The remaining train steps of epoch `run.epoch` (0-based; all `steps_per_epoch` of them unless `run` was
    saved inside it) with a progress bar. save(ts, run) is called with the run so far whenever `every_s`
    seconds have passed since the epoch began or since the last save (never when `every_s` is None, nor after
    the epoch's last step: the epoch's end is saved by the caller).

    Returns (the new train state, {"loss", "psnr": means over the epoch's steps, "lr": the last step's rate,
    "train_s": the epoch's training time, from its start in an earlier process if resumed inside it}).
    """
    from tqdm.auto import tqdm  # late: only training needs it

    spe = train_cfg.steps_per_epoch
    params, state, opt = ts.params, ts.state, ts.opt
    loss_sum, psnr_sum = run.epoch_loss_sum, run.epoch_psnr_sum
    lr = None
    done = run.step - run.epoch * spe
    t0 = t_saved = time.perf_counter()
    bar = tqdm(total=spe, initial=done, desc=f"epoch {run.epoch + 1}/{train_cfg.epochs}", disable=not progress,
               leave=False)
    for i in range(done, spe):
        step = run.epoch * spe + i
        t_step = time.perf_counter()
        params, state, opt, m = step_fn(params, state, opt, jax.random.fold_in(ts.key, step), step)
        m = {k: float(v) for k, v in jax.device_get(m).items()}
        loss_sum += m["loss"]
        psnr_sum += m["psnr"]
        lr = m["lr"]
        bar.set_postfix(loss=f"{m['loss']:.2e}", psnr=f"{m['psnr']:.2f}", lr=f"{lr:.0e}",
                        ex_s=f"{train_cfg.batch_size / (time.perf_counter() - t_step):.1f}")
        bar.update()
        now = time.perf_counter()
        if save is not None and every_s is not None and i + 1 < spe and now - t_saved >= every_s:
            save(ts._replace(params=params, state=state, opt=opt),
                 dataclasses.replace(run, step=step + 1, epoch_loss_sum=loss_sum, epoch_psnr_sum=psnr_sum,
                                     epoch_train_s=run.epoch_train_s + now - t0))
            t_saved = time.perf_counter()
    bar.close()
    means = {"loss": loss_sum / spe, "psnr": psnr_sum / spe, "lr": lr,
             "train_s": run.epoch_train_s + time.perf_counter() - t0}
    return ts._replace(params=params, state=state, opt=opt), means


def _early_stopping(run: _Run, ts: _TrainState, val_loss: float, train_cfg: TrainConfig) -> tuple[_Run, _TrainState]:
    """After epoch `run.epoch` (1-based, just finished): keep its weights if its validation loss is the lowest
    so far, else count one more bad epoch; the run is finished after `patience` bad epochs in a row or when
    the epoch budget is used up."""
    if val_loss < run.best_loss:
        run = dataclasses.replace(run, best_loss=val_loss, best_epoch=run.epoch - 1, bad_epochs=0)
        ts = ts._replace(best=jax.device_get({"params": ts.params, "state": ts.state}))
    else:
        run = dataclasses.replace(run, bad_epochs=run.bad_epochs + 1)
    finished = run.bad_epochs >= train_cfg.patience or run.epoch >= train_cfg.epochs
    return dataclasses.replace(run, finished=finished), ts


def _training_card(run: _Run, *, train_cfg: TrainConfig, settings: dict, sensor: SensorConfig, validation: dict,
                   bicubic_psnr: float | None, data: str) -> dict:
    """The training card saved with the checkpoints: data, sensor, amount of training, hardware, validation."""
    return {
        "data": data,
        "sensor": jax.tree_util.tree_map(lambda v: v.tolist() if hasattr(v, "tolist") else v, config_to_dict(sensor)),
        "steps": run.step,
        "epochs": run.epoch,
        "examples": run.step * train_cfg.batch_size,
        "best_epoch": run.best_epoch,
        "wall_time_s": run.wall_time_s,
        "hardware": _hardware(),
        "validation": {
            "sequences": list(validation.get("names", [])),
            "frames": int(validation["gt"].shape[0]),
            "loss": run.best_loss,
            "psnr": run.history[run.best_epoch]["val_psnr"] if run.best_epoch >= 0 else None,
            "bicubic_psnr": bicubic_psnr,
        },
        "train_config": settings["train_config"],
        "init": settings.get("init"),
        "seed": train_cfg.seed,
    }


RESUME_FILE = "resume.npz"  # the train state inside an epoch; last.npz keeps the last epoch's end
RUN_FILES = ("metrics.jsonl", "last.npz", "best.npz", RESUME_FILE)  # what `fit` writes into its folder


def _save_state(path: Path, ts: _TrainState, run: _Run, settings: dict, card: dict):
    """Everything a resume needs (params, BN and Adam state, best weights, RNG key, the run), written atomically."""
    tree = {"params": ts.params, "state": ts.state, "opt": ts.opt, "best": ts.best, "key": jax.random.key_data(ts.key)}
    save_tree(path, tree, dict(settings, kind="train_state", run=dataclasses.asdict(run), card=card))


def _write_checkpoints(out: Path, ts: _TrainState, run: _Run, model_cfg: ModelConfig, settings: dict, card: dict):
    """At an epoch's end: `best.npz` (when this epoch is the best), `last.npz` and `metrics.jsonl`, each written
    atomically; then `resume.npz` (inside this epoch) is removed."""
    # best first, then last: a kill between the two resumes from the latest state inside this epoch (or the
    # previous epoch's end) and rewrites both; resume.npz, behind last.npz once it is written, goes last.
    if run.best_epoch == run.epoch - 1:
        save_model(out / "best.npz", Model(ts.best["params"], ts.best["state"], model_cfg), card=card)
    _save_state(out / "last.npz", ts, run, settings, card)
    write_text_atomic(out / "metrics.jsonl", "".join(json.dumps(r) + "\n" for r in run.history))
    (out / RESUME_FILE).unlink(missing_ok=True)


def fit(
    model_cfg: ModelConfig,
    train_cfg: TrainConfig,
    *,
    out,
    make_batch=None,
    validation: dict | None = None,
    sensor: SensorConfig = SensorConfig(),
    resume: bool = False,
    overwrite: bool = False,
    mesh: Mesh | None | str = "auto",
    progress: bool = True,
    callback=None,
    data_description: str | None = None,
    conv3d_impl: str = "auto",
    init=None,
    checkpoint_every_s: float | None = 600.0,
):
    """Train a network; returns (best `Model`, history: list of per-epoch records).

    out: folder for `metrics.jsonl` (one JSON record per epoch), `best.npz` (the best model so far, with its
    training card; `jaxsr.load_model` reads it) and `last.npz` (params, BN state, Adam state, RNG key, step,
    epoch, best-so-far weights and early-stopping counters), all written every epoch; inside an epoch the same
    state goes to `resume.npz` every `checkpoint_every_s` seconds of training (None: never), so that a killed
    run loses at most that much (removed at the epoch's end). `resume=True` continues from the later of the two
    (a folder with neither starts afresh) and gives the same result as an uninterrupted run (bit-identical on
    the same machine). A folder that already holds a run (any of `RUN_FILES`) is refused (FileExistsError)
    unless `resume` or `overwrite` (start a new run in its place: the old run's files are removed when the new
    one first saves its state) is given.
    make_batch: the data source (default `jaxsr.training.data.scene_batches`); validation: a dict from
    `jaxsr.training.data.validation_set` (default: built from `jaxsr.scenes.test_sequences`). mesh: "auto" (all
    devices when there are more than one), None (no sharding) or a `Mesh` with a "data" axis. callback(record)
    is called after each epoch's checkpoint is written. conv3d_impl: how the network's convolutions run (see
    `apply_model`; not saved, a run may resume with another). Everything random follows `train_cfg.seed`.
    The network trains in `model_cfg.temporal`'s form: windows, or clips of `train_cfg.clip_length(model_cfg)`
    frames (default data `scene_clips`; validation on whole edge-padded sequences, `evaluate_sequences`).
    init: start from these weights instead of random ones (a `Model` or a checkpoint path, the same
    architecture in either temporal form: e.g. a windowed model fine-tuned into the sequence form; or a smaller
    TR, grown to this one by `jaxsr.nn.grow_tr`: a warm start from its function); recorded in the training card,
    ignored when resuming.
    """
    if model_cfg.scale != sensor.scale:
        raise ValueError(f"fit: model scale {model_cfg.scale} differs from sensor scale {sensor.scale}")
    out = Path(out)
    held = [name for name in RUN_FILES if (out / name).exists()]
    if resume and overwrite:
        raise ValueError("fit: resume and overwrite exclude each other (continue the run, or start over)")
    if held and not (resume or overwrite):
        raise FileExistsError(f"{out} holds a training run ({', '.join(held)}); pass resume=True (--resume) to "
                              "continue it or overwrite=True (--force) to start a new one in its place")
    if not (checkpoint_every_s is None or checkpoint_every_s >= 0):  # also refuses NaN
        raise ValueError(f"fit: checkpoint_every_s={checkpoint_every_s!r}; expected seconds >= 0, or None")
    out.mkdir(parents=True, exist_ok=True)
    mesh = choose_mesh(mesh, train_cfg.batch_size)
    k_init, k_data, k_val = run_keys(train_cfg.seed)
    if make_batch is None:
        make_batch = default_data(model_cfg, train_cfg, sensor)
    if data_description is None:
        data_description = getattr(make_batch, "description", "user-supplied make_batch")
    if validation is None:
        validation = validation_set(k_val, model_cfg.tr, train_cfg, sensor=sensor)
    val_bicubic = _bicubic_psnr(validation, model_cfg.scale)
    settings = _settings(model_cfg, train_cfg)
    if init is not None:
        settings["init"] = str(init) if not isinstance(init, Model) else "a Model passed to fit"
    ts, run = _start_or_resume(out, model_cfg, train_cfg, settings, k_init=k_init, k_data=k_data,
                               resume=resume, init=init)
    step_fn = make_train_step(model_cfg, train_cfg, make_batch, mesh=mesh, conv3d_impl=conv3d_impl)
    params, state, opt = replicate((ts.params, ts.state, ts.opt), mesh)
    ts = ts._replace(params=params, state=state, opt=opt)

    def card_of(run: _Run) -> dict:
        return _training_card(run, train_cfg=train_cfg, settings=settings, sensor=sensor, validation=validation,
                              bicubic_psnr=val_bicubic, data=data_description)

    old_run = held if overwrite else []  # the replaced run's files, removed before the new run's first save

    def forget_old_run():
        for name in old_run:
            (out / name).unlink(missing_ok=True)
        old_run.clear()

    def save_inside_epoch(ts: _TrainState, run: _Run):
        forget_old_run()
        # the card counts the steps and time so far; the run keeps the epoch's time apart until the epoch ends
        _save_state(out / RESUME_FILE, ts, run, settings,
                    card_of(dataclasses.replace(run, wall_time_s=run.wall_time_s + run.epoch_train_s)))

    spe = train_cfg.steps_per_epoch
    while not run.finished and run.epoch < train_cfg.epochs:
        t0, before = time.perf_counter(), run.epoch_train_s  # before: training time in an earlier process
        ts, train = _run_epoch(step_fn, ts, run, train_cfg, progress=progress, save=save_inside_epoch,
                               every_s=checkpoint_every_s)
        val = _validate(ts, validation, model_cfg, train_cfg, conv3d_impl)
        run = dataclasses.replace(run, epoch=run.epoch + 1, step=(run.epoch + 1) * spe, epoch_loss_sum=0.0,
                                  epoch_psnr_sum=0.0, epoch_train_s=0.0)
        record = {
            "epoch": run.epoch, "step": run.step, "lr": train["lr"],
            "train_loss": train["loss"], "train_psnr": train["psnr"],
            "val_loss": val["loss"], "val_psnr": val["psnr"], "val_bicubic_psnr": val_bicubic,
            "examples_per_s": spe * train_cfg.batch_size / train["train_s"],
            "epoch_time_s": before + time.perf_counter() - t0,
        }
        run, ts = _early_stopping(run, ts, val["loss"], train_cfg)
        record["wall_time_s"] = run.wall_time_s + record["epoch_time_s"]
        run = dataclasses.replace(run, wall_time_s=record["wall_time_s"], history=(*run.history, record))
        if progress:
            print(json.dumps(record))
        forget_old_run()
        _write_checkpoints(out, ts, run, model_cfg, settings, card_of(run))
        if callback is not None:
            callback(record)
    best = jax.tree_util.tree_map(jnp.asarray, ts.best)
    return Model(best["params"], best["state"], model_cfg), list(run.history)
