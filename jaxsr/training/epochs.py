"""The epochs of a run, or of several runs stacked: their train steps (`_advance`, `_run_epoch`), which runs
train next (`_next_group`) and early stopping (`_early_stopping`).
"""

from __future__ import annotations

import dataclasses
import math
import time

import jax
import jax.numpy as jnp
import numpy as np

from ..config import TrainConfig
from .run_state import _Run, _TrainState


class TrainingDiverged(ValueError):
    """The loss or the weights went non-finite: the run stops before it saves them (`fit` then keeps what its
    folder held before it, and the finite epochs it completed)."""


def check_finite_loss(loss: float, *, step: int, where: str = "") -> None:
    """Raise `TrainingDiverged` for a loss that is NaN or infinite, naming the step."""
    if not math.isfinite(loss):
        raise TrainingDiverged(f"training diverged{where}: the loss of step {step} is {loss}; the run stops here and "
                               "nothing of it past its last finite epoch is saved (a learning rate too high for "
                               "these data, or data the network cannot read: check the sensor and the data)")


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
            check_finite_loss(last_loss[i], step=step + 1, where=f" (run {i})" if len(runs) > 1 else "")
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
