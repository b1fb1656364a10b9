"""Train the sequence-form models for the bundle at the training time of the windowed bundled model of each TR.

    python experiments/train_sequence_bundle.py [--trs 4 1 2 3] [--runs runs/bundle-seq]

Each TR: the `bundle` preset (batch 4, 16 x 32 LR crops, 5 epochs, the rate cut for the last, patience 3, 3 x 16
validation frames) in the sequence form, on rendered clips of 2R + 8 frames (`scene_clips`, loss on the 8 frames
whose receptive field lies inside). Its length is set by time, not steps: the windowed model's card says how long
its training took (`wall_time_s`); the script measures the sequence step here (the fastest of 3 steps after
compilation, on one device, so neither load from other work nor the faster sharded step of the run shortens it) and trains for that time divided by the step
time, rounded up to whole epochs of 4-clip steps. The sequence models therefore get at least the windowed model's
training time (more where this machine is loaded, since the budget counts steps). Runs are resumable: run the
same command again after an interruption. Bundle the results with `bundle_weights.py --form sequence`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp

import jaxsr
from jaxsr.checkpoint import read_metadata
from jaxsr.config import PRESETS, SensorConfig
from jaxsr.data import scene_clips
from jaxsr.model import init_model
from jaxsr.optim import adam_init
from jaxsr.train import fit, make_train_step

from _report import machine

WEIGHTS = Path(jaxsr.__file__).parent / "weights"
EPOCHS = 5


def step_seconds(model_cfg, train_cfg, make_batch, repeats: int = 3) -> float:
    """The fastest of `repeats` train steps after one compiling call (the step fit then reuses: same configs
    and data source hit `make_train_step`'s cache)."""
    step = make_train_step(model_cfg, train_cfg, make_batch)
    params, state = init_model(jax.random.key(0), model_cfg)
    opt = adam_init(params)
    times = []
    for i in range(repeats + 1):
        t0 = time.perf_counter()
        params, state, opt, metrics = step(params, state, opt, jax.random.key(i), jnp.int32(i))
        jax.block_until_ready(metrics)
        times.append(time.perf_counter() - t0)
    return min(times[1:])


def plan(tr: int, run: Path) -> dict:
    """The run's schedule: from run/plan.json when resuming (the budget is fixed once), else measured now."""
    path = run / "plan.json"
    if path.exists():
        return json.loads(path.read_text())
    window_s = read_metadata(WEIGHTS / f"tr{tr}.npz")["card"]["wall_time_s"]
    model_cfg = jaxsr.ModelConfig(tr=tr, temporal="sequence")
    base = PRESETS["bundle"]
    probe = dataclasses.replace(base, examples_per_epoch=base.batch_size)
    step_s = step_seconds(model_cfg, probe, scene_clips(probe.clip_length(model_cfg), probe, sensor=SensorConfig()))
    steps_per_epoch = math.ceil(window_s / step_s / EPOCHS)
    record = {"tr": tr, "window_wall_time_s": window_s, "sequence_step_s": step_s,
              "steps_per_epoch": steps_per_epoch, "epochs": EPOCHS, "machine": machine()}
    run.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=1))
    return record


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trs", type=int, nargs="+", default=[4, 1, 2, 3])
    parser.add_argument("--runs", default="runs/bundle-seq")
    args = parser.parse_args()
    jaxsr.use_cpu_cores()  # both cores as devices, the batch split over them (as `jaxsr train` does)
    for tr in args.trs:
        run = Path(args.runs) / f"tr{tr}"
        p = plan(tr, run)
        print(f"TR{tr}: windowed model trained {p['window_wall_time_s']:.0f} s; sequence step {p['sequence_step_s']:.2f} s "
              f"-> {p['epochs']} x {p['steps_per_epoch']} steps", flush=True)
        model_cfg = jaxsr.ModelConfig(tr=tr, temporal="sequence")
        train_cfg = dataclasses.replace(PRESETS["bundle"], examples_per_epoch=4 * p["steps_per_epoch"], epochs=EPOCHS)
        resume = (run / "last.npz").exists()
        fit(model_cfg, train_cfg, out=run, resume=resume, progress=False,
            callback=lambda r: print(json.dumps({k: r[k] for k in ("epoch", "train_loss", "val_loss", "val_psnr")}),
                                     flush=True))


if __name__ == "__main__":
    main()
