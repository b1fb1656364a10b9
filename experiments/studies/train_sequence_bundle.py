"""Train the sequence-form models for the bundle at the training time of the windowed bundled model of each TR.

    python experiments/studies/train_sequence_bundle.py [--trs 4 1 2 3] [--runs runs/bundle-seq]

Each TR: the `bundle` preset (batch 4, 16 x 32 LR crops, 5 epochs, the rate cut for the last, patience 3, 3 x 16
validation frames) in the sequence form, on rendered clips of 2R + 8 frames (`scene_clips`, loss on the 8 frames
whose receptive field lies inside). Its length is set by time, not steps: the script times the windowed and the
sequence train step here, interleaved (the fastest of 3 steps of each after compilation, one device), and gives
the sequence model the windowed bundle's 1280 steps times the ratio of the two step times, rounded up to whole
epochs: the same training time as the windowed model of its TR, measured as a ratio on one machine in one run,
so that load from other work cancels. (TR4's run of 2026-11-23 was planned by an earlier rule, its step time
against the windowed card's wall time on another machine; its plan.json and card record it.) Runs are
resumable: run the same command again after an interruption. Bundle them with `bundle_weights.py --form sequence`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

import jax

import jaxsr
from jaxsr.io.checkpoint import read_metadata, resolve_model_path
from jaxsr.config import PRESETS
from jaxsr.nn import init_model
from jaxsr.training.optim import adam_init
from jaxsr.training import default_data, fit, make_train_step

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import machine, step_timer, write_atomic  # noqa: E402

EPOCHS = 5


def _probe(model_cfg, train_cfg):
    """A compiled train step of `model_cfg` on its default data, with fresh weights: a callable running one step."""
    step = make_train_step(model_cfg, train_cfg, default_data(model_cfg, train_cfg))
    params, state = init_model(jax.random.key(0), model_cfg)
    return step_timer(step, [params, state, adam_init(params)])


def step_seconds(tr: int, repeats: int = 3) -> dict:
    """The fastest of `repeats` train steps of each form of TR`tr` on the bundle preset, timed in turn."""
    probe = dataclasses.replace(PRESETS["bundle"], examples_per_epoch=PRESETS["bundle"].batch_size)
    runs = {form: _probe(jaxsr.ModelConfig(tr=tr, temporal=form), probe) for form in ("window", "sequence")}
    times = {form: [] for form in runs}
    for i in range(1, repeats + 1):
        for form, run in runs.items():
            times[form].append(run(i))
    return {form: min(t) for form, t in times.items()}


def plan(tr: int, run: Path) -> dict:
    """The run's schedule: from run/plan.json when resuming (the budget is fixed once), else measured now."""
    path = run / "plan.json"
    if path.exists():
        return json.loads(path.read_text())
    window_steps = read_metadata(resolve_model_path(f"tr{tr}"))["card"]["steps"]
    seconds = step_seconds(tr)
    steps_per_epoch = math.ceil(window_steps * seconds["window"] / seconds["sequence"] / EPOCHS)
    record = {"tr": tr, "rule": "windowed steps x window step / sequence step, timed in one run",
              "window_steps": window_steps, "window_step_s": seconds["window"], "sequence_step_s": seconds["sequence"],
              "steps_per_epoch": steps_per_epoch, "epochs": EPOCHS, "machine": machine()}
    run.mkdir(parents=True, exist_ok=True)
    write_atomic(str(path), json.dumps(record, indent=1))
    return record


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trs", type=int, nargs="+", default=[4, 1, 2, 3])
    parser.add_argument("--runs", default="runs/bundle-seq")
    args = parser.parse_args()
    jaxsr.runtime.use_cpu_cores()  # both cores as devices, the batch split over them (as `jaxsr train` does)
    for tr in args.trs:
        run = Path(args.runs) / f"tr{tr}"
        p = plan(tr, run)
        print(f"TR{tr}: {json.dumps(p)}", flush=True)
        model_cfg = jaxsr.ModelConfig(tr=tr, temporal="sequence")
        train_cfg = dataclasses.replace(PRESETS["bundle"], examples_per_epoch=4 * p["steps_per_epoch"], epochs=EPOCHS)
        fit(model_cfg, train_cfg, out=run, resume=True, progress=False,  # an empty folder starts afresh
            callback=lambda r: print(json.dumps({k: r[k] for k in ("epoch", "train_loss", "val_loss", "val_psnr")}),
                                     flush=True))


if __name__ == "__main__":
    main()
