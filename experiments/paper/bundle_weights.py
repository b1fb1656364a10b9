"""Package trained models as the bundled weights (jaxsr/weights/tr<N>.npz), stored as float16 when that costs
under 0.05 dB, each with its training card; writes experiments/results/weights.md.

    python experiments/paper/bundle_weights.py --runs runs/bundle [--trs 0 1 2 3 4] [--checkpoint select] [--force]
    python experiments/paper/bundle_weights.py --form sequence --runs runs/bundle-seq --trs 1 2 3 4 [--force]
    python experiments/paper/bundle_weights.py --runs runs/campaign/s0 \
        --trained-with "python experiments/paper/campaign.py"
    python experiments/paper/bundle_weights.py --measure-forms [--trs 0 1 2 3 4] [--form-frames 48]

The window-form models come from `jaxsr train --tr N --preset bundle -o runs/bundle/trN` and are bundled as
tr<N>.npz (results/weights.md); the sequence-form models from `experiments/studies/train_sequence_bundle.py` and are
bundled as tr<N>-seq.npz (`jaxsr.load_model("tr4-seq")`; results/weights_sequence.md). `--checkpoint select` (the
default) bundles whichever of best.npz (the epoch with the lowest validation loss during training) and last.npz
(the final epoch) has the higher mean PSNR on the presets' three validation sequences (their first --frames
frames, 64 by default, with noise other than training's validation; never the test scenes). Until 2026-11-24 those
were val1_street, val2_road and val3_courtyard, two of which move the camera out of the modelled scene (val1 has
31 % of its pixels beyond the depth range over 500 frames and bicubic falls from 20.5 dB on its first 8 frames to
6-8 dB after frame 200), so only their first 64-80 frames were like the test scenes; since then they are
val4_street, val2_road and val5_courtyard, all with static cameras. In a schedule as short as the bundle
preset's, the training-time choice rests on
3 x 16 frames and on the Huber loss, which can disagree with PSNR. The
float16 cost is measured on the same frames: the mean PSNR of the float32 model minus that of the float16 one.
`--keep-better` (for runs that continue across sessions, such as the campaign's) lets the bundled model of each TR
compete on the same frames: a run's model replaces it only when, as stored, it scores higher; otherwise the
bundled file is left untouched and its row says so.

Each windowed model reading depth alone is also run in the sequence form on the first --form-frames frames of the
three test scenes (`jaxsr.inference.measure_form_equivalence`), and the record goes into its card under "forms"
(`jaxsr.io.checkpoint.FORMS_CARD_KEY`): where both forms' PSNR agree within `FORM_TOLERANCE_DB`, over all those
frames and over the first and last R frames alone, `form="auto"` runs the weights in the sequence form
(`Model.equivalent_forms`). Bundling measures it whenever it writes weights; `--measure-forms` measures the bundled
files of --trs again and rewrites only their cards (the arrays stay bit-identical).
"""

from __future__ import annotations

import argparse
import functools
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

import jaxsr
from jaxsr import scenes
from jaxsr.io.checkpoint import save_model
from jaxsr.config import TrainConfig

from jaxsr.inference import measure_form_equivalence
from jaxsr.io.checkpoint import FORMS_CARD_KEY

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import scene_scores, simulate_clip, test_clips  # noqa: E402
from harness.reports import header, markdown_table, write_atomic  # noqa: E402

WEIGHTS = Path(jaxsr.__file__).parent / "weights"
VALIDATION = TrainConfig().val_sequences
MAX_COST_DB = 0.05
FORM_FRAMES = 48  # test-scene frames per scene for the form measurement: about a minute per model on 2 cores
SUFFIX = {"window": "", "sequence": "-seq"}  # bundled file names: tr4.npz, tr4-seq.npz


@functools.cache
def validation_clips(frames: int) -> dict:
    """The first `frames` frames of each validation sequence (see the module docstring), simulated with noise of
    their own (not training's)."""
    seqs = scenes.test_sequences(n_frames=frames, names=VALIDATION)
    return {n: simulate_clip(jax.random.key(7000 + i), seqs[n]) for i, n in enumerate(VALIDATION)}


@functools.cache
def form_clips(frames: int) -> dict:
    """The first `frames` frames of the three test scenes, simulated at their SNR (noise seed 0)."""
    return test_clips(frames)


def form_record(model, frames: int) -> dict:
    """The card's record of `model` in the sequence form against its window form, on the first `frames` frames of
    the test scenes (noise seed 0), as stored (float16 weights where they are stored so)."""
    clips = form_clips(frames)
    record = measure_form_equivalence(model, [(c.lr, c.gt) for c in clips.values()])
    return dict(record, measured=(f"jaxsr.inference.measure_form_equivalence: {', '.join(clips)}, first {frames} "
                                  f"frames each (jaxsr.eval.scoring.test_clips, noise seed 0), precision default on "
                                  f"{jax.default_backend()}, jaxsr {jaxsr.__version__}, {time.strftime('%Y-%m-%d')}"))


def measure_forms(trs, frames: int) -> None:
    """Measure the bundled windowed depth models of `trs` in the sequence form again and rewrite their cards'
    "forms" record, the arrays (and their storage dtype) unchanged: checked bit for bit after writing."""
    for tr in trs:
        target = WEIGHTS / f"tr{tr}.npz"
        meta = jaxsr.read_metadata(target)
        model = jaxsr.load_model(target)
        if model.reads_photons or model.form != "window":
            print(f"tr{tr}: not a windowed model reading depth alone; skipped", flush=True)
            continue
        record = form_record(model, frames)
        before = np.load(target)
        arrays = {k: before[k] for k in before.files if k != "__metadata__"}
        card = dict(meta["card"], **{FORMS_CARD_KEY: {"sequence": record}})
        save_model(target, model, card=card, storage_dtype=meta["storage_dtype"])
        after = np.load(target)
        same = set(after.files) - {"__metadata__"} == set(arrays) and all(
            after[k].dtype == v.dtype and np.array_equal(after[k], v) for k, v in arrays.items())
        if not same:
            raise SystemExit(f"{target}: the arrays changed on rewriting the card; restore it from git")
        print(f"tr{tr}: {record}", flush=True)


def mean_psnr(model, clips) -> float:
    """Mean over the validation sequences of the model's PSNR on their scored frames."""
    return float(np.mean([p for p, _ in scene_scores(model, clips)[0].values()]))


def schedule(args) -> str:
    """The training command of the runs, without the TR, and what it is."""
    if args.trained_with:
        return f"`{args.trained_with}`"
    return ("`jaxsr train --preset bundle`" if args.form == "window" else
            "`experiments/studies/train_sequence_bundle.py` (the bundle preset in the sequence form, clips of 2R + 8 "
            "frames, as long as the windowed model of its TR trained: see that script)")


def describe(tc: dict) -> str:
    """The training schedule of a card's train_config, in words."""
    crops = "whole LR frames" if tc["patch"] is None else f"{tc['patch'][0]} x {tc['patch'][1]} LR crops"
    return (f"batch {tc['batch_size']}, {crops} of freshly rendered random "
            f"scenes, SNR {tc['snr_range'][0]:g}-{tc['snr_range'][1]:g}, {tc['mean_signal_range'][0]:g}-"
            f"{tc['mean_signal_range'][1]:g} signal photons, up to {tc['epochs']} epochs, Adam "
            f"{tc['lr']:g} cut by {tc['lr_decay']:g} every {tc['decay_epochs']} epochs, early stopping after "
            f"{tc['patience']} epochs; validation on {len(tc['val_sequences'])} x {tc['val_frames']} frames of the "
            "validation sequences")


def card_row(tr: int, checkpoint: str, card: dict, val_psnr: str, target: Path) -> list:
    """A weights.md row: the model's checkpoint label, its card's training and storage, the validation PSNR text."""
    val, storage = card.get("validation", {}), card.get("storage", {})
    return [f"TR{tr}", checkpoint, card["steps"], card["examples"], f"{card['wall_time_s'] / 60:.0f}",
            f"{val.get('psnr', float('nan')):.2f}", f"{val.get('bicubic_psnr', float('nan')):.2f}", val_psnr,
            f"{storage.get('psnr_cost_db', float('nan')):+.4f}", storage.get("dtype", "?"),
            f"{target.stat().st_size / 2**20:.1f}"]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", default="runs/bundle", help="folder with tr<N>/best.npz")
    parser.add_argument("--trs", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--frames", type=int, default=64,
                        help="validation frames scored per sequence, its first (default 64)")
    parser.add_argument("--checkpoint", choices=["select", "best", "last"], default="select",
                        help="which checkpoint of each run to bundle (default: the better of best and last on the "
                        "validation frames)")
    parser.add_argument("--form", choices=["window", "sequence"], default="window",
                        help="the runs' temporal form: window -> tr<N>.npz, sequence -> tr<N>-seq.npz")
    parser.add_argument("--trained-with", default=None,
                        help="the command that trained the runs, for the cards (default: the bundle's, per form)")
    parser.add_argument("--force", action="store_true", help="replace existing bundled weights")
    parser.add_argument("--keep-better", action="store_true",
                        help="replace a bundled model only by one that scores higher on the validation frames")
    parser.add_argument("--form-frames", type=int, default=FORM_FRAMES,
                        help=f"test-scene frames per scene for the sequence-form measurement (default {FORM_FRAMES})")
    parser.add_argument("--measure-forms", action="store_true",
                        help="only measure the bundled windowed depth models of --trs in the sequence form again and "
                        "rewrite their cards (weights unchanged)")
    args = parser.parse_args(argv)
    if args.measure_forms:
        measure_forms(args.trs, args.form_frames)
        return
    started = time.time()
    targets = {tr: WEIGHTS / f"tr{tr}{SUFFIX[args.form]}.npz" for tr in args.trs}
    for target in targets.values():  # refuse before the validation frames are rendered
        if target.exists() and not (args.force or args.keep_better):
            raise SystemExit(f"{target} exists; pass --force to replace it (or --keep-better)")
    clips = validation_clips(args.frames)
    rows, kept, epochs = [], [], []  # epochs: each bundled model's run length (its card's train_config)
    for tr, target in targets.items():
        run = Path(args.runs) / f"tr{tr}"
        names = ["best", "last"] if args.checkpoint == "select" else [args.checkpoint]
        candidates = {name: jaxsr.load_model(run / f"{name}.npz") for name in names}
        val_psnr = {name: mean_psnr(m, clips) for name, m in candidates.items()}
        chosen = max(val_psnr, key=val_psnr.get)
        source, model, full = run / f"{chosen}.npz", candidates[chosen], val_psnr[chosen]
        card = jaxsr.read_metadata(source)["card"]
        with tempfile.TemporaryDirectory() as tmp:
            half = jaxsr.load_model(save_model(Path(tmp) / "half.npz", model, storage_dtype="float16"))
            reduced = mean_psnr(half, clips)
        cost = full - reduced
        dtype = "float16" if cost < MAX_COST_DB else "float32"
        replaced = ""
        if args.keep_better and target.exists():
            bundled = mean_psnr(jaxsr.load_model(target), clips)
            replaced = f" (replaced bundled {bundled:.2f})"
            stored = reduced if dtype == "float16" else full
            if bundled >= stored:
                kept_card = jaxsr.read_metadata(target)["card"]
                epochs.append(kept_card["train_config"]["epochs"])
                rows.append(card_row(tr, f"kept: bundled ({kept_card.get('checkpoint', {}).get('file', '?')})",
                                     kept_card, f"bundled {bundled:.2f}, run {stored:.2f}", target))
                kept.append(tr)
                print(*rows[-1], flush=True)
                continue
        trained_with = args.trained_with or (
            f"jaxsr train --tr {tr} --preset bundle -o {run}" if args.form == "window" else
            f"python experiments/studies/train_sequence_bundle.py --trs {tr} --runs {args.runs}")
        card = dict(card, trained_with=trained_with,
                    checkpoint={"file": f"{chosen}.npz", "rule": args.checkpoint,
                                "validation_psnr_db": {k: round(v, 3) for k, v in val_psnr.items()}},
                    storage={"dtype": dtype, "psnr_cost_db": round(cost, 4),
                             "measured_on": f"{', '.join(VALIDATION)}, first {args.frames} frames"})
        card.pop(FORMS_CARD_KEY, None)  # a record of other weights
        stored_model = half if dtype == "float16" else model
        if stored_model.form == "window" and not stored_model.reads_photons:
            card[FORMS_CARD_KEY] = {"sequence": form_record(stored_model, args.form_frames)}
        save_model(target, model, card=card, storage_dtype=dtype)
        epochs.append(card["train_config"]["epochs"])
        rows.append(card_row(
            tr, f"{chosen} (epoch {card['epochs'] if chosen == 'last' else card['best_epoch'] + 1})", card,
            " / ".join(f"{val_psnr[k]:.2f}" if k in val_psnr else "-" for k in ("best", "last")) + replaced, target))
        print(*rows[-1], flush=True)
    if len(kept) == len(args.trs):
        print("every bundled model kept; nothing written")
        return
    total = sum(p.stat().st_size for p in WEIGHTS.glob("*.npz"))
    form = args.form
    text = header(f"Bundled weights (jaxsr/weights), {form} form", started)
    kept_note = " (a model kept from before: the command on its own card)" if kept else ""
    text += (f"Each model trained with {schedule(args)}{kept_note}: "
             f"{describe(dict(card['train_config'], epochs=max(epochs)))}. Card columns: "
             "the best epoch's validation PSNR and bicubic's on the same frames, from the training card. 'val PSNR "
             f"best / last': mean over {', '.join(VALIDATION)} (the first {args.frames} frames of each, other noise) "
             f"of the two checkpoints of the run; rule `--checkpoint {args.checkpoint}` picks the bundled one. "
             "float16 cost: "
             "float32 minus float16 PSNR of the bundled one on the same frames.\n\n")
    if kept:
        text += (f"`--keep-better`: for {', '.join(f'TR{tr}' for tr in kept)} the bundled model scored at least as "
                 f"high as the run's on the same frames (the run's in its 'val PSNR' column), so it was kept; its "
                 "row is its own card's.\n\n")
    text += markdown_table(["model", "checkpoint", "steps", "examples", "train min", "card val PSNR",
                            "card bicubic", "val PSNR best / last", "float16 cost dB", "stored", "MB"], rows)
    text += f"\nAll bundled weights together: {total / 2**20:.1f} MB.\n"
    results = "experiments/results/weights.md" if form == "window" else "experiments/results/weights_sequence.md"
    write_atomic(results, text)
    print(f"wrote {results} ({time.time() - started:.0f} s)")


if __name__ == "__main__":
    main()
