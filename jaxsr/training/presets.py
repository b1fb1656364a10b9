"""Training from a preset, as `jaxsr train` does it: one call from options to a finished (or resumed) run; and
fine-tuning a trained model to a sensor described in a file, as `jaxsr finetune` does it, on the same path."""

from __future__ import annotations

import contextlib
import os
import dataclasses
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp

from ..config import PRESETS, ModelConfig, Optics, PhotonRegime, Sensor
from ..io.checkpoint import config_from_dict, load_model, read_metadata, resolve_model_path
from ..io.files import check_output_folder, removing_new_folder
from ..io.formats import read_npz_arrays
from ..nn.duf import DUF
from ..nn.model import Model, architecture, architectures
from .data import regime_batches, run_keys, sequence_batches, sequence_clips
from .duf import initial_weights
from .folders import RUN_FILES, _check_seeds, _check_stack_folder, _latest_state, resume_config, seed_folder
from .loop import fit
from .recipes import recipe
from .sensor_file import card_entry, read_sensor_file, sensor_differences, training_sensor

__all__ = ["MAX_TR", "train", "sequence_data", "finetune", "regime_validation", "FINETUNE_LR_FACTOR",
           "PHOTON_INPUTS"]

# The network has 3 + TR blocks over windows of 2TR+1 frames, so memory and compute grow with TR; the paper
# uses TR 0-4, and a TR beyond this does not fit a training batch in the memory of a usual machine.
MAX_TR = 8


def sequence_data(path, model_cfg: ModelConfig, train_cfg, sensor: Sensor):
    """The data source for HR sequences from an .npz with arrays depth (radial m) and intensity, (N, T, H, W),
    read and checked now: windows of 2 tr + 1 frames for the window form, clips of `train_cfg.clip_length` frames
    for the sequence form. Returns make_batch (key -> (inputs, gt)); ValueError for another file or dtype."""
    if Path(path).suffix.lower() != ".npz":
        raise ValueError(f"--data {path}: expected an .npz file with arrays depth (radial m) and intensity, "
                         "(N, T, H, W)")
    d = read_npz_arrays(path, ["depth", "intensity"], names=("depth", "intensity"))  # the file's others stay packed
    for name in ("depth", "intensity"):
        if d[name].dtype.kind not in "iuf":
            raise ValueError(f"--data {path}: {name} holds {d[name].dtype} values; expected real numbers")
    if architecture(model_cfg).sequence_form(model_cfg):
        make_batch = sequence_clips(d["depth"], d["intensity"], train_cfg.clip_length(model_cfg), train_cfg,
                                    sensor=sensor)
    else:
        make_batch = sequence_batches(d["depth"], d["intensity"], model_cfg.tr, train_cfg, sensor=sensor)
    make_batch.description = f"{path}: " + make_batch.description
    return make_batch


def train(out, *, arch: str = "duf", tr: int = 4, scale: int = 4, temporal: str = "window", preset: str = "cpu",
          seed: int | None = None, seeds=None, epochs: int | None = None, clip_frames: int | None = None,
          data=None, init=None, resume: bool = False, overwrite: bool = False, checkpoint_minutes: float = 10.0,
          progress: bool = True) -> tuple[Model, list] | dict:
    """Train a network from a preset into folder `out`, as `jaxsr train` does (the same options, the same files).

    arch: a registered architecture ("duf", the paper's network with `tr`, `scale` and `temporal`; "histnet" or
    "iseebetter" at their published sizes, x4). preset: a key of `jaxsr.config.PRESETS`, with `seed`, `epochs`
    and `clip_frames` (sequence form) overriding its own when given. seeds: a stacked run of these seeds (a list,
    not with `seed`; see `jaxsr.fit`), each in its own folder `out/seed<k>` (`seed_folder`); with resume, a seed
    whose folder holds no run starts afresh, as long as one of them holds one. data: None (rendered scenes) or an
    .npz of HR sequences (DUF only; `sequence_data`). init: weights to start from (DUF only; see `jaxsr.fit`).
    resume / overwrite: continue the run in `out`, or start over in its place (see `jaxsr.fit`); resume refuses
    (FileNotFoundError) a missing folder or one without a run, where `fit` would start a new one.
    checkpoint_minutes: minutes of training between saves inside an epoch (0: every step; inf: never).
    Configs and data are built and checked before any work, and a run that fails or is stopped before its first
    save leaves no new folder. Returns (best `Model`, history: per-epoch records), with `seeds` a dict {seed:
    (best `Model`, history)}; raises ValueError for a bad option and FileExistsError for an `out` that is a file or
    holds a run (without resume or overwrite).
    """
    if arch not in architectures():
        raise ValueError(f"train: arch must be one of {', '.join(architectures())}, got {arch!r}")
    if preset not in PRESETS:
        raise ValueError(f"train: preset must be one of {', '.join(sorted(PRESETS))}, got {preset!r}")
    _check_minutes(checkpoint_minutes)
    if seed is not None and seeds is not None:
        raise ValueError("train: seed and seeds exclude each other (one run, or a stacked run of several seeds)")
    seeds = _check_seeds(seeds)
    changes = {k: v for k, v in (("seed", seed), ("epochs", epochs), ("clip_frames", clip_frames)) if v is not None}
    train_cfg = dataclasses.replace(PRESETS[preset], **changes)
    published = recipe(arch).published  # a learned baseline's size; None: the options choose the paper's network's
    if published is None:
        if architecture(arch).config_type is not ModelConfig:
            raise ValueError(f"train: {arch} has no published size and is not the paper's network; train it with "
                             "jaxsr.fit")
        if not 0 <= tr <= MAX_TR:
            raise ValueError(f"train: tr must be 0..{MAX_TR} (memory and compute grow with the window of 2TR+1 "
                             f"frames), got {tr}")
        model_cfg = ModelConfig(tr=tr, scale=scale, temporal=temporal)
        if architecture(model_cfg).sequence_form(model_cfg):
            train_cfg.clip_length(model_cfg)  # raises now for clips too short for the network
        elif clip_frames is not None:
            raise ValueError("--clip-frames applies to the sequence form (--temporal sequence) only")
    else:
        if data is not None or init is not None or scale != 4:
            raise ValueError(f"train: {arch} trains at x4 on rendered scenes from random weights (no data, init or "
                             "scale)")
        model_cfg = published
    sensor = Sensor(optics=Optics.of_hr(Sensor().hr_shape, scale))  # the paper's HR frame at this scale
    _check_out(out, resume, seeds=seeds, overwrite=overwrite)
    _check_init_outside(init, out, resume, flag="--init")
    if init is not None and not isinstance(init, Model):
        _check_weights(init)
    make_batch = sequence_data(data, model_cfg, train_cfg, sensor) if data is not None else None
    return _fit_in_new_folder(out, model_cfg, train_cfg, make_batch=make_batch, sensor=sensor, resume=resume,
                              overwrite=overwrite, progress=progress, init=init,
                              checkpoint_every_s=60 * checkpoint_minutes, seeds=seeds)


def _check_weights(init) -> None:
    """Load the starting weights `init` (a name or path) once, so that a file that holds no model, or a damaged
    or hostile one (a header claiming terabytes, non-finite weights), fails now, not after the set-up (drawing
    the validation set took minutes)."""
    load_model(resolve_model_path(init))


def _check_minutes(checkpoint_minutes):
    if not checkpoint_minutes >= 0:  # also refuses NaN
        raise ValueError(f"--checkpoint-minutes {checkpoint_minutes}: expected a number of minutes >= 0")


def _check_out(out, resume: bool, *, seeds=None, overwrite: bool = False):
    """The checks of folder `out` that `train` and `finetune` make before any work: not a file, a place this
    process can write (`jaxsr.io.NotWritableError`: no permission, a read-only file system), holding a run
    to resume when `resume`, and holding none unless `resume` or `overwrite` (said now, not after the minutes the
    validation set and the first compilation take); with `seeds` (a stacked run), of each seed's folder in it (one
    holding a run is enough to resume), and `out` itself holding none."""
    folders = [Path(out)] if seeds is None else [seed_folder(out, s) for s in seeds]
    for folder in {Path(out), *folders}:
        if folder.exists() and not folder.is_dir():
            raise FileExistsError(f"{folder} is a file; -o/--output is a folder")
    for folder in {Path(out), *folders}:  # a read-only place was refused only at the first write, minutes on
        check_output_folder(folder)
    if seeds is not None:
        _check_stack_folder(Path(out))
    if resume and not any((folder / name).exists() for folder in folders for name in RUN_FILES):
        what = (f"{out} holds no training run (none of" if seeds is None else
                f"no seed folder of {out} ({', '.join(f.name for f in folders)}) holds a training run (one of")
        raise FileNotFoundError(f"--resume: nothing to resume: {what} {', '.join(RUN_FILES)}); leave out --resume "
                                "to start one")
    if not (resume or overwrite):
        for folder in folders:
            held = [name for name in RUN_FILES if (folder / name).exists()]
            if held:
                raise FileExistsError(f"{folder} holds a training run ({', '.join(held)}); pass --resume to continue "
                                      "it or --force to start a new one in its place")


def _fit_in_new_folder(out, model_cfg, train_cfg, *, resume: bool, seeds=None, **fit_args):
    """`fit` into folder `out` (with `seeds`, a stacked run into its seeds' folders in it), which a run that fails
    or stops before its first save leaves as it was (new folders are removed); a resumed run keeps the
    validation sequences it began with (`resume_config`)."""
    folders = [] if seeds is None else [seed_folder(out, s) for s in seeds]
    with contextlib.ExitStack() as stack:
        for folder in (out, *folders):  # left in reverse: the seeds' folders before `out`
            stack.enter_context(removing_new_folder(folder))
        if resume:
            resumed = [resume_config(folder, train_cfg) for folder in folders or [out]]
            if any(cfg != resumed[0] for cfg in resumed):
                raise ValueError(f"--resume: the seeds' runs in {out} validate on different sequences; resume each "
                                 "alone (--seed K -o OUT/seedK)")
            train_cfg = resumed[0]
        return fit(model_cfg, train_cfg, out=out, resume=resume, seeds=seeds, **fit_args)


# Fine-tuning: Adam's rate 10x below the preset's (the weights start from a trained function), cut 10x half way.
FINETUNE_LR_FACTOR = 0.1
# A model that reads the photons behind each depth and marks no return (`jaxsr.nn.with_photon_inputs` widens a
# depth-only model to it, starting from its function).
PHOTON_INPUTS = {"inputs": ("depth", "signal", "background"), "no_return_head": True}


def regime_validation(tr: int, train_cfg, regime: PhotonRegime, *, batches: int, sensor: Sensor,
                      inputs=("depth",), key=None, snrs=None) -> dict:
    """A fixed validation set drawn from a photon regime: `batches` batches of `regime_batches(tr, train_cfg,
    regime, ...)` drawn with keys folded from `key` (default a fixed key independent of any training keys), as
    `fit` takes it (and `jaxsr.training.evaluate` reads it): {"windows", "gt", "lr" (the centre frames, for the
    bicubic reference), "names"}. Model selection on the regime the model is for.

    snrs: frame SNRs to validate at instead of the regime's log-uniform range, the batches shared out among them
    in turn (at least one each), every clip at that SNR (no clips of the paper's regime, whose SNR is its own): a
    selection that sees every SNR named as often, such as a real recording's 45, beyond the wide regime's 20."""
    if not (isinstance(batches, int) and batches >= 1):
        raise ValueError(f"regime_validation: batches must be an integer >= 1, got {batches!r}")
    key = jax.random.key(2**31 - 1) if key is None else key
    if snrs is not None:
        snrs = tuple(float(s) for s in snrs)
        if not snrs:
            raise ValueError("regime_validation: snrs must name at least one SNR, or be None")
        for s in snrs:  # each checked as a regime's SNRs are (finite, > 0)
            dataclasses.replace(regime, snr_range=(s, s))
        regime = dataclasses.replace(regime, paper_prob=0.0)
    # at SNRs, the SNR is an argument of the one compiled source, not a constant of one per SNR: the simulation
    # compiles once (a minute or more on an accelerator's host) however many SNRs are named
    source = jax.jit(regime_batches(tr, train_cfg, regime, sensor=sensor, inputs=inputs))
    if snrs is None:
        drawn = [source(jax.random.fold_in(key, i)) for i in range(batches)]
    else:
        drawn = [source(jax.random.fold_in(key, i), snr=jnp.float32(snrs[i % len(snrs)]))
                 for i in range(max(batches, len(snrs)))]
    windows = jnp.concatenate([w for w, _ in drawn])
    gt = jnp.concatenate([g for _, g in drawn])
    names = [f"regime draws x{windows.shape[0]}" + ("" if snrs is None else
                                                      f" at SNR {', '.join(f'{s:g}' for s in snrs)}")]
    return {"windows": windows, "gt": gt, "lr": windows[:, tr], "names": names}


def _init_config(init, photons: bool | None) -> ModelConfig:
    """The model a fine-tune trains: the architecture of the weights `init` (read from the file), in the window
    form, widened to the photon inputs when `photons` (None: as `init` reads), with the default no-return decision
    threshold (a calibration of `init`'s weights says nothing about the fine-tuned ones: calibrate those anew)."""
    path = resolve_model_path(init)  # FileNotFoundError naming the model
    meta = read_metadata(path)
    name = meta.get("architecture", meta.get("baseline", "duf"))  # files older than the name: the DUF network
    if "config" not in meta or name not in architectures() or architecture(name).config_type is not ModelConfig:
        got = f"a {name} model" if "config" in meta else "a file that holds no model"
        raise ValueError(f"-m/--model {init}: expected a model of the paper's network (tr0..tr4 or a checkpoint of "
                         f"it), got {got}")
    cfg = dataclasses.replace(config_from_dict(ModelConfig, meta["config"]), temporal="window",
                              no_return_logit=ModelConfig().no_return_logit)
    if cfg.scale != 4:
        raise ValueError(f"-m/--model {init}: a x{cfg.scale} model; fine-tuning trains x4 models")
    reads_photons = DUF.reads_photons(cfg) or DUF.no_return_head(cfg)
    if photons:  # the photon inputs added to what the model reads (tr4-ambient keeps its ambient channel)
        inputs = cfg.inputs + tuple(n for n in PHOTON_INPUTS["inputs"] if n not in cfg.inputs)
        return dataclasses.replace(cfg, inputs=inputs, no_return_head=True)
    if photons is False and reads_photons:
        raise ValueError(f"-m/--model {init}: the model reads {', '.join(cfg.inputs)}; a model cannot be narrowed to "
                         "depth alone (leave photons unset to keep its inputs)")
    return cfg


def _start_score(model_cfg: ModelConfig, train_cfg, init, validation: dict, sensor: Sensor) -> dict:
    """The validation score of the weights a fine-tune starts from (as `fit` starts: widened to photon inputs
    with the run's init key where asked), {"val_loss", "val_psnr"}: the mark its epochs have to beat."""
    params, state = initial_weights(run_keys(train_cfg.seed)[0], model_cfg, init)
    val = recipe(model_cfg).evaluate(Model(params, state, model_cfg), validation, train_cfg, sensor=sensor)
    return {"val_loss": float(val["loss"]), "val_psnr": float(val["psnr"])}


def _check_init_outside(init, out, resume: bool, *, flag: str = "-m/--model") -> None:
    """Refuse starting weights (`flag`: finetune's -m/--model, train's --init) that lie inside the run folder a new
    run writes over (--force deletes them at the first save, and the closing advice would name a file that is
    gone); resuming reads the run's own state."""
    if resume or not isinstance(init, (str, os.PathLike)):
        return
    start = Path(resolve_model_path(init)).resolve()
    folder = Path(out).resolve()
    if folder == start or folder in start.parents:
        raise ValueError(f"{flag} {init} lies inside -o/--output {out}, which this run writes over: copy the "
                         "starting model elsewhere first, or choose another -o/--output")


def finetune(out, *, sensor_file, init="tr4", epochs: int = 10, steps_per_epoch: int = 256, val_batches: int = 16,
             preset: str = "bundle", photons: bool | None = None, seed: int | None = None, resume: bool = False,
             overwrite: bool = False, checkpoint_minutes: float = 10.0, progress: bool = True) -> tuple[Model, list]:
    """Fine-tune trained weights to the sensor a TOML file describes, into folder `out`, as `jaxsr finetune`
    does: `train`'s path (the same folder checks, lock, files, resume and training card) with the sensor's data.

    sensor_file: the sensor (`jaxsr.training.sensor_file.read_sensor_file`: bins, bin width, gate, pulse,
    resolution, photon levels and SNR). init: the weights to start from (tr0..tr4, a checkpoint or a run
    folder); the model keeps their architecture and TR, in the window form, and with `photons` True reads
    the photons behind each depth too (`PHOTON_INPUTS`; None keeps what `init` reads). Training: `epochs`
    epochs of `steps_per_epoch` steps of the `preset`'s batch and LR crops (cut to the sensor's frame) on
    `regime_batches` with the file's training sensor and PhotonRegime, Adam's rate `FINETUNE_LR_FACTOR` x the
    preset's, cut 10x after half the epochs, early stopping after max(3, epochs / 4) epochs without progress;
    validation on `val_batches` batches of the same regime drawn with fixed keys (`regime_validation`).
    The training card records the sensor file (its text, gate, IRF fit, the `jaxsr upscale` gate flags), the
    regime and the starting weights' validation score ("finetune": "start"), which the epochs have to beat (a
    warning when none does: best.npz then holds the best fine-tuned epoch all the same). resume continues the
    run in `out` (refused, ValueError, when the file now describes another sensor: the parsed keys count, not
    the comments; a larger `epochs` trains a finished run longer, on its schedule); overwrite starts over in its
    place. Returns (best `Model`, history); the sensor file's warnings go out as `warnings.warn`."""
    for name, value, lo in (("epochs", epochs, 1), ("steps_per_epoch", steps_per_epoch, 1),
                            ("val_batches", val_batches, 1)):
        if not (isinstance(value, int) and not isinstance(value, bool) and value >= lo):
            raise ValueError(f"finetune: {name} must be an integer >= {lo}, got {value!r}")
    if preset not in PRESETS:
        raise ValueError(f"finetune: preset must be one of {', '.join(sorted(PRESETS))}, got {preset!r}")
    _check_minutes(checkpoint_minutes)
    _check_out(out, resume, overwrite=overwrite)
    _check_init_outside(init, out, resume)
    file_sensor, regime, info = read_sensor_file(sensor_file)
    sensor = training_sensor(file_sensor)  # what is simulated: the gate at the scenes' range, a window of the frame
    model_cfg = _init_config(init, photons)
    _check_weights(init)
    entry = card_entry(info)
    base = PRESETS[preset]
    rows, cols = sensor.lr_shape
    patch = None if base.patch is None else (min(base.patch[0], rows), min(base.patch[1], cols))
    schedule = {"decay_epochs": max(1, epochs // 2), "patience": max(3, epochs // 4)}
    saved_path = _latest_state(Path(out)) if resume else None
    if saved_path is not None:
        saved = read_metadata(saved_path)
        card = saved.get("card", {})
        if "sensor_file" not in card:
            raise ValueError(f"--resume: the run in {out} is not a fine-tune to a sensor file (one of jaxsr train?); "
                             "use --force to start over in its place, or another -o/--output")
        differ = sensor_differences(card, entry, regime)
        if differ:
            raise ValueError(f"--resume: {sensor_file} describes another sensor than the run in {out} was trained "
                             f"for ({card['sensor_file'].get('path')}): {', '.join(differ)} differ; use --force to "
                             "start over, or another -o/--output")
        # a resumed run keeps its schedule (the rate's cut and the patience), so that --epochs may extend it
        saved_cfg = saved.get("train_config", {})
        schedule = {k: saved_cfg.get(k, v) for k, v in schedule.items()}
    train_cfg = dataclasses.replace(base, examples_per_epoch=steps_per_epoch * base.batch_size, epochs=epochs,
                                    lr=base.lr * FINETUNE_LR_FACTOR, patch=patch, **schedule,
                                    **({} if seed is None else {"seed": seed}))
    for line in info["warnings"]:
        warnings.warn(f"{info['path']}: {line}", stacklevel=2)
    make_batch = regime_batches(model_cfg.tr, train_cfg, regime, sensor=sensor, inputs=model_cfg.inputs)
    validation = regime_validation(model_cfg.tr, train_cfg, dataclasses.replace(regime, paper_prob=0.0),
                                   batches=val_batches, sensor=sensor, inputs=model_cfg.inputs,
                                   key=run_keys(train_cfg.seed)[2])
    init_path = str(resolve_model_path(init))
    if saved_path is not None and "start" in card.get("finetune", {}):
        start = card["finetune"]["start"]
    else:
        start = _start_score(model_cfg, train_cfg, init_path, validation, sensor)
    extra = {"sensor_file": entry, "regime": regime.to_dict(),
             "finetune": {"from": str(init), "lr_factor": FINETUNE_LR_FACTOR, "val_batches": val_batches,
                          "preset": preset, "photons": DUF.reads_photons(model_cfg), "start": start}}
    if progress:
        print(f"starting from {init}: val loss {start['val_loss']:.3e}, val PSNR {start['val_psnr']:.2f} dB")
    model, history = _fit_in_new_folder(out, model_cfg, train_cfg, make_batch=make_batch, validation=validation,
                                        sensor=sensor, resume=resume, overwrite=overwrite, progress=progress,
                                        init=init_path, checkpoint_every_s=60 * checkpoint_minutes, card_extra=extra)
    if history and min(r["val_loss"] for r in history) >= start["val_loss"]:
        warnings.warn(f"no epoch beat the starting model {init} on the sensor's validation (val loss "
                      f"{start['val_loss']:.3e}); {Path(out) / 'best.npz'} holds the best epoch all the same: train "
                      "longer, or keep using the starting model", stacklevel=2)
    return model, history
