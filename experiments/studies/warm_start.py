"""Warm start against training from scratch: TR k+1 grown from the campaign's trained TR k, on the same data.

    python experiments/studies/warm_start.py --tr 1 [--epochs 2] [--lr 1e-4] [--seed 0] [--campaign runs/campaign]

`jaxsr.nn.grow_tr` carries the trained TR k's stem, blocks and head into the TR k+1 network, draws the added block as
the campaign's TR k+1 run drew it (the same key) and gives the head zero weights on its features, so training
starts from TR k's function. The grown network then trains with the campaign's preset and seed, so on exactly
the data and validation frames of the campaign's run of TR k+1 from random weights (runs/campaign/s<seed>/tr<k+1>):
the two validation curves are paired, epoch by epoch. Both train the same TR k+1 network, so equal steps are equal
CPU time for that part; the warm start also uses TR k's training, which costs nothing extra when TR k is trained
anyway (as for a sweep over TR) and is shown for the case where it is not. `--lr` trains the warm run at another
rate than the preset's (a trained start may need a smaller step). Resumable: each run lives in
runs/warm_start/s<seed>/tr<k+1>-from-tr<k>[-lr<rate>] with the TR k weights it grew from (init.npz); a second
call with more --epochs continues it. Writes experiments/results/warm_start_tr<k+1>.md with every rate run so far.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import shutil
import sys
import time
from pathlib import Path

import jaxsr
from jaxsr.config import PRESETS
from jaxsr.training.data import run_keys, validation_set
from jaxsr.nn import init_model
from jaxsr.training import evaluate, fit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import BLOCK, SCENE_LABELS, TEST_SCENES, format_interval, interval, scene_scores, test_clips  # noqa: E402
from harness.reports import header, markdown_table, write_atomic  # noqa: E402
from harness.runs import CAMPAIGN_PRESET as PRESET  # noqa: E402
from harness.runs import history, run_dir  # noqa: E402


@functools.cache
def fit_validation(tr: int, train_cfg) -> dict:
    """The validation windows `fit` uses for a run of `tr` with `train_cfg` (rendered once per TR)."""
    return validation_set(run_keys(train_cfg.seed)[2], tr, train_cfg)


def start_psnr(model, train_cfg) -> float:
    """Validation PSNR (dB) of `model` before any training step, on the frames `fit` validates on."""
    val = fit_validation(model.config.tr, train_cfg)
    return evaluate(model.params, model.state, val["windows"], val["gt"], model.config)["psnr"]


def test_scene_section(frames: int, checkpoints: dict) -> str:
    """The checkpoints (label -> best.npz) on the test scenes, each against the first (the start) and the
    second (from scratch) with paired frame intervals: a markdown section."""
    clips = test_clips(frames, spread=True)
    rows, per_frame = [], {}
    for label, path in checkpoints.items():
        means, per_frame[label] = scene_scores(jaxsr.load_model(path), clips)
        steps = jaxsr.read_metadata(path).get("card", {}).get("steps", "?")  # the checkpoint's own steps
        rows.append([label, str(steps), *(f"{means[n][0]:.2f}" for n in TEST_SCENES),
                     f"{per_frame[label].mean(-1).mean():.2f}"])
    start, scratch = list(per_frame)[:2]
    for row, label in zip(rows, per_frame):
        row += ["-" if label == ref else format_interval(interval(per_frame[label], per_frame[ref]))
                for ref in (start, scratch)]
    return (f"\n## Test scenes\n\nEach run's selected weights (best.npz: lowest validation loss; steps of that "
            f"checkpoint) on {frames} frames spread over each 500-frame test scene (as sweep_tr.py), PSNR (dB); "
            f"differences of the mean over the scenes with 95 % paired intervals over blocks of {BLOCK} frames "
            "(the choice of frames, not retraining).\n\n"
            + markdown_table(["weights", "steps", *(SCENE_LABELS[n] for n in TEST_SCENES), "mean",
                              f"- {start}", f"- {scratch}"], rows))


def variant_dir(runs: Path, seed: int, tr: int, lr: float | None) -> Path:
    """The warm run's folder: one per TR and learning rate (None: the preset's)."""
    name = f"tr{tr}-from-tr{tr - 1}" + ("" if lr is None else f"-lr{lr:g}")
    return runs / f"s{seed}" / name


def rates_run(runs: Path, seed: int, tr: int) -> list:
    """The learning rates of the warm runs of `tr` under `runs` (None: the preset's first), from their folders."""
    base = variant_dir(runs, seed, tr, None).name
    rates = [None] if (runs / f"s{seed}" / base).is_dir() else []
    for d in (runs / f"s{seed}").glob(f"{base}-lr*"):
        try:
            rates.append(float(d.name[len(base) + 3:]))
        except ValueError:  # not a folder this script made
            continue
    return sorted(rates, key=lambda v: -1.0 if v is None else v)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tr", type=int, required=True, help="the TR to train (grown from the campaign's TR - 1)")
    parser.add_argument("--epochs", type=int, default=2, help="epochs of the warm-started run in all")
    parser.add_argument("--lr", type=float, default=None,
                        help="the warm run's learning rate (default: the preset's, as the run from scratch)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--campaign", default="runs/campaign")
    parser.add_argument("--runs", default="runs/warm_start")
    parser.add_argument("--frames", type=int, default=100, help="test frames scored per scene (spread over 500)")
    args = parser.parse_args()
    if args.tr < 1:
        parser.error("--tr must be >= 1 (TR0 has no smaller TR to grow from)")
    if args.lr is not None and not args.lr > 0:
        parser.error(f"--lr must be > 0, got {args.lr}")
    started = time.time()
    jaxsr.runtime.use_cpu_cores()
    small_run = run_dir(Path(args.campaign), args.seed, args.tr - 1)
    scratch_run = run_dir(Path(args.campaign), args.seed, args.tr)
    out = variant_dir(Path(args.runs), args.seed, args.tr, args.lr)
    init = out / "init.npz"  # the TR k weights this run grew from (the campaign's best.npz moves on)
    if not init.exists():
        if not (small_run / "best.npz").exists():
            raise SystemExit(f"no trained TR{args.tr - 1} in {small_run}: run experiments/paper/campaign.py first")
        out.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(small_run / "best.npz", init)
    preset = PRESETS[PRESET]
    cfg = dataclasses.replace(preset, seed=args.seed, epochs=args.epochs, lr=preset.lr if args.lr is None else args.lr)
    done = history(out)
    if len(done) < args.epochs:
        fit(jaxsr.ModelConfig(tr=args.tr), cfg, out=out, resume=bool(done), init=init, progress=False)

    small = jaxsr.load_model(init)
    k_init = run_keys(args.seed)[0]  # the key fit grew the added block with
    grown = jaxsr.nn.grow_tr(k_init, small, args.tr)
    starts = {"TR k": start_psnr(small, cfg), "grown": start_psnr(grown, cfg),
              "random": start_psnr(jaxsr.Model(*init_model(k_init, grown.config), grown.config), cfg)}
    card = jaxsr.read_metadata(init).get("card", {})
    scratch = {r["epoch"]: r for r in history(scratch_run)}
    variants = {lr: h for lr in rates_run(Path(args.runs), args.seed, args.tr)
                if (h := history(variant_dir(Path(args.runs), args.seed, args.tr, lr)))}
    label = {lr: f"warm, lr {preset.lr if lr is None else lr:g}" for lr in variants}
    epochs = sorted({r["epoch"] for h in variants.values() for r in h})
    rows = [["0 (start)", "0", f"{starts['random']:.2f}"]
            + [f"{starts['grown']:.2f} ({starts['grown'] - starts['random']:+.2f})" for _ in variants]]
    for e in epochs:
        s = scratch.get(e)
        cells = []
        for h in variants.values():
            w = next((r for r in h if r["epoch"] == e), None)
            cells.append("-" if w is None else f"{w['val_psnr']:.2f}"
                         + ("" if s is None else f" ({w['val_psnr'] - s['val_psnr']:+.2f})"))
        rows.append([str(e), str(e * cfg.steps_per_epoch), "-" if s is None else f"{s['val_psnr']:.2f}", *cells])
    later = [r for e, r in sorted(scratch.items()) if e > max(epochs, default=0)]
    text = header(f"Warm start: TR{args.tr} grown from a trained TR{args.tr - 1} against TR{args.tr} from scratch",
                  started)
    text += (f"Every run trains TR{args.tr} with the `{PRESET}` preset, seed {args.seed}: the same training batches "
             f"and the same validation frames (3 x {cfg.val_frames}; validation PSNR in dB, in brackets the "
             f"difference to the run from scratch at the same step). From scratch: the campaign's run "
             f"{scratch_run} (random weights, lr {preset.lr:g}). Warm: `fit(init=...)` of TR{args.tr - 1}'s "
             f"best.npz of the campaign at the time (copied to init.npz in the run folder: "
             f"{card.get('steps', '?')} steps, {card.get('wall_time_s', 0) / 60:.0f} min of training on "
             f"its card; its own validation PSNR {starts['TR k']:.2f} dB), grown by `jaxsr.nn.grow_tr` with the "
             f"scratch run's key for the added block, into {out.parent}/. Row 0 is before any step (the grown "
             f"network reads real frames where TR{args.tr - 1}'s padded blocks read zeros, hence the change from "
             f"TR{args.tr - 1}'s own score). Equal steps are equal CPU time for the TR{args.tr} runs; counting "
             f"TR{args.tr - 1}'s training as well, the warm start had spent that much more (nothing more when "
             "that TR is trained anyway, as in a sweep over TR).\n\n")
    text += markdown_table(["epoch", "steps", "from scratch", *label.values()], rows)
    if later:
        text += ("\nFrom scratch, later epochs: " + ", ".join(f"epoch {r['epoch']} {r['val_psnr']:.2f}"
                                                          for r in later) + ".\n")
    text += test_scene_section(args.frames, {f"TR{args.tr - 1} (the start)": init,
                                            f"TR{args.tr} from scratch": scratch_run / "best.npz",
                                            **{label[lr]: variant_dir(Path(args.runs), args.seed, args.tr, lr)
                                               / "best.npz" for lr in variants}})
    out_md = Path("experiments/results") / f"warm_start_tr{args.tr}.md"
    write_atomic(str(out_md), text)
    print(text)


if __name__ == "__main__":
    main()
