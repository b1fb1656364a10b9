"""Fine-tune a bundled depth-only model on the wide photon regime (`jaxsr.config.PhotonRegime`), resumably.

    python experiments/studies/photon_finetune.py --tr 0                 # train (or resume) runs/photons/tr0
    python experiments/studies/photon_finetune.py --tr 0 --keep          # its best weights into photon_weights/
    python experiments/studies/photon_finetune.py --tr 0 --photons       # reading photons: runs/photons/tr0-photons

The first step of the photons work: the same network and input as the paper's (centre-of-mass depth only),
started from the bundled weights (`init`), trained on clips whose every sensor parameter is drawn from the wide
regime: 0.5-1000 signal photons per LR pixel, SNR 0.05-20, pulse widths 0.3-3 bins, dark counts, hot and dead
pixels, no-return regions with ground truth 1.0 (`jaxsr.training.regime_batches`). `--photons` widens the model
first (`jaxsr.nn.with_photon_inputs`): it also reads the photons behind each depth (signal and background,
`jaxsr.nn.network_inputs`) and marks no return with a head of its own, starting from the bundled function;
`--ambient` widens a photon model once more, to read the ambient level from the mean of the bins outside the peak;
`--paper-share` of the clips come from the paper's regime, so that it keeps its accuracy there. Validation draws
from the same regime with fixed keys, or at the SNRs of `--val-snrs` (model selection on the regime the model is
for; the paper's fixed sequences at 14 photons measure the cost there separately). Every run resumes where it
stopped (a session's end, a kill): `--checkpoint-minutes` of training are lost at most. `--keep` copies the run's
best weights (float16, with the training card, which records the regime) to
experiments/photon_weights/tr<N>[-photons|-ambient].npz; the bundled `tr0-photons` and `tr4-photons`
(jaxsr/weights/) are such files, copied there (the `-ambient` ones were saved from the run's best.npz with the
photon model's card appended to their stages: experiments/photon_weights/README.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path


import jaxsr
from jaxsr.config import PRECISIONS, PRESETS, PhotonRegime
from jaxsr.runtime import enable_compilation_cache
from jaxsr.training import regime_batches
from jaxsr.training.presets import PHOTON_INPUTS, regime_validation

KEPT = Path(__file__).resolve().parents[1] / "photon_weights"


def train_config(epochs: int, steps_per_epoch: int, lr: float, seed: int, *, batch_size: int | None = None,
                 decay_epochs: int | None = None, precision: str = "default", no_return_weight: float | None = None):
    """The bundle preset's crops (and batch, unless given), with this run's length and a fine-tuning rate (cut 10x
    after `decay_epochs`, default half way)."""
    base = PRESETS["bundle"]
    batch = batch_size or base.batch_size
    return dataclasses.replace(base, batch_size=batch, examples_per_epoch=steps_per_epoch * batch, epochs=epochs,
                               lr=lr, decay_epochs=decay_epochs or max(1, epochs // 2),
                               patience=max(3, epochs // 4), seed=seed, precision=precision,
                               no_return_weight=base.no_return_weight if no_return_weight is None else no_return_weight)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tr", type=int, default=0, help="the bundled model to start from (tr0 .. tr4)")
    parser.add_argument("--out", default=None, help="run folder (default runs/photons/tr<N>)")
    parser.add_argument("--epochs", type=int, default=40)
    parser.add_argument("--steps-per-epoch", type=int, default=256)
    parser.add_argument("--lr", type=float, default=1e-4, help="Adam's rate (a fine-tune: 10x below the paper's)")
    parser.add_argument("--batch-size", type=int, default=None,
                        help="clips per step (default the bundle preset's 4; an accelerator runs 16 or more well)")
    parser.add_argument("--decay-epochs", type=int, default=None, help="cut the rate 10x every this many epochs "
                        "(default half the epochs)")
    parser.add_argument("--precision", default="default", choices=PRECISIONS,
                        help="how the convolutions multiply (TrainConfig.precision)")
    parser.add_argument("--no-return-weight", type=float, default=None,
                        help="weight of the no-return head's cross-entropy in the loss (default TrainConfig's)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar (logs to a file)")
    parser.add_argument("--val-batches", type=int, default=16, help="batches of 4 regime draws to validate on")
    parser.add_argument("--init", default=None,
                        help="weights to start from (default the bundled tr<N>; e.g. "
                        "experiments/photon_weights/tr0-wide-depth.npz to continue this study's kept run in a new "
                        "folder)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--photons", action="store_true",
                        help="read signal and background photons too and mark no return (default: depth only)")
    parser.add_argument("--ambient", action="store_true",
                        help="with --photons, read the ambient channel too (jaxsr.sensor.ambient_photons: the mean "
                        "of the bins outside the peak, which tells the ambient level at a few photons); the run "
                        "is runs/photons/tr<N>-ambient, started from the bundled tr<N>-photons unless --init")
    parser.add_argument("--paper-share", type=float, default=0.0,
                        help="share of clips from the paper's regime (PhotonRegime.paper_prob)")
    parser.add_argument("--signal-range", type=float, nargs=2, default=PhotonRegime().signal_range,
                        metavar=("LO", "HI"), help="signal photons per LR pixel drawn (PhotonRegime.signal_range)")
    parser.add_argument("--snr-range", type=float, nargs=2, default=PhotonRegime().snr_range, metavar=("LO", "HI"),
                        help="frame SNR drawn (PhotonRegime.snr_range); a higher HI for sensors with little ambient "
                        "light, such as indoors or at night (a real one, tower, reads 45)")
    parser.add_argument("--no-return-prob", type=float, default=PhotonRegime().no_return_prob,
                        help="share of clips with added no-return regions (PhotonRegime.no_return_prob)")
    parser.add_argument("--thin-prob", type=float, default=PhotonRegime().thin_prob,
                        help="share of the clips with no-return regions that thin returns cross (poles, cables, a "
                        "lattice tower's beams: PhotonRegime.thin_prob); validation draws them as often")
    parser.add_argument("--static-prob", type=float, default=PhotonRegime().static_prob,
                        help="share of static clips, every frame the centre frame (a still scene from a still "
                        "sensor, as the real recordings' photon videos: PhotonRegime.static_prob); validation "
                        "draws them as often")
    parser.add_argument("--val-snrs", type=float, nargs="+", default=None, metavar="SNR",
                        help="validate at these frame SNRs, in equal shares, instead of the regime's range (e.g. 0.1 "
                        "1.3 5 45: model selection that sees a recording as dark as tower as often as the rest)")
    parser.add_argument("--checkpoint-minutes", type=float, default=5.0)
    parser.add_argument("--keep", action="store_true", help="copy the run's best weights to experiments/photon_weights")
    args = parser.parse_args(argv)
    if args.ambient and not args.photons:
        parser.error("--ambient widens a photon model: give --photons too")
    name = f"tr{args.tr}-ambient" if args.ambient else f"tr{args.tr}-photons" if args.photons else f"tr{args.tr}"
    out = Path(args.out or f"runs/photons/{name}")
    if args.keep:
        model = jaxsr.load_model(out / "best.npz")
        card = jaxsr.read_metadata(out / "best.npz")["card"]
        KEPT.mkdir(exist_ok=True)
        if (KEPT / f"{name}.npz").exists():
            raise SystemExit(f"{KEPT / f'{name}.npz'} exists: move it away first (a kept model is not replaced "
                             "silently)")
        path = jaxsr.save_model(KEPT / f"{name}.npz", model, card=card, storage_dtype="float16")
        print(f"kept {path} ({card['steps']} steps, validation PSNR {card['validation']['psnr']:.2f} dB)")
        return
    # a restart on the same machine (a resumed lease) skips XLA's compilation; the stages' times go to the log so
    # that a call that trains no epoch says where its time went
    enable_compilation_cache()
    started = time.perf_counter()
    say = lambda msg: print(f"{name} [{time.perf_counter() - started:.0f} s] {msg}", flush=True)  # noqa: E731
    sensor = jaxsr.Sensor()
    regime = PhotonRegime(signal_range=tuple(args.signal_range), snr_range=tuple(args.snr_range),
                          no_return_prob=args.no_return_prob, thin_prob=args.thin_prob, static_prob=args.static_prob,
                          paper_prob=args.paper_share)
    model_cfg = jaxsr.ModelConfig(tr=args.tr, **(PHOTON_INPUTS if args.photons else {}))
    if args.ambient:
        model_cfg = dataclasses.replace(model_cfg, inputs=(*model_cfg.inputs, "ambient"))
    train_cfg = train_config(args.epochs, args.steps_per_epoch, args.lr, args.seed, batch_size=args.batch_size,
                             decay_epochs=args.decay_epochs, precision=args.precision,
                             no_return_weight=args.no_return_weight)
    # validation on the whole wide regime (PhotonRegime(), paper_prob 0) whatever the draws above, or at the SNRs
    # of --val-snrs: a run that trains on part of it (--signal-range, --snr-range) is still chosen for the regime
    # the photon models serve; thin returns and static scenes, kinds of scene rather than ranges, are validated on
    # as often as trained on
    validation = regime_validation(args.tr, train_cfg, PhotonRegime(thin_prob=args.thin_prob,
                                                                    static_prob=args.static_prob),
                                   batches=args.val_batches, sensor=sensor, inputs=model_cfg.inputs,
                                   snrs=args.val_snrs)
    resuming = any((out / f).exists() for f in ("last.npz", "resume.npz"))
    say(f"validation set drawn ({args.val_batches} batches); training{' (resuming)' if resuming else ''}")
    jaxsr.fit(model_cfg, train_cfg, out=out, make_batch=regime_batches(
        args.tr, train_cfg, regime, sensor=sensor, inputs=model_cfg.inputs), validation=validation, sensor=sensor,
        resume=True, progress=not args.no_progress,
        callback=lambda r: say(f"epoch {r['epoch']}: val PSNR {r['val_psnr']:.2f} dB, {r['epoch_time_s']:.0f} s"),
        init=args.init or (f"tr{args.tr}-photons" if args.ambient else f"tr{args.tr}"),
        checkpoint_every_s=60 * args.checkpoint_minutes,
        card_extra={"regime": regime.to_dict(), "trained_with": "experiments/studies/photon_finetune.py"})


if __name__ == "__main__":
    main()
