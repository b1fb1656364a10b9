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

This module holds `fit` and the loop that ties the run's parts together; each part has its module: the run
folders (`folders`), the saved train state and resume (`run_state`), the epochs and early stopping (`epochs`),
the records and training card (`records`) and the mesh and processes (`processes`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import time
import warnings
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.sharding import Mesh

from ..config import Sensor, TrainConfig
from ..io.files import folder_lock
from ..nn.model import Model, architecture
from .data import run_keys
from .epochs import (TrainingDiverged, _advance, _early_stopping, _next_group, _run_epoch, _stack, _unstack,
                     check_finite_loss)
from .folders import RUN_FILES, _check_seeds, _check_stack_folder, _held_run_files, seed_folder
from .processes import _lead, _on_lead, _share, choose_mesh, replicate
from .recipes import recipe
from .records import _bicubic_psnr, _epoch_record, _run_lineage, _training_card
from .run_state import (_Run, _save_resume, _settings, _start_across_processes, _start_or_resume, _TrainState,
                        _write_checkpoints)

__all__ = ["fit"]


def fit(
    model_cfg,
    train_cfg: TrainConfig,
    *,
    out,
    seeds=None,
    make_batch=None,
    validation: dict | None = None,
    sensor: Sensor = Sensor(),
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


class _Seat(NamedTuple):
    """What one run of a `fit` keeps from start to end: its folder, config (its seed), settings as its
    checkpoints record them, validation set with its bicubic PSNR, and data key."""

    out: Path
    train_cfg: TrainConfig
    settings: dict
    validation: dict
    val_bicubic: float | None
    key: jax.Array


REPLACED_FOLDER = ".replaced"  # inside a run folder: the run a new one replaces, until the new one has an epoch


def _keep_what_was_there(out: Path) -> None:
    """After a run in `out` diverged: where it replaced a run and has no epoch of its own yet, its files go and
    the run it set aside (REPLACED_FOLDER) comes back. Anything else stays: a fresh or resumed run's saves are of
    finite weights, and a resumed run's earlier files were never this session's to remove."""
    aside = out / REPLACED_FOLDER
    if not aside.is_dir():
        return
    for name in RUN_FILES:
        (out / name).unlink(missing_ok=True)
    for f in aside.iterdir():
        os.replace(f, out / f.name)
    aside.rmdir()


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

    # a replaced run's files: set aside (REPLACED_FOLDER) at this run's first save, removed once this run has an
    # epoch of its own, put back if it diverges before
    old_runs = [list(h) if overwrite else [] for h in held]

    def set_old_run_aside(i: int):
        aside = seats[i].out / REPLACED_FOLDER
        for name in old_runs[i]:
            if (seats[i].out / name).exists():
                aside.mkdir(exist_ok=True)
                os.replace(seats[i].out / name, aside / name)
        old_runs[i].clear()

    def forget_old_run(i: int):
        set_old_run_aside(i)
        shutil.rmtree(seats[i].out / REPLACED_FOLDER, ignore_errors=True)

    def save_inside_epoch(i: int, train, run: _Run):
        set_old_run_aside(i)
        # the card counts the steps and time so far; the run keeps the epoch's time apart until the epoch ends
        _save_resume(seats[i].out, view(i, train), run, seats[i].settings,
                     card_of(i, dataclasses.replace(run, wall_time_s=run.wall_time_s + run.epoch_train_s)))

    while group := _next_group(runs, train_cfg.epochs):
        try:
            train, trained = _run_epoch(advance, train, runs, group, train_cfg, progress=progress and lead,
                                        save=save_inside_epoch if lead else None, every_s=checkpoint_every_s)
        except TrainingDiverged:
            if lead:
                for i in group:
                    _keep_what_was_there(seats[i].out)
            raise
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
            record = _epoch_record(run, epoch, val, bicubic_psnr=seat.val_bicubic,
                                   examples=spe * train_cfg.batch_size, validation_s=time.perf_counter() - t_val)
            record = _share(record)  # process 0's numbers: every process logs and stops on the same
            try:
                check_finite_loss(record["val_loss"], step=run.step, where=" on the validation set")
            except TrainingDiverged:
                if lead:
                    _keep_what_was_there(seat.out)
                raise
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
