"""Train the learned baselines of Table 3 (HistNet, iSeeBetter) on our data at the compute of a bundled TR model.

    python experiments/paper/train_baselines.py histnet [--runs runs/baselines] [--bundle]
    python experiments/paper/train_baselines.py iseebetter [--runs runs/baselines] [--bundle]
    python experiments/paper/train_baselines.py report [--runs runs/baselines]  # experiments/results/train_baselines.md

Data: the bundled TR models' (`bundle` preset: batch 4, 16 x 32 LR crops of freshly rendered training clips, SNR
0.5-8, 7-28 signal photons; validation on the first 16 frames of the three validation sequences), in each
baseline's form (the baseline's training recipe, `jaxsr.training.recipe(cfg).data`). Schedule: the bundle's 5 epochs,
Adam 1e-3 cut to 1e-4 for the last epoch, patience 3, the best epoch's weights kept (validation loss: each baseline's
own content loss, HistNet L1, iSeeBetter MSE). iSeeBetter follows its authors' recipe, a GAN started from a
pre-trained generator: its first `PRETRAIN_EPOCHS` epochs train the RBPN generator alone on the MSE, the last one
adds the discriminator and the adversarial term (at the cut rate 1e-4, the published one). A first run that had
the GAN from the first step stayed below bicubic (its discriminator won early).

Budget (the rule of `train_sequence_bundle.py`): the comparable bundled TR model trained 1280 steps of batch 4;
the baseline gets 1280 x (TR step time / baseline step time) steps, rounded up to whole epochs, both steps timed
here interleaved in one run (the fastest of 3 after compilation, one JAX device), so that load from other work
cancels. The comparable TR is the one of nearest cost per output frame (`COMPARABLE`, GFLOP from XLA's cost
analysis of one 32 x 64 frame):
- HistNet at width 16 (2.85 M parameters, 4.2 GFLOP per frame, single-frame) against TR0 (3.6 GFLOP);
- iSeeBetter's RBPN reduced to 5 frames, base_filter 64, feat 16, 2 residual blocks (0.55 M parameters, 13.4
  GFLOP per frame including the flow) against TR2 (12.2 GFLOP), which reads the same 5-frame window. The
  published RBPN (12.7 M parameters, 7 frames) costs 567 GFLOP per frame, 20x TR4: at TR4's budget it would get
  about 60 steps.

For iSeeBetter the baseline step time is the mean over the epochs of the generator-only and the GAN step times
(each timed as above), so that both phases together cost the comparable TR's training.

The plan (budget, timings, machine) is written once to runs/baselines/<name>/plan.json; run the same command
again to resume an interrupted run. `--bundle` then stores the best weights in jaxsr/weights/<name>.npz
(float16, with their training card and the float16 cost measured on the validation frames) for
`jaxsr.load_model(name)`.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import math
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

import jaxsr
from jaxsr.training import baseline_validation_set, evaluate_baseline, recipe
from jaxsr.io.checkpoint import read_metadata, resolve_model_path
from jaxsr.config import PRESETS
from jaxsr.nn import count_params, init_model
from jaxsr.training.optim import adam_init
from jaxsr.training.data import validation_set
from jaxsr.training import default_data, evaluate, make_train_step

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import machine, step_timer, write_atomic  # noqa: E402

EPOCHS = 5
TR_STEPS = 1280  # the bundled windowed models' steps (their cards)
CONFIGS = {
    "histnet": jaxsr.baselines.HistNetConfig(width=16),
    "iseebetter": jaxsr.baselines.RBPNConfig(base_filter=64, feat=16, n_resblock=2, frames=5),
}
COMPARABLE = {"histnet": 0, "iseebetter": 2}  # the TR of nearest GFLOP per output frame (module docstring)
PRETRAIN_EPOCHS = {"histnet": 0, "iseebetter": EPOCHS - 1}  # generator-only epochs before the GAN (docstring)


def tr_probe(tr: int):
    """One windowed TR`tr` train step on the bundle preset, fresh weights: run(i) -> seconds."""
    cfg = jaxsr.ModelConfig(tr=tr)
    probe = dataclasses.replace(PRESETS["bundle"], examples_per_epoch=PRESETS["bundle"].batch_size)
    step = make_train_step(cfg, probe, default_data(cfg, probe))
    params, state = init_model(jax.random.key(0), cfg)
    return step_timer(step, [params, state, adam_init(params)])


def baseline_probe(name: str, train_cfg, *, pretrain: bool = False):
    """One train step of baseline `name` as the run takes it, fresh weights: run(i) -> seconds. pretrain: the
    generator-only step of iSeeBetter's first epochs instead of the GAN step."""
    cfg = CONFIGS[name]
    pretrain_steps = 1 << 30 if pretrain else 0  # every timed step in the phase asked for
    how = recipe(cfg)  # the probe starts from fresh weights as the run does
    step = how.step(cfg, train_cfg, how.data(cfg, train_cfg, jaxsr.Sensor()), pretrain_steps=pretrain_steps)
    ts = [how.init(jax.random.key(0), cfg, None)]
    return step_timer(lambda t, key, i: step(t, key, i), ts)


def step_seconds(probes: dict, repeats: int = 3) -> dict:
    """The fastest of `repeats` calls of each probe, called in turn (so that load from other work falls on all)."""
    times = {k: [] for k in probes}
    for i in range(1, repeats + 1):
        for k, run in probes.items():
            times[k].append(run(i))
    return {k: min(t) for k, t in times.items()}


def budget(tr_steps: int, tr_step_s: float, baseline_step_s: float, epochs: int = EPOCHS) -> int:
    """Steps per epoch of the baseline: tr_steps x tr_step_s / baseline_step_s, rounded up to whole epochs."""
    if not (tr_step_s > 0 and baseline_step_s > 0 and tr_steps > 0 and epochs > 0):
        raise ValueError(f"budget: need positive steps and step times, got {tr_steps}, {tr_step_s}, {baseline_step_s}")
    return math.ceil(tr_steps * tr_step_s / baseline_step_s / epochs)


def plan(name: str, run: Path, *, measure=None) -> dict:
    """The run's budget: read from run/plan.json when it exists (fixed once), else measured now and written there
    atomically. measure: () -> {"tr": s, "baseline": s} step times (default: `step_seconds` of the two probes)."""
    path = run / "plan.json"
    if path.exists():
        return json.loads(path.read_text())
    tr = COMPARABLE[name]
    card = read_metadata(resolve_model_path(f"tr{tr}"))["card"]
    tr_steps = card["steps"]
    pre = PRETRAIN_EPOCHS[name]
    if measure is None:
        train_cfg = train_config(1)
        probes = {"tr": tr_probe(tr), "baseline": baseline_probe(name, train_cfg)}
        if pre:
            probes["generator"] = baseline_probe(name, train_cfg, pretrain=True)
        measure = lambda: step_seconds(probes)
    seconds = measure()
    mean_step = ((pre * seconds["generator"] if pre else 0.0) + (EPOCHS - pre) * seconds["baseline"]) / EPOCHS
    record = {
        "baseline": name, "config": dataclasses.asdict(CONFIGS[name]), "comparable_tr": tr,
        "rule": f"TR{tr}'s {tr_steps} steps x TR{tr} step time / baseline step time (its mean over the epochs' "
                "phases; each the fastest of 3, timed in turn in one run, one JAX device), rounded up to whole epochs",
        "tr_steps": tr_steps, "tr_step_s": seconds["tr"], "baseline_step_s": seconds["baseline"],
        "pretrain_epochs": pre, "generator_step_s": seconds.get("generator"), "mean_step_s": mean_step,
        "tr_card_wall_time_s": card.get("wall_time_s"),
        "steps_per_epoch": budget(tr_steps, seconds["tr"], mean_step), "epochs": EPOCHS,
        "machine": machine(), "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="minutes"),
    }
    run.mkdir(parents=True, exist_ok=True)
    write_atomic(str(path), json.dumps(record, indent=1))
    return record


def train_config(steps_per_epoch: int, base=PRESETS["bundle"]):
    """The bundle preset with `steps_per_epoch` steps per epoch and `EPOCHS` epochs (the rate cut for the last)."""
    return dataclasses.replace(base, examples_per_epoch=base.batch_size * steps_per_epoch, epochs=EPOCHS,
                               decay_epochs=EPOCHS - 1)


def bundle(name: str, run: Path, out: Path, p: dict) -> None:
    """Store the run's best weights as float16 in `out` with the card, the plan and the float16 cost."""
    model = jaxsr.load_model(run / "best.npz")
    meta = read_metadata(run / "best.npz")
    train_cfg = train_config(p["steps_per_epoch"])
    val = baseline_validation_set(jax.random.fold_in(jax.random.key(train_cfg.seed), 2), name, model.config, train_cfg)
    full = evaluate_baseline(model, val)
    half = jaxsr.Model(jax.tree_util.tree_map(lambda x: x.astype(jnp.float16).astype(jnp.float32), model.params),
                       {}, model.config)
    run_meta = read_metadata(run / "last.npz")["run"]  # the whole run; the card is the kept epoch's
    whole = {"steps": run_meta["step"], "epochs": run_meta["epoch"], "wall_time_s": run_meta["wall_time_s"],
             "planned_steps": p["steps_per_epoch"] * p["epochs"],
             "finished": run_meta["epoch"] >= p["epochs"] or run_meta["bad_epochs"] >= train_cfg.patience,
             "cpu_minutes": round(run_meta["wall_time_s"] * _cores() / 60, 1),
             "cpu_minutes_note": f"wall time x {_cores()} cores; the cores were shared with other work"}
    card = dict(meta["card"], plan=p, run=whole, parameters=count_params(model.params),
                float16_cost_db=full["psnr"] - evaluate_baseline(half, val)["psnr"],
                bundled=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="minutes"))
    path = jaxsr.save_model(out, model, card=card, storage_dtype="float16")
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB): val PSNR {full['psnr']:.2f} dB, float16 cost "
          f"{card['float16_cost_db']:+.4f} dB")


def gflops_per_frame(name: str, lr_shape=(32, 64)) -> float:
    """GFLOP of one output frame of baseline `name` at `lr_shape` LR pixels, from XLA's cost analysis of the
    forward pass (flow and histogram features included)."""
    cfg = CONFIGS[name]
    h, w = lr_shape
    params, _ = jaxsr.nn.architecture(cfg).template(cfg)
    if name == "histnet":
        fn = lambda p, c, i: jaxsr.baselines.apply_histnet(p, c, i, cfg)
        args = (jax.ShapeDtypeStruct((1, h, w, 16), jnp.float32), jax.ShapeDtypeStruct((1, 4 * h, 4 * w), jnp.float32))
    else:
        fn = lambda p, x: jaxsr.baselines.apply_rbpn(p, x, cfg)
        args = (jax.ShapeDtypeStruct((1, cfg.frames, h, w), jnp.float32),)
    cost = jax.jit(fn).lower(params, *args).cost_analysis()
    cost = cost[0] if isinstance(cost, (list, tuple)) else cost
    return cost["flops"] / 1e9


def report(runs: Path, out: str) -> None:
    """experiments/results/train_baselines.md: each run's plan, cost and validation PSNR per epoch."""
    from harness.reports import header, markdown_table

    started = time.time()
    rows, epochs, plans, from_card = [], [], {}, []
    for name in CONFIGS:
        p, hist, whole = run_record(runs / name, Path(jaxsr.__file__).parent / "weights" / f"{name}.npz")
        if p is None:
            print(f"{name}: no run in {runs / name} and no bundled weights, left out")
            continue
        plans[name] = p
        if hist is None:
            from_card.append(name)
        params = count_params(jaxsr.nn.architecture(CONFIGS[name]).template(CONFIGS[name])[0])
        tr = p["comparable_tr"]
        rows.append([name, ", ".join(f"{k} {v}" for k, v in p["config"].items() if k not in ("disc_widths",)),
                     f"{params / 1e6:.2f} M", f"{gflops_per_frame(name):.1f}",
                     f"TR{tr} ({jaxsr.nn.duf.flops_per_frame(jaxsr.ModelConfig(tr=tr)) / 1e9:.1f})",
                     f"{p['tr_step_s']:.3f} / {p.get('mean_step_s', p['baseline_step_s']):.3f}",
                     f"{p['steps_per_epoch'] * p['epochs']}", f"{whole['steps']}",
                     f"{whole['wall_time_s'] / 60:.1f} ({whole['wall_time_s'] * _cores() / 60:.0f})",
                     f"{whole['best_psnr']:.2f} (epoch {whole['best_epoch']})", tr_on_same_frames(tr, p)])
        epochs += [[name, r["epoch"], r["step"], f"{r.get('train_loss', r.get('train_content', float('nan'))):.4g}",
                    f"{r['val_loss']:.4g}", f"{r['val_psnr']:.2f}", f"{r['wall_time_s'] / 60:.1f}"]
                   for r in hist or ()]
    text = header("Training the learned baselines (HistNet, iSeeBetter) on our data", started)
    text += ("`experiments/paper/train_baselines.py` (its docstring has the rule): each baseline gets the steps of the "
             "bundled TR model of nearest cost per output frame times the ratio of the two train-step times, both "
             "timed in turn in one run on the machine of the plan (so that load from other work cancels). Data: the "
             "bundle preset (batch 4, 16 x 32 LR crops of rendered training clips, SNR 0.5-8); validation on 3 x 16 "
             "frames of the validation sequences, each baseline's own content loss (HistNet L1, iSeeBetter MSE) "
             "selecting the kept epoch. iSeeBetter (since 2026-11-24): its first epochs (`pretrain_epochs` in the "
             "plan) train the generator alone on the MSE, the last adds the GAN, and its step time is the mean "
             "over the phases. GFLOP per 32 x 64 frame: XLA's cost analysis of the forward pass; ours "
             "`jaxsr.nn.duf.flops_per_frame`. Wall minutes on 2 CPU cores shared with other work (CPU-minutes = wall "
             "x 2 cores in brackets). Last column: the bundled TR model of comparable cost and bicubic on the same "
             "validation frames and noise, measured when this report was written.\n\n")
    text += ("Runs: `python experiments/paper/train_baselines.py NAME` (plan, then training; re-run to resume), then "
             "`--bundle` (or `--bundle-only` for a run stopped early) for jaxsr/weights/NAME.npz. "
             + " ".join(f"{n}: planned {pl['date']} on {pl['machine']}; the comparable TR's own training took "
                        f"{pl['tr_card_wall_time_s'] / 60:.1f} wall minutes (its card, another machine and load)."
                        for n, pl in plans.items()) + "\n\n")
    text += markdown_table(["baseline", "config", "parameters", "GFLOP/frame", "comparable (GFLOP/frame)",
                            "step s: TR / baseline", "planned steps", "steps done", "wall min (CPU-min)",
                            "best val PSNR dB", "bundled TR val PSNR (bicubic)"], rows)
    if from_card:
        text += (f"\n{', '.join(from_card)}: trained on another machine (its run folder is not here); its row is "
                 "read from the bundled file's card, its per-epoch rows are in the git history of this report.\n")
    text += "\nPer epoch:\n\n" + markdown_table(["baseline", "epoch", "step", "train loss", "val loss",
                                                   "val PSNR dB", "wall min"], epochs)
    write_atomic(out, text)
    print(f"wrote {out}")


def run_record(run: Path, bundled: Path):
    """(plan, per-epoch history or None, {"steps", "wall_time_s", "best_psnr", "best_epoch"}) of a baseline's run:
    from its folder when it is here, else from the bundled file's card (history None); (None, None, None) when
    neither exists."""
    if (run / "plan.json").is_file():
        hist = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()] if (
            run / "metrics.jsonl").is_file() else []
        best = min(hist, key=lambda r: r["val_loss"]) if hist else {"val_psnr": float("nan"), "epoch": 0}
        return json.loads((run / "plan.json").read_text()), hist, {
            "steps": hist[-1]["step"] if hist else 0, "wall_time_s": hist[-1]["wall_time_s"] if hist else 0.0,
            "best_psnr": best["val_psnr"], "best_epoch": best["epoch"]}
    if not bundled.is_file():
        return None, None, None
    card = read_metadata(bundled)["card"]
    return card["plan"], None, {"steps": card["run"]["steps"], "wall_time_s": card["run"]["wall_time_s"],
                                "best_psnr": card["validation"]["psnr"], "best_epoch": card["best_epoch"] + 1}


def tr_on_same_frames(tr: int, p: dict) -> str:
    """The bundled TR model's and bicubic's mean PSNR on the baseline's validation frames (`jaxsr.fit`'s key and
    frames for the plan's training config), measured now: "28.17 (22.53)"."""
    train_cfg = train_config(p["steps_per_epoch"])
    val = validation_set(jax.random.fold_in(jax.random.key(train_cfg.seed), 2), tr, train_cfg)
    model = jaxsr.load_model(f"tr{tr}")
    ours = evaluate(model.params, model.state, val["windows"], val["gt"], model.config)["psnr"]
    bicubic = float(jnp.mean(jaxsr.psnr(jnp.clip(jaxsr.bicubic(val["lr"], scale=4), 0, 1), val["gt"])))
    return f"{ours:.2f} ({bicubic:.2f})"


def _cores() -> int:
    import os

    return os.cpu_count() or 1


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("name", choices=[*sorted(CONFIGS), "report"])
    parser.add_argument("--runs", default="runs/baselines")
    parser.add_argument("--bundle", action="store_true", help="store the best weights in jaxsr/weights/<name>.npz")
    parser.add_argument("--bundle-only", action="store_true",
                        help="bundle the best weights reached so far without training on (an unfinished run's card "
                             "says how far it got; the same command without it resumes the run)")
    parser.add_argument("--weights-dir", default=str(Path(jaxsr.__file__).parent / "weights"))
    parser.add_argument("--out", default="experiments/results/train_baselines.md", help="the report's file")
    args = parser.parse_args()
    if args.name == "report":
        report(Path(args.runs), args.out)
        return
    run = Path(args.runs) / args.name
    p = plan(args.name, run)
    print(json.dumps(p), flush=True)
    train_cfg = train_config(p["steps_per_epoch"])
    if not args.bundle_only:
        jaxsr.fit(CONFIGS[args.name], train_cfg, out=run, resume=True, card_extra={"plan": p},
                  pretrain_epochs=p.get("pretrain_epochs", 0), progress=False,
                  callback=lambda r: print(json.dumps(r), flush=True))
    if args.bundle or args.bundle_only:
        bundle(args.name, run, Path(args.weights_dir) / f"{args.name}.npz", p)


if __name__ == "__main__":
    main()
