"""`fit`: one training loop for every network (the DUF network in either form, HistNet, iSeeBetter's GAN).

`fit` runs epochs of `TrainConfig.steps_per_epoch` jitted steps of the architecture's recipe
(`jaxsr.training.recipes`: the data are drawn inside each step), validates after each epoch, logs to
`metrics.jsonl`, writes `best.npz` (a `Model`, `jaxsr.load_model` reads it) and `last.npz` (everything needed to
resume) after every epoch, `resume.npz` (the same, inside an epoch) every `checkpoint_every_s` seconds of
training, and stops early after `patience` epochs without a lower validation loss. A resumed run gives the
same result as an uninterrupted one. Data parallelism (the DUF network): a `jax.sharding.Mesh` with a "data" axis
(default: all devices) splits each batch, also across processes and hosts (`jaxsr.runtime.init_distributed`): every
process runs the same steps on its share of the global batch, and process 0 alone reads and writes the run folder.
Stacked runs (`fit(seeds=[...])`): several seeds of one network, each in its own run folder, their train states
stacked along a leading axis and updated by one jitted step, the recipe's vmapped over the seeds.
"""

from __future__ import annotations

import builtins
import contextlib
import dataclasses
import json
import math
import numbers
import platform
import time
import warnings
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from ..baselines.interpolation import bicubic
from ..config import SensorConfig, TrainConfig
from ..eval.metrics import psnr
from ..io.checkpoint import (config_from_dict, config_to_dict, load_tree, read_metadata, resolve_model_path, save_model,
                             save_tree)
from ..io.files import folder_lock, write_text_atomic
from ..nn.model import Model, architecture
from .data import run_keys
from .duf import data_mesh
from .recipes import recipe

__all__ = [
    "choose_mesh",
    "replicate",
    "fit",
    "resume_config",
    "seed_folder",
    "RUN_FILES",
    "RESUME_FILE",
]


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
    """The arrays of a run: `train`, what the recipe's step updates ({"params", "state", "opt"} and, for a GAN,
    the discriminator's "disc", "disc_state", "disc_opt"), `best`, the best epoch's {"params", "state"} (on the
    host), and the data `key` (step s draws its batch with fold_in(key, s)). `last.npz` holds them side by side
    (the key as raw key data)."""

    train: dict
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
    epoch_sums: dict = dataclasses.field(default_factory=dict)  # sums of the step's other metrics (a GAN's losses)
    best_loss: float = math.inf
    best_epoch: int = -1
    bad_epochs: int = 0
    wall_time_s: float = 0.0
    finished: bool = False
    history: tuple = ()


def _train_state_template(model_cfg, k_init) -> dict:
    """Shapes of everything `last.npz` holds for `model_cfg`, computing nothing."""
    train = jax.eval_shape(lambda k: recipe(model_cfg).init(k, model_cfg, None), k_init)
    best = {"params": train["params"], "state": train["state"]}
    return {**train, "best": best, "key": jax.eval_shape(lambda: jax.random.key_data(jax.random.key(0)))}


def choose_mesh(mesh, batch_size: int) -> Mesh | None:
    """`fit`'s mesh argument resolved: "auto" shards over all devices when there are several that divide the
    batch evenly.

    Across processes (`jax.process_count()` > 1) the batch is the global one, and it must be split: the mesh
    ("auto", or a `Mesh`) must hold every process's devices and `batch_size` must be a multiple of their number,
    else ValueError (so must it be for mesh=None, which would have every process do the whole batch)."""
    n, processes = jax.device_count(), jax.process_count()
    if processes > 1:
        if not (mesh == "auto" or (isinstance(mesh, Mesh) and mesh.devices.size == n)):
            raise ValueError(f"fit: across {processes} processes the batch is split over a mesh of all {n} devices; "
                             f"got mesh={mesh!r} (pass 'auto')")
        if batch_size % n:
            raise ValueError(f"fit: the global batch of {batch_size} (TrainConfig.batch_size) does not split evenly "
                             f"over the {n} devices of {processes} processes; choose a multiple of {n}")
        return data_mesh() if mesh == "auto" else mesh
    if mesh != "auto":
        return mesh
    return data_mesh() if n > 1 and batch_size % n == 0 else None


def replicate(tree, mesh: Mesh | None):
    """`tree` with a copy on every device of `mesh`, as a sharded train step expects its carry (params, state,
    Adam state: the step shards only the batch), so that its first calls do not compile again for another
    placement; unchanged when `mesh` is None."""
    return tree if mesh is None else jax.device_put(tree, NamedSharding(mesh, P()))


def _lead() -> bool:
    """Whether this process reads and writes the run folder: process 0 of a run across processes, or the only one."""
    return jax.process_index() == 0


def _share(value):
    """Process 0's `value` (JSON-serialisable) on every process; `value` itself with one process. Sent as the bytes
    of its JSON text (padded to a power of two, so that few lengths compile), so that floats arrive exactly."""
    if jax.process_count() == 1:
        return value
    from jax.experimental import multihost_utils  # late: only runs across processes need it

    text = json.dumps(value).encode() if _lead() else b""
    size = int(multihost_utils.broadcast_one_to_all(np.int32(len(text))))
    buffer = np.full(max(256, 1 << (size - 1).bit_length()), ord(" "), np.uint8)
    buffer[: len(text)] = np.frombuffer(text, np.uint8)
    return json.loads(np.asarray(multihost_utils.broadcast_one_to_all(buffer), np.uint8).tobytes().decode())


def _on_lead(fn):
    """fn() run by process 0 alone (it reads and writes the run folder), its JSON-serialisable result on every
    process; an exception it raises is raised on every process, of the same built-in type with the same message
    (RuntimeError naming it for others), so that no process waits for one that failed. fn() itself with one process."""
    if jax.process_count() == 1:
        return fn()
    error = None
    if _lead():
        try:
            outcome = {"value": fn()}
        except Exception as e:  # noqa: BLE001 - every process must learn of it; re-raised below
            error, outcome = e, {"error": type(e).__name__, "message": str(e)}
    else:
        outcome = None
    outcome = _share(outcome)
    if error is not None:
        raise error
    if "error" in outcome:
        kind = getattr(builtins, outcome["error"], None)
        if isinstance(kind, type) and issubclass(kind, Exception):
            raise kind(outcome["message"])
        raise RuntimeError(f"process 0: {outcome['error']}: {outcome['message']}")
    return outcome["value"]


def _bicubic_psnr(validation: dict, scale: int) -> float | None:
    """Mean PSNR (dB) of bicubic upsampling of the validation set's centre frames (None without "lr"): the
    baseline every epoch's validation PSNR is logged beside."""
    if "lr" not in validation:
        return None
    lr = validation["lr"]
    depth = lr[..., 0] if lr.ndim == validation["gt"].ndim + 1 else lr  # a photon model's channels: depth first
    return float(jnp.mean(psnr(bicubic(depth, scale=scale), validation["gt"])))


def _settings(model_cfg, train_cfg: TrainConfig, pretrain_epochs: int) -> dict:
    """{"architecture", "config", "train_config"} (and "pretrain_epochs" when used) as a checkpoint's metadata
    holds them."""
    # JSON round trip: tuples become lists, as they are when read back from a checkpoint
    settings = {"architecture": architecture(model_cfg).name, "config": config_to_dict(model_cfg),
                "train_config": config_to_dict(train_cfg)}
    if pretrain_epochs:
        settings["pretrain_epochs"] = pretrain_epochs
    return json.loads(json.dumps(settings))


def _check_resumable(path: Path, meta: dict, settings: dict):
    """Raise ValueError naming every setting in which the run saved at `path` differs from `settings`.

    Everything must match except `epochs`: extending a finished run is a resume, not a new run (the schedule
    depends on decay_epochs and patience, not on the epoch budget). Fields older versions kept in the model
    config (`checkpoint.LEGACY_FIELDS`) are ignored, fields they lacked take their defaults.
    """
    def flat(arch, model, train, pretrain):
        return dict(model, architecture=arch, pretrain_epochs=pretrain,
                    **{f"train.{k}": v for k, v in train.items() if k != "epochs"})

    if meta.get("kind") != "train_state":
        raise ValueError(f"fit: cannot resume {str(path)!r}: it holds no training state of `fit` (kind "
                         f"{meta.get('kind')!r}; a learned baseline's run of jaxsr 0.1 resumes with that version)")
    arch = architecture(meta.get("architecture", "duf"))
    # through JSON as `settings` went (tuples become lists), with the fields older files lack at their defaults
    saved_cfg = json.loads(json.dumps(config_to_dict(config_from_dict(arch.config_type, meta["config"]))))
    saved_train = json.loads(json.dumps(config_to_dict(config_from_dict(TrainConfig, meta["train_config"]))))
    saved = flat(arch.name, saved_cfg, saved_train, meta.get("pretrain_epochs", 0))
    wanted = flat(settings["architecture"], settings["config"], settings["train_config"],
                  settings.get("pretrain_epochs", 0))
    differ = sorted(k for k in saved.keys() | wanted.keys() if saved.get(k) != wanted.get(k))
    if differ:
        before, now = meta.get("processes", 1), jax.process_count()
        across = (f"; a run begun on {before} process(es) continues on {now} only with the same global batch "
                  "(TrainConfig.batch_size, split over all devices)" if "train.batch_size" in differ and before != now
                  else "")
        raise ValueError(
            f"fit: cannot resume {str(path)!r}: it was trained with other settings: "
            + ", ".join(f"{k} {saved.get(k)!r} (now {wanted.get(k)!r})" for k in differ) + across
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


def _latest_state(out: Path) -> Path | None:
    """The train state to resume the run in folder `out` from: `resume.npz` (inside an epoch) when it is ahead of
    `last.npz` (an epoch's end; ahead of it when a kill fell between writing it and removing resume.npz), None
    when neither exists."""
    saved = [p for p in (out / "last.npz", out / RESUME_FILE) if p.is_file()]
    return max(saved, key=lambda p: read_metadata(p).get("run", {}).get("step", 0), default=None)


def _start_or_resume(out: Path, model_cfg, train_cfg: TrainConfig, settings: dict, *, k_init, k_data,
                     resume: bool, init=None) -> tuple[_TrainState, _Run]:
    """The run saved in folder `out` (`_latest_state`) when resuming one, else a fresh one (weights from `init` or
    drawn with `k_init`, data from `k_data`)."""
    path = _latest_state(out) if resume else None
    if path is None:
        train = recipe(model_cfg).init(k_init, model_cfg, init)
        best = jax.device_get({"params": train["params"], "state": train["state"]})
        return _TrainState(train, best, k_data), _Run()
    meta = read_metadata(path)
    _check_resumable(path, meta, settings)
    before, now = meta.get("processes", 1), jax.process_count()
    if before != now:  # the global batch is the same (_check_resumable): so is each step's update, up to rounding
        warnings.warn(f"resuming {str(path)!r}, begun on {before} process(es), on {now}: the global batch of "
                      f"{train_cfg.batch_size} is unchanged, so each step computes the same update, split over "
                      f"{jax.device_count()} devices; the run goes on as it would have, up to float rounding (not bit "
                      "for bit)", stacklevel=4)
    tree, meta = load_tree(path, _train_state_template(model_cfg, k_init))
    tree = jax.tree_util.tree_map(jnp.asarray, tree)
    best, key = tree.pop("best"), jax.random.wrap_key_data(tree.pop("key"))
    saved = meta["run"]
    # A run that used up its epoch budget continues when given more; an early-stopped run stays stopped.
    run = _Run(**dict(saved, history=tuple(saved["history"]), finished=saved["bad_epochs"] >= train_cfg.patience))
    return _TrainState(tree, best, key), run


def _start_across_processes(out: Path, model_cfg, train_cfg: TrainConfig, settings: dict, *, k_init, k_data,
                            resume: bool, init=None) -> tuple[_TrainState, _Run]:
    """`_start_or_resume` run by process 0 (the only one that reads the run folder, or `init`'s checkpoint), its
    train state and run sent to every process (`multihost_utils.broadcast_one_to_all`, exact)."""
    from jax.experimental import multihost_utils  # late: only runs across processes need it

    started = []

    def start():
        ts, run = _start_or_resume(out, model_cfg, train_cfg, settings, k_init=k_init, k_data=k_data, resume=resume,
                                   init=init)
        started.append(ts)
        return dataclasses.asdict(run)

    saved = _on_lead(start)
    run = _Run(**dict(saved, history=tuple(saved["history"])))
    if started:
        ts = started[0]
        tree = {**ts.train, "best": ts.best, "key": jax.random.key_data(ts.key)}
    else:  # zeros of the same shapes: broadcast_one_to_all adds them to process 0's arrays
        tree = jax.tree_util.tree_map(lambda a: np.zeros(a.shape, a.dtype), _train_state_template(model_cfg, k_init))
    tree = jax.device_get(multihost_utils.broadcast_one_to_all(tree))
    best, key = tree.pop("best"), jax.random.wrap_key_data(jnp.asarray(tree.pop("key")))
    return _TrainState(jax.tree_util.tree_map(jnp.asarray, tree), best, key), run


def _stack(trees: list):
    """Pytrees of one structure stacked along a new leading axis, one entry per run."""
    return jax.tree_util.tree_map(lambda *leaves: jnp.stack(leaves), *trees)


def _unstack(tree, i: int):
    """Entry `i` of a pytree stacked by `_stack`."""
    return jax.tree_util.tree_map(lambda leaf: leaf[i], tree)


def _advance(step_fn, keys: list, *, stacked: bool):
    """advance(train, step, active) -> (train, metrics): train step `step` of every run, each drawing its data
    with fold_in(its key, step), as one run alone does.

    One run (`keys` of one, not `stacked`): the recipe's `step_fn` on its train state (`active` unused). Stacked:
    one jitted step, `step_fn` vmapped over the runs' train states stacked along a leading axis (`_stack`),
    each metric one value per run; a run whose entry of `active` (bools, one per run) is False keeps its state
    (its update is computed and dropped: a run that stopped early, or waits for the others to catch up)."""
    if not stacked:
        (key,) = keys
        return lambda train, step, active: step_fn(train, jax.random.fold_in(key, step), step)

    def one_step(train, keys, step, active):
        draws = jax.vmap(jax.random.fold_in, in_axes=(0, None))(keys, step)
        new, metrics = jax.vmap(step_fn, in_axes=(0, 0, None))(train, draws, step)
        keep = lambda n, o: jnp.where(active.reshape(active.shape + (1,) * (n.ndim - 1)), n, o)  # noqa: E731
        return jax.tree_util.tree_map(keep, new, train), metrics

    jitted = jax.jit(one_step, donate_argnums=(0,) if jax.default_backend() != "cpu" else ())
    stacked_keys = jnp.stack(keys)
    return lambda train, step, active: jitted(train, stacked_keys, step, jnp.asarray(active))


def _next_group(runs: list, epochs: int) -> list:
    """The runs that train next: the unfinished ones (neither stopped early nor at `epochs`) at the lowest epoch,
    so that a run resumed behind the others trains alone until it has caught up; [] when every run is done."""
    left = [i for i, run in enumerate(runs) if not run.finished and run.epoch < epochs]
    first = min((runs[i].epoch for i in left), default=None)
    return [i for i in left if runs[i].epoch == first]


def _run_epoch(advance, train, runs: list, group: list, train_cfg: TrainConfig, *, progress: bool, save=None,
               every_s: float | None = None):
    """The remaining train steps of one epoch of the runs `group` (indices into `runs`, all in the same 0-based
    epoch: all `steps_per_epoch` steps of it for a run not saved inside it) with a progress bar, one
    advance(train, step, active) (`_advance`) per step: a run trains from its own step on (one resumed further
    into the epoch waits for the others to reach it), the runs outside `group` not at all. save(i, train, run)
    is called for each run `i` that has trained, with its run so far, whenever `every_s` seconds have passed
    since the epoch began or since the last save (never when `every_s` is None, nor after the epoch's last step:
    the epoch's end is saved by the caller).

    Returns (the new train state, {i: {"loss", "psnr": means over the epoch's steps, "lr": the last step's rate,
    "other": means of the step's other metrics, "train_s": the epoch's training time, from its start in an
    earlier process if resumed inside it}} for each i of `group`). The loss is the step's "loss", or a GAN
    generator's "g_loss".
    """
    from tqdm.auto import tqdm  # late: only training needs it

    spe, epoch = train_cfg.steps_per_epoch, runs[group[0]].epoch
    start = {i: runs[i].step - epoch * spe for i in group}
    loss_sum = {i: runs[i].epoch_loss_sum for i in group}
    psnr_sum = {i: runs[i].epoch_psnr_sum for i in group}
    sums = {i: dict(runs[i].epoch_sums) for i in group}
    lr, began, last_loss = {}, {}, {}
    active = np.zeros(len(runs), bool)
    first = min(start.values())
    t_saved = time.perf_counter()
    bar = tqdm(total=spe, initial=first, desc=f"epoch {epoch + 1}/{train_cfg.epochs}", disable=not progress,
               leave=False)
    for j in range(first, spe):
        step = epoch * spe + j
        t_step = time.perf_counter()
        for i in group:
            active[i] = start[i] <= j
            if active[i]:
                began.setdefault(i, t_step)
        train, m = advance(train, step, active)
        m = jax.device_get(m)
        trained = [i for i in group if active[i]]
        for i in trained:
            values = {k: float(np.ravel(v)[i]) for k, v in m.items()}  # one value per run when stacked
            last_loss[i] = values.pop("loss") if "loss" in values else values.pop("g_loss")  # a GAN: the generator's
            loss_sum[i] += last_loss[i]
            psnr_sum[i] += values.pop("psnr")
            lr[i] = values.pop("lr")
            for k, v in values.items():
                sums[i][k] = sums[i].get(k, 0.0) + v
        bar.set_postfix(loss=f"{np.mean([last_loss[i] for i in trained]):.2e}",
                        psnr=f"{np.mean([psnr_sum[i] for i in trained]) / (j + 1):.2f}", lr=f"{lr[trained[0]]:.0e}",
                        ex_s=f"{train_cfg.batch_size * len(trained) / (time.perf_counter() - t_step):.1f}")
        bar.update()
        now = time.perf_counter()
        if save is not None and every_s is not None and j + 1 < spe and now - t_saved >= every_s:
            for i in trained:
                save(i, train, dataclasses.replace(runs[i], step=step + 1, epoch_loss_sum=loss_sum[i],
                                                   epoch_psnr_sum=psnr_sum[i], epoch_sums=dict(sums[i]),
                                                   epoch_train_s=runs[i].epoch_train_s + now - began[i]))
            t_saved = time.perf_counter()
    bar.close()
    end = time.perf_counter()
    means = {i: {"loss": loss_sum[i] / spe, "psnr": psnr_sum[i] / spe, "lr": lr[i],
                 "other": {k: v / spe for k, v in sums[i].items()}, "train_s": runs[i].epoch_train_s + end - began[i]}
             for i in group}
    return train, means


def _early_stopping(run: _Run, ts: _TrainState, val_loss: float, train_cfg: TrainConfig) -> tuple[_Run, _TrainState]:
    """After epoch `run.epoch` (1-based, just finished): keep its weights if its validation loss is the lowest
    so far, else count one more bad epoch; the run is finished after `patience` bad epochs in a row or when
    the epoch budget is used up."""
    if val_loss < run.best_loss:
        run = dataclasses.replace(run, best_loss=val_loss, best_epoch=run.epoch - 1, bad_epochs=0)
        ts = ts._replace(best=jax.device_get({"params": ts.train["params"], "state": ts.train["state"]}))
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
        "date": time.strftime("%Y-%m-%d", time.gmtime()),
    }


_LINEAGE_KEYS = ("earlier_stages", "total_steps", "total_examples")


def _count(x) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x) and x >= 0


def _lineage_after(card) -> dict:
    """The lineage of a run that starts from the weights `card` describes: the card's stages (oldest first) with the
    card itself last, and the steps and examples of them all. {} where the card has no such shape (a card is
    metadata: `save_model` takes any JSON), so that a lineage never stops a run."""
    if not isinstance(card, dict) or not card:
        return {}
    earlier = card.get("earlier_stages", [])
    steps, examples = (card.get(f"total_{k}", card.get(k, 0)) for k in ("steps", "examples"))
    if not (isinstance(earlier, list) and all(isinstance(e, dict) for e in earlier) and _count(steps)
            and _count(examples)):
        return {}
    return {"earlier_stages": [*earlier, {k: v for k, v in card.items() if k not in _LINEAGE_KEYS}],
            "total_steps": steps, "total_examples": examples}


def _run_lineage(out: Path, init, resume: bool) -> dict:
    """The training behind a run's starting weights, for its card: when resuming, what its saved card recorded
    (the starting checkpoint may have moved or been replaced since); else that of `init` (a checkpoint's name or
    path; a Model carries none), {} where it has none or cannot be read."""
    path = _latest_state(out) if resume else None
    if path is not None:
        card = read_metadata(path).get("card")
        if not isinstance(card, dict) or "earlier_stages" not in card:
            return {}  # a run begun without a lineage keeps none
        saved = {k: card.get(k) for k in _LINEAGE_KEYS}
        steps, examples = saved["total_steps"], saved["total_examples"]
        if not (_count(steps) and _count(examples) and _count(card.get("steps")) and _count(card.get("examples"))):
            return {}
        return {"earlier_stages": saved["earlier_stages"], "total_steps": steps - card["steps"],
                "total_examples": examples - card["examples"]}
    if init is None or isinstance(init, Model):
        return {}
    try:
        card = read_metadata(resolve_model_path(init)).get("card")
    except (OSError, ValueError, KeyError):  # unreadable: the run starts as before, its card without a lineage
        return {}
    return _lineage_after(card)


RESUME_FILE = "resume.npz"  # the train state inside an epoch; last.npz keeps the last epoch's end
RUN_FILES = ("metrics.jsonl", "last.npz", "best.npz", RESUME_FILE)  # what `fit` writes into its folder


def _save_state(path: Path, ts: _TrainState, run: _Run, settings: dict, card: dict):
    """Everything a resume needs (the train state, best weights, RNG key, the run), written atomically."""
    tree = {**ts.train, "best": ts.best, "key": jax.random.key_data(ts.key)}
    save_tree(path, tree, dict(settings, kind="train_state", run=dataclasses.asdict(run), card=card,
                               processes=jax.process_count()))


def _write_checkpoints(out: Path, ts: _TrainState, run: _Run, model_cfg, settings: dict, card: dict):
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
    model_cfg,
    train_cfg: TrainConfig,
    *,
    out,
    seeds=None,
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
    pretrain_epochs: int = 0,
    card_extra: dict | None = None,
):
    """Train a network of any registered architecture; returns (best `Model`, history: list of per-epoch records),
    or with `seeds` a dict {seed: (best `Model`, history)}.

    model_cfg: the network to train, by its config: `ModelConfig` (the DUF network, in the form its `temporal`
    says: windows, or clips of `train_cfg.clip_length(model_cfg)` frames validated on whole sequences),
    `jaxsr.baselines.HistNetConfig` or `jaxsr.baselines.RBPNConfig` (iSeeBetter: a generator and a discriminator,
    each with its own Adam, updated in the same step; `pretrain_epochs` epochs of the generator alone on its
    content loss first). What differs between networks is their recipe (`jaxsr.training.recipes`); the loop,
    its files and its rules are the same for all.
    out: folder for `metrics.jsonl` (one JSON record per epoch), `best.npz` (the best model so far, with its
    training card; `jaxsr.load_model` reads it) and `last.npz` (the train state: weights, BN and Adam state, a
    GAN's discriminator, RNG key, step, epoch, best-so-far weights and early-stopping counters), all written every
    epoch; inside an epoch the same state goes to `resume.npz` every `checkpoint_every_s` seconds of training
    (None: never), so that a killed run loses at most that much (removed at the epoch's end). `resume=True`
    continues from the later of the two (a folder with no run files starts afresh; one holding run files but
    neither, e.g. best.npz and metrics.jsonl alone, is refused: FileExistsError) and gives the same result as an
    uninterrupted run (bit-identical on the same machine); it is refused if any setting but `epochs` differs, and
    warns (nothing to train) when the run already has `epochs` epochs or stopped early. A folder that already
    holds a run (any of `RUN_FILES`) is refused (FileExistsError) unless `resume` or `overwrite` (start a new run
    in its place: the old run's files are removed when the new one first saves its state) is given. The run
    holds a lock on `out` (`out/.lock`, removed at the end): a second `fit` on the same folder meanwhile fails at
    once (FileExistsError).
    seeds: a stacked run, several seeds of this network trained at once (a list of distinct integers 0..2^32-1,
    e.g. [0, 1, 2]; None: one run of `train_cfg.seed`). Seed k trains as the run of `train_cfg` with seed=k
    alone would (its initial weights, data, validation set; equal up to float rounding), in its own folder
    `out/seed<k>`, a run folder as above: its files, card, lock, resume and early stopping are its own, and
    every rule above applies to each (a run that stops early keeps its state while the others train on; the
    stacked run ends when every seed's has). Their train states are stacked along a leading axis and updated
    by one jitted step, the recipe's vmapped over the seeds, so that small networks keep a GPU busy (on CPU it is
    slower than the runs one after another: a warning says so; a single seed trains unstacked, in its folder).
    A seed's folder may be resumed alone and a single run's folder in a stack; seeds resumed at different
    epochs train alone until they catch up. Not across processes, nor with `pretrain_epochs` (ValueError);
    `out` itself must not hold a run (FileExistsError).
    make_batch: the data source (default: the recipe's, rendered scenes in the network's input form);
    validation: a dict as the recipe's validation set gives (default: built from `jaxsr.scenes.test_sequences`,
    each seed's with its own noise).
    mesh: "auto" (all devices when there are more than one), None (no sharding) or a `Mesh` with a "data" axis
    (the DUF network; HistNet and iSeeBetter train on one device).
    callback(record) is called after each epoch's checkpoint is written (with `seeds`, for each seed's, the
    record's "seed" saying which). conv3d_impl: how the DUF network's
    convolutions run (see `jaxsr.apply_model`; not saved, a run may resume with another). Everything random
    follows `train_cfg.seed`. init (DUF): start from these weights instead of random ones (a `Model` or a
    checkpoint path, the same architecture in either temporal form, or a smaller TR grown to this one by
    `jaxsr.nn.grow_tr`); recorded in the training card with the training behind it (a checkpoint's card: its
    stages under "earlier_stages", oldest first, and "total_steps" and "total_examples" with this run's),
    ignored when resuming. card_extra: entries added to
    the training card.

    Across processes and hosts (a data-parallel recipe: the DUF network), after `jaxsr.runtime.init_distributed`
    in every process: each process calls `fit` with the same arguments and runs the same steps;
    `train_cfg.batch_size` is the global batch, split over the devices of all processes (it must be a multiple of
    their number: ValueError), the mesh ("auto") spans them all. Process 0 alone reads and writes `out` (the lock,
    `metrics.jsonl`, the checkpoints with their card, progress output); the others touch nothing there and
    receive what process 0 read (a resumed state, its errors: raised on every process). Each process validates on
    its own copy of the replicated weights; the record of process 0 is every process's, so that all stop together
    and return the same model and history; `callback` runs on every process. The run's state records its number
    of processes: a resume on another number is allowed when the global batch is the same (it is a setting: it
    must be), and warns that it continues equal up to float rounding, no longer bit for bit.
    """
    arch = architecture(model_cfg)  # ValueError for a config of no registered architecture
    recipe(model_cfg)  # ValueError for an architecture without a recipe
    if arch.scale(model_cfg) != sensor.scale:
        raise ValueError(f"fit: model scale {arch.scale(model_cfg)} differs from sensor scale {sensor.scale}")
    if not (isinstance(pretrain_epochs, int) and pretrain_epochs >= 0):
        raise ValueError(f"fit: pretrain_epochs must be an int >= 0, got {pretrain_epochs!r}")
    out = Path(out)
    if resume and overwrite:
        raise ValueError("fit: resume and overwrite exclude each other (continue the run, or start over)")
    if not (checkpoint_every_s is None or checkpoint_every_s >= 0):  # also refuses NaN
        raise ValueError(f"fit: checkpoint_every_s={checkpoint_every_s!r}; expected seconds >= 0, or None")
    seeds = _check_seeds(seeds)
    if seeds is not None and (pretrain_epochs or jax.process_count() > 1):
        raise ValueError("fit: a stacked run (seeds) trains in one process and without pretrain_epochs; train "
                         + ("one seed per run across processes" if pretrain_epochs == 0 else "each seed alone"))
    folders = [out] if seeds is None else [seed_folder(out, s) for s in seeds]
    cfgs = [train_cfg] if seeds is None else [dataclasses.replace(train_cfg, seed=s) for s in seeds]
    with contextlib.ExitStack() as lock:

        def open_folders():  # on process 0 alone across processes: the others never touch the folders
            if seeds is not None:
                _check_stack_folder(out)
            for folder in folders:
                if folder.exists() and not folder.is_dir():
                    raise FileExistsError(f"{folder} is a file; fit's out is a folder")
                folder.mkdir(parents=True, exist_ok=True)
                lock.enter_context(folder_lock(folder, what="training run"))  # a second run on it fails at once

        _on_lead(open_folders)
        fitted = _fit_in(folders, model_cfg, cfgs, by_seed=seeds is not None, make_batch=make_batch,
                         validation=validation, sensor=sensor, resume=resume, overwrite=overwrite, mesh=mesh,
                         progress=progress, callback=callback,
                         data_description=data_description, conv3d_impl=conv3d_impl, init=init,
                         checkpoint_every_s=checkpoint_every_s, pretrain_epochs=pretrain_epochs,
                         card_extra=card_extra)
    return fitted[0] if seeds is None else dict(zip(seeds, fitted))


def _check_seeds(seeds) -> tuple | None:
    """The seeds of a stacked run (`fit(seeds=...)`) checked: None stays None, else a tuple of at least one
    distinct integer 0..2^32-1 (ValueError naming what is wrong)."""
    if seeds is None:
        return None
    if isinstance(seeds, (str, bytes)) or not hasattr(seeds, "__iter__"):
        raise ValueError(f"fit: seeds must be a list of integers, got {seeds!r}")
    seeds = tuple(seeds)
    bad = [s for s in seeds if isinstance(s, bool) or not isinstance(s, numbers.Integral) or not 0 <= s < 2**32]
    if bad or not seeds:
        raise ValueError(f"fit: seeds must be integers 0..2^32-1, at least one, got {list(seeds)!r}")
    twice = sorted({int(s) for s in seeds if seeds.count(s) > 1})
    if twice:
        raise ValueError(f"fit: seeds must differ, got {', '.join(map(str, twice))} more than once")
    return tuple(int(s) for s in seeds)


def seed_folder(out, seed: int) -> Path:
    """The run folder of seed `seed` of a stacked run in `out`: `out/seed<seed>`."""
    return Path(out) / f"seed{seed}"


def _check_stack_folder(out: Path):
    """A stacked run's folder `out` (its seeds' run folders go inside) is not a file, nor a run folder itself."""
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"{out} is a file; fit's out is a folder")
    held = [name for name in RUN_FILES if (out / name).exists()]
    if held:
        raise FileExistsError(f"{out} holds a training run ({', '.join(held)}); a stacked run trains each seed in "
                              "a folder inside out (seed<k>), not next to a run: choose another out")


def _first_epoch_kill(out: Path, held: list) -> bool:
    """Whether the run files `held` in `out`, with no train state, are what a kill inside the first epoch's save
    leaves (best.npz of epoch 1 alone: last.npz and metrics.jsonl come after it): a resume starts that run afresh."""
    if held != ["best.npz"]:
        return False
    try:
        return read_metadata(out / "best.npz").get("card", {}).get("epochs") == 1
    except ValueError:
        return False


def _held_run_files(out: Path, *, resume: bool, overwrite: bool) -> list:
    """The run files (`RUN_FILES`) folder `out` holds, checked against what `fit` was asked to do with them:
    FileExistsError for a run neither resumed nor overwritten, or one to resume without its train state."""
    held = [name for name in RUN_FILES if (out / name).exists()]
    if held and not (resume or overwrite):
        raise FileExistsError(f"{out} holds a training run ({', '.join(held)}); pass resume=True (--resume) to "
                              "continue it or overwrite=True (--force) to start a new one in its place")
    if resume and held and _latest_state(out) is None and not _first_epoch_kill(out, held):
        raise FileExistsError(f"{out} holds a run without its train state ({', '.join(held)}; no last.npz or "
                              f"{RESUME_FILE}), so it cannot be resumed; overwrite=True (--force) starts over in "
                              "its place")
    return held


class _Seat(NamedTuple):
    """What one run of a `fit` keeps from start to end: its folder, config (its seed), settings as its
    checkpoints record them, validation set with its bicubic PSNR, and data key."""

    out: Path
    train_cfg: TrainConfig
    settings: dict
    validation: dict
    val_bicubic: float | None
    key: jax.Array


def _fit_in(folders: list, model_cfg, cfgs: list, *, by_seed: bool, make_batch, validation, sensor, resume,
            overwrite, mesh, progress, callback, data_description, conv3d_impl, init, checkpoint_every_s,
            pretrain_epochs, card_extra) -> list:
    """`fit` of one run per folder of `folders` (each with the config of `cfgs` beside it: they differ in their
    seed alone), which exist and whose locks this process holds (process 0's, across processes); several runs
    are stacked (`_advance`). by_seed (`fit(seeds=...)`, one seed or more): the records the callback gets and
    the progress lines name their seed, the cards the stack's seeds. Returns [(best `Model`, history)] in the
    order of `folders`."""
    arch, how = architecture(model_cfg), recipe(model_cfg)
    lead, processes, train_cfg = _lead(), jax.process_count(), cfgs[0]
    held = [_on_lead(lambda out=out: _held_run_files(out, resume=resume, overwrite=overwrite)) for out in folders]
    if not how.data_parallel:
        if processes > 1:
            raise ValueError(f"fit: {arch.name} trains on one device (its step does not split a batch), so not across "
                             f"{processes} processes; train it in one")
        if isinstance(mesh, Mesh):
            raise ValueError(f"fit: {arch.name} trains on one device (its step does not split a batch); pass "
                             "mesh=None or 'auto'")
        mesh = None
    mesh = choose_mesh(mesh, train_cfg.batch_size)
    if make_batch is None:
        make_batch = how.data(model_cfg, train_cfg, sensor)
    if data_description is None:
        data_description = getattr(make_batch, "description", "user-supplied make_batch")
    seats, states, runs = [], [], []
    # the training behind each run's weights, for its card (written by the lead process alone)
    lineages = [_run_lineage(out, init, resume) if lead else {} for out in folders]
    start = _start_or_resume if processes == 1 else _start_across_processes
    for out, cfg in zip(folders, cfgs):
        k_init, k_data, k_val = run_keys(cfg.seed)
        val = how.validation(k_val, model_cfg, cfg, sensor) if validation is None else validation
        settings = _settings(model_cfg, cfg, pretrain_epochs)
        if init is not None:
            settings["init"] = str(init) if not isinstance(init, Model) else "a Model passed to fit"
        ts, run = start(out, model_cfg, cfg, settings, k_init=k_init, k_data=k_data, resume=resume, init=init)
        seats.append(_Seat(out, cfg, settings, val, _bicubic_psnr(val, arch.scale(model_cfg)), ts.key))
        states.append(ts)
        runs.append(run)
    if lead and resume and not _next_group(runs, train_cfg.epochs):  # each run done (a stack's seeds: all of them)
        for seat, run in zip(seats, runs):
            why = (f"stopped early after {run.epoch} epochs ({train_cfg.patience} without a lower validation loss)"
                   if run.finished else f"already has {run.epoch} epochs (epochs={train_cfg.epochs})")
            warnings.warn(f"the run in {seat.out} {why}; nothing to train"
                          + ("" if run.finished else ": give more epochs (--epochs) to continue it"), stacklevel=3)
    spe, stacked = train_cfg.steps_per_epoch, len(seats) > 1
    if stacked and lead and jax.default_backend() == "cpu" and _next_group(runs, train_cfg.epochs):
        warnings.warn(f"{len(seats)} seeds stacked on CPU train slower than one after another (XLA:CPU runs the "
                      "convolutions vmapped over the seeds' weights as grouped ones, several times slower: x0.2 at "
                      "TR0, docs/training.md)", stacklevel=3)
    step_fn = how.step(model_cfg, train_cfg, make_batch, sensor=sensor, mesh=mesh, conv3d_impl=conv3d_impl,
                       pretrain_steps=pretrain_epochs * spe)
    advance = _advance(step_fn, [seat.key for seat in seats], stacked=stacked)
    train = replicate(_stack([ts.train for ts in states]) if stacked else states[0].train, mesh)
    bests = [ts.best for ts in states]
    del states  # the runs' train states live in `train` from here on

    def view(i: int, train) -> _TrainState:  # run i's own train state
        return _TrainState(_unstack(train, i) if stacked else train, bests[i], seats[i].key)

    def card_of(i: int, run: _Run) -> dict:
        seat = seats[i]
        card = _training_card(run, train_cfg=seat.train_cfg, settings=seat.settings, sensor=sensor,
                              validation=seat.validation, bicubic_psnr=seat.val_bicubic, data=data_description)
        if pretrain_epochs:
            card["pretrain_epochs"] = pretrain_epochs
        lineage = lineages[i]
        if lineage:  # a fine-tune: the training before it, and the sums with this run's
            card = {**card, "earlier_stages": lineage["earlier_stages"],
                    "total_steps": lineage["total_steps"] + run.step,
                    "total_examples": lineage["total_examples"] + run.step * seat.train_cfg.batch_size}
        if by_seed:
            card["stacked_seeds"] = [s.train_cfg.seed for s in seats]
        return {**card, **(card_extra or {})}

    old_runs = [list(h) if overwrite else [] for h in held]  # replaced runs' files, removed before the first save

    def forget_old_run(i: int):
        for name in old_runs[i]:
            (seats[i].out / name).unlink(missing_ok=True)
        old_runs[i].clear()

    def save_inside_epoch(i: int, train, run: _Run):
        forget_old_run(i)
        # the card counts the steps and time so far; the run keeps the epoch's time apart until the epoch ends
        _save_state(seats[i].out / RESUME_FILE, view(i, train), run, seats[i].settings,
                    card_of(i, dataclasses.replace(run, wall_time_s=run.wall_time_s + run.epoch_train_s)))

    while group := _next_group(runs, train_cfg.epochs):
        train, trained = _run_epoch(advance, train, runs, group, train_cfg, progress=progress and lead,
                                    save=save_inside_epoch if lead else None, every_s=checkpoint_every_s)
        for i in group:
            t_val, ts, seat = time.perf_counter(), view(i, train), seats[i]
            weights = (ts.train["params"], ts.train["state"])
            if processes > 1:  # each process validates on its own copy of the (replicated) weights
                weights = jax.tree_util.tree_map(jnp.asarray, jax.device_get(weights))
            val = how.evaluate(Model(*weights, model_cfg), seat.validation, seat.train_cfg, sensor=sensor,
                               conv3d_impl=conv3d_impl)
            epoch = trained[i]
            run = dataclasses.replace(runs[i], epoch=runs[i].epoch + 1, step=(runs[i].epoch + 1) * spe,
                                      epoch_loss_sum=0.0, epoch_psnr_sum=0.0, epoch_sums={}, epoch_train_s=0.0)
            record = {
                "epoch": run.epoch, "step": run.step, "lr": epoch["lr"],
                "train_loss": epoch["loss"], "train_psnr": epoch["psnr"],
                **{f"train_{k}": v for k, v in epoch["other"].items()},
                "val_loss": val["loss"], "val_psnr": val["psnr"], "val_bicubic_psnr": seat.val_bicubic,
                "examples_per_s": spe * train_cfg.batch_size / epoch["train_s"],
                "epoch_time_s": epoch["train_s"] + time.perf_counter() - t_val,
            }
            record = _share(record)  # process 0's numbers: every process logs and stops on the same
            run, ts = _early_stopping(run, ts, record["val_loss"], seat.train_cfg)
            bests[i] = ts.best
            record["wall_time_s"] = run.wall_time_s + record["epoch_time_s"]
            runs[i] = run = dataclasses.replace(run, wall_time_s=record["wall_time_s"], history=(*run.history, record))
            told = {"seed": seat.train_cfg.seed, **record} if by_seed else record
            if lead:
                if progress:
                    print(json.dumps(told))
                forget_old_run(i)
                _write_checkpoints(seat.out, ts, run, model_cfg, seat.settings, card_of(i, run))
            if callback is not None:
                callback(told)
    return [(Model(*(jax.tree_util.tree_map(jnp.asarray, (b["params"], b["state"]))), model_cfg), list(run.history))
            for b, run in zip(bests, runs)]
