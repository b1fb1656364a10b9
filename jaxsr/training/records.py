"""What a run records about itself: each epoch's record (a line of `metrics.jsonl`), the training card saved
with its checkpoints, and the lineage of a fine-tune (the training behind its starting weights).
"""

from __future__ import annotations

import math
import numbers
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from ..baselines.interpolation import bicubic
from ..config import Sensor, TrainConfig
from ..eval.metrics import psnr
from ..io.checkpoint import read_metadata, resolve_model_path
from ..nn.model import Model
from .folders import _latest_state
from .run_state import _Run


def _hardware() -> dict:
    """The machine a run trains on, for its card: backend, devices, processes, host, JAX version."""
    devs = jax.devices()
    return {
        "backend": jax.default_backend(),
        "devices": len(devs),
        "device_kind": devs[0].device_kind,
        "processes": jax.process_count(),
        "host": platform.platform(),
        "jax": jax.__version__,
    }


def _bicubic_psnr(validation: dict, scale: int) -> float | None:
    """Mean PSNR (dB) of bicubic upsampling of the validation set's centre frames (None without "lr"): the
    baseline every epoch's validation PSNR is logged beside."""
    if "lr" not in validation:
        return None
    lr = validation["lr"]
    depth = lr[..., 0] if lr.ndim == validation["gt"].ndim + 1 else lr  # a photon model's channels: depth first
    return float(jnp.mean(psnr(bicubic(depth, scale=scale), validation["gt"])))


def _epoch_record(run: _Run, epoch: dict, val: dict, *, bicubic_psnr: float | None, examples: int,
                  validation_s: float) -> dict:
    """The record of epoch `run.epoch` (1-based, just finished) as `metrics.jsonl` logs it, but for its
    "wall_time_s": epoch: `_run_epoch`'s means of it; val: the recipe's {"loss", "psnr"} of its weights;
    examples: the epoch's training examples; validation_s: the time its validation took."""
    return {
        "epoch": run.epoch, "step": run.step, "lr": epoch["lr"],
        "train_loss": epoch["loss"], "train_psnr": epoch["psnr"],
        **{f"train_{k}": v for k, v in epoch["other"].items()},
        "val_loss": val["loss"], "val_psnr": val["psnr"], "val_bicubic_psnr": bicubic_psnr,
        "examples_per_s": examples / epoch["train_s"],
        "epoch_time_s": epoch["train_s"] + validation_s,
    }


def _training_card(run: _Run, *, train_cfg: TrainConfig, settings: dict, sensor: Sensor, validation: dict,
                   bicubic_psnr: float | None, data: str) -> dict:
    """The training card saved with the checkpoints: data, sensor, amount of training, hardware, validation."""
    return {
        "data": data,
        "sensor": sensor.to_dict(),  # jaxsr.Sensor.from_dict reads it back
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
