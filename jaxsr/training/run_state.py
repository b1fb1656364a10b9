"""A run's saved state: what `last.npz` and `resume.npz` hold, writing them, and starting a run afresh or from
them.

The train state (`_TrainState`: what the recipe's step updates, the best weights, the data key) and where the run
stands (`_Run`: epoch, step, early-stopping counters, history) are saved with the settings that made them; a
resume checks those settings (`_check_resumable`) and continues as the uninterrupted run would. Across processes,
process 0 reads the state and sends it to the others (`_start_across_processes`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import warnings
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..config import TrainConfig
from ..io.checkpoint import config_from_dict, config_to_dict, load_tree, read_metadata, save_model, save_tree
from ..io.files import write_text_atomic
from ..nn.model import Model, architecture
from .folders import RESUME_FILE, _latest_state
from .processes import _on_lead
from .recipes import recipe


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


def _save_state(path: Path, ts: _TrainState, run: _Run, settings: dict, card: dict):
    """Everything a resume needs (the train state, best weights, RNG key, the run), written atomically."""
    tree = {**ts.train, "best": ts.best, "key": jax.random.key_data(ts.key)}
    save_tree(path, tree, dict(settings, kind="train_state", run=dataclasses.asdict(run), card=card,
                               processes=jax.process_count()))


def _save_resume(out: Path, ts: _TrainState, run: _Run, settings: dict, card: dict):
    """Inside an epoch: the train state to `resume.npz` in folder `out` (`last.npz` keeps the last epoch's end)."""
    _save_state(out / RESUME_FILE, ts, run, settings, card)


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
