"""Training from a preset, as `jaxsr train` does it: one call from options to a finished (or resumed) run."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..baselines.histnet import HistNetConfig
from ..baselines.rbpn import RBPNConfig
from ..config import PRESETS, ModelConfig, SensorConfig
from ..io.files import removing_new_folder
from ..io.formats import read_npz_arrays
from ..nn.model import Model, architecture, architectures
from .data import sequence_batches, sequence_clips
from .loop import RUN_FILES, fit, resume_config

__all__ = ["MAX_TR", "train", "sequence_data"]

# The network has 3 + TR blocks over windows of 2TR+1 frames, so memory and compute grow with TR; the paper
# uses TR 0-4, and a TR beyond this does not fit a training batch in the memory of a usual machine.
MAX_TR = 8

# The learned baselines at their published sizes (jaxsr.baselines), by architecture name
_BASELINE_CONFIGS = {"histnet": HistNetConfig(), "iseebetter": RBPNConfig()}


def sequence_data(path, model_cfg: ModelConfig, train_cfg, sensor: SensorConfig):
    """The data source for HR sequences from an .npz with arrays depth (radial m) and intensity, (N, T, H, W),
    read and checked now: windows of 2 tr + 1 frames for the window form, clips of `train_cfg.clip_length` frames
    for the sequence form. Returns make_batch (key -> (inputs, gt)); ValueError for another file or dtype."""
    if Path(path).suffix.lower() != ".npz":
        raise ValueError(f"--data {path}: expected an .npz file with arrays depth (radial m) and intensity, "
                         "(N, T, H, W)")
    d = read_npz_arrays(path, ["depth", "intensity"])
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
          seed: int | None = None, epochs: int | None = None, clip_frames: int | None = None, data=None, init=None,
          resume: bool = False, overwrite: bool = False, checkpoint_minutes: float = 10.0,
          progress: bool = True) -> tuple[Model, list]:
    """Train a network from a preset into folder `out`, as `jaxsr train` does (the same options, the same files).

    arch: a registered architecture ("duf", the paper's network with `tr`, `scale` and `temporal`; "histnet" or
    "iseebetter" at their published sizes, x4). preset: a key of `jaxsr.config.PRESETS`, with `seed`, `epochs`
    and `clip_frames` (sequence form) overriding its own when given. data: None (rendered scenes) or an .npz of
    HR sequences (DUF only; `sequence_data`). init: weights to start from (DUF only; see `jaxsr.fit`).
    resume / overwrite: continue the run in `out`, or start over in its place (see `jaxsr.fit`); resume refuses
    (FileNotFoundError) a missing folder or one without a run, where `fit` would start a new one.
    checkpoint_minutes: minutes of training between saves inside an epoch (0: every step; inf: never).
    Configs and data are built and checked before any work, and a run that fails or is stopped before its first
    save leaves no new folder. Returns (best `Model`, history: per-epoch records); raises ValueError for a bad
    option and FileExistsError for an `out` that is a file or holds a run (without resume or overwrite).
    """
    if arch not in architectures():
        raise ValueError(f"train: arch must be one of {', '.join(architectures())}, got {arch!r}")
    if preset not in PRESETS:
        raise ValueError(f"train: preset must be one of {', '.join(sorted(PRESETS))}, got {preset!r}")
    if not checkpoint_minutes >= 0:  # also refuses NaN
        raise ValueError(f"--checkpoint-minutes {checkpoint_minutes}: expected a number of minutes >= 0")
    changes = {k: v for k, v in (("seed", seed), ("epochs", epochs), ("clip_frames", clip_frames)) if v is not None}
    train_cfg = dataclasses.replace(PRESETS[preset], **changes)
    if arch == "duf":
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
        model_cfg = _BASELINE_CONFIGS[arch]
    sensor = SensorConfig() if scale == 4 else SensorConfig(scale=scale)
    if Path(out).exists() and not Path(out).is_dir():
        raise FileExistsError(f"{out} is a file; --out is a folder")
    if resume and not any((Path(out) / name).exists() for name in RUN_FILES):
        raise FileNotFoundError(f"--resume: nothing to resume: {out} holds no training run (none of "
                                f"{', '.join(RUN_FILES)}); leave out --resume to start one")
    make_batch = sequence_data(data, model_cfg, train_cfg, sensor) if data is not None else None
    with removing_new_folder(out):  # a run that fails or stops before its first save leaves no folder
        train_cfg = resume_config(out, train_cfg) if resume else train_cfg  # a run keeps the validation it began with
        return fit(model_cfg, train_cfg, out=out, make_batch=make_batch, sensor=sensor, resume=resume,
                   overwrite=overwrite, progress=progress, init=init, checkpoint_every_s=60 * checkpoint_minutes)
