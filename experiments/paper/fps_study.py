"""Frame-rate study (the paper's Table 2 and Fig. 6): people walking at 4.3 km/h, 9 m away, captured at 1 to
100 frames/s, super-resolved by TR0-TR4; and the validation of the scene-adaptive TR (`jaxsr.inference.adaptive`).

    python experiments/paper/fps_study.py [--frames 100] [--span 500] [--weights DIR] [--write-table]
                                    [--seed-runs CHECKPOINT ...]

At each frame rate the walkers scene is rendered at times t0 + i / fps, i < --span (the same scene, sampled as a
camera at that rate would: 500 frames are 5 s at 100 FPS and 500 s at 1 FPS), simulated at SNR 1.3 and scored
on --frames frames spread evenly over them (the people's positions, and so the scores, change along the span).
The motion of the walkers is reported twice: exact, from the scene geometry (`mean_lr_shift`), and as
`jaxsr.inference.adaptive.estimate_motion` measures it from the noisy centre-of-mass frames. `--write-table` stores PSNR
against estimated motion, with each TR's frames/s, as jaxsr/weights/frame_rate_study.json, the table `choose_tr`
reads.

Validation of `choose_tr` (the auto row): the table comes from clips starting at t0 = 0 s with noise seed 0;
auto is then scored on different clips (t0 = 60 s, seed 1), where it chooses from each clip's own
centre-of-mass frames and is compared with the best fixed TR on those clips.

`--seed-runs` scores other trainings of a TR (e.g. TR0's seeds 1 and 2) on the same clips: each TR difference is
then also given over every pair of runs, so that a claim can be read against retraining as well as against the
choice of frames.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jaxsr
from jaxsr.inference.adaptive import STUDY_TABLE, choose_tr, estimate_motion
from jaxsr.runtime import enable_compilation_cache

from _seeds import add_seed_run_args, format_pairs, load_seed_runs, pairs_differences, seed_summary

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import (  # noqa: E402
    BLOCK,
    FRAME_RATES as RATES,
    FPS_NOTE,
    SEQUENCE_FRAMES,
    add_model_args,
    format_interval,
    frame_scores,
    interval,
    load_tr,
    model_fps,
    score,
    walkers_clip,
    scored_output,
    weights_source,
)
from harness.reports import header, markdown_table, write_atomic  # noqa: E402

PAPER_TABLE2 = {  # PSNR per TR at each frame rate (paper Table 2)
    1.0: (22.12, 21.52, 21.38, 21.30, 21.30), 2.5: (22.28, 21.80, 21.69, 21.66, 21.62),
    5.0: (22.22, 22.01, 21.94, 21.91, 21.91), 10.0: (22.17, 22.43, 22.35, 22.32, 22.34),
    20.0: (22.16, 22.82, 22.85, 22.86, 22.87), 25.0: (22.14, 22.92, 23.02, 23.04, 23.10),
    50.0: (22.16, 23.03, 23.25, 23.36, 23.44), 100.0: (22.16, 22.95, 23.21, 23.34, 23.44),
}


def plot(path, rates, psnr, ssim, auto=None):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for ax, table, label in zip(axes, (psnr, ssim), ("PSNR (dB)", "SSIM")):
        for tr in sorted(table):
            ax.plot(rates, table[tr], "o-", label=f"TR{tr}")
        ax.set_xscale("log")
        ax.set_xlabel("frames per second")
        ax.set_ylabel(label)
    if auto is not None:
        axes[0].plot(rates, auto, "k*", ms=9, label="auto (held-out clips)")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100, help="frames scored per frame rate (default 100)")
    parser.add_argument("--span", type=int, default=SEQUENCE_FRAMES,
                        help=f"frames rendered per frame rate, the scored ones spread over them (default "
                        f"{SEQUENCE_FRAMES})")
    add_model_args(parser, trs=(0, 1, 2, 3, 4))
    parser.add_argument("--write-table", action="store_true", help="store the table choose_tr uses")
    add_seed_run_args(parser)
    parser.add_argument("--out", default="experiments/results/fps_study")
    args = parser.parse_args()
    started = time.time()
    enable_compilation_cache()
    sensor = jaxsr.Sensor()
    models = {tr: load_tr(tr, args.weights) for tr in args.trs}
    seed_runs = load_seed_runs(args.seed_runs)
    span = max(args.span, args.frames)

    study, per_frame, held_out, motion, estimated, seed_frames = {}, {}, {}, {}, {}, {}
    for fps in RATES:
        clip, motion[fps] = walkers_clip(fps, span, t0=0.0, seed=0, sensor=sensor, n_scored=args.frames)
        estimated[fps] = estimate_motion(clip.lr)
        held, _ = walkers_clip(fps, span, t0=60.0, seed=1, sensor=sensor, n_scored=args.frames)
        per_frame[fps] = {tr: frame_scores(*scored_output(m, clip)) for tr, m in models.items()}
        study[fps] = {tr: (float(p.mean()), float(s.mean())) for tr, (p, s) in per_frame[fps].items()}
        seed_frames[fps] = {name: frame_scores(*scored_output(m, clip))[0] for name, m in seed_runs.items()}
        held_out[fps] = (held.lr, {tr: score(*scored_output(m, held))[0] for tr, m in models.items()})
        speed_clip = held  # frames/s are measured on the last rate's held-out clip
        print(f"{fps:g} FPS: motion {motion[fps]:.2f} (estimated {estimated[fps].motion:.2f}) LR px/frame; "
              + ", ".join(f"TR{tr} {p:.2f}/{s:.3f}" for tr, (p, s) in study[fps].items()), flush=True)

    speed = {tr: model_fps(m, speed_clip) for tr, m in models.items()}
    table = {
        "motion": [estimated[f].motion for f in RATES],
        "psnr": {str(tr): [study[f][tr][0] for f in RATES] for tr in models},
        "fps": {str(tr): speed[tr] for tr in models},
        "source": (f"experiments/paper/fps_study.py --frames {args.frames} --span {span}, "
                   f"{weights_source(args.weights)}, {time.strftime('%Y-%m-%d')}; motion as estimate_motion measures "
                   f"it, frames/s end to end, {FPS_NOTE}"),
    }
    # choose_tr on the held-out clips, with the table from the study clips
    auto = {}
    for fps in RATES:
        held_lr, scores = held_out[fps]
        choice = choose_tr(held_lr, table=table)
        auto[fps] = (choice.tr, scores[choice.tr], max(scores.values()), max(scores, key=scores.get))

    trs = sorted(models)
    rows = []
    for fps in RATES:
        best = max(trs, key=lambda tr: study[fps][tr][0])
        cells = [f"**{study[fps][tr][0]:.2f}** / {study[fps][tr][1]:.3f}" if tr == best else
                 f"{study[fps][tr][0]:.2f} / {study[fps][tr][1]:.3f}" for tr in trs]
        rows.append([f"{fps:g}", f"{motion[fps]:.2f}", f"{estimated[fps].motion:.2f}"] + cells
                    + [" / ".join(f"{v:.2f}" for i, v in enumerate(PAPER_TABLE2[fps]) if i in trs)])
    auto_rows = [[f"{fps:g}", f"TR{a[0]}", f"{a[1]:.2f}", f"TR{a[3]} {a[2]:.2f}", f"{a[1] - a[2]:+.2f}"]
                 for fps, a in auto.items()]
    worst = min(a[1] - a[2] for a in auto.values())

    text = header("Frame-rate study (paper Table 2, Fig. 6) and the scene-adaptive TR", started)
    text += (f"Scene `walkers_100fps` (people walking at 4.3 km/h about 9 m away, static camera, SNR 1.3), "
             f"{span} frames at each rate from t0 = 0 s, {args.frames} of them scored (spread evenly); models: "
             f"{weights_source(args.weights)}. "
             "Cells: PSNR (dB) / SSIM, the best TR in bold. Motion: LR px per frame of the moving objects, exact "
             "(scene geometry) and estimated from the noisy centre-of-mass frames. Last column: the paper's PSNR "
             "for the same TRs.\n\n")
    text += markdown_table(["FPS", "motion", "estimated"] + [f"TR{tr}" for tr in trs] + ["paper PSNR"], rows)
    text += (f"\nFrames/s of each TR on this machine (end to end, {FPS_NOTE}): "
             + ", ".join(f"TR{tr} {speed[tr]:.1f}" for tr in trs) + "\n")
    text += ("\n## choose_tr on held-out clips\n\nThe table above (t0 = 0 s, noise seed 0) drives `choose_tr`; "
             "each held-out clip (t0 = 60 s, seed 1) is scored with the TR chosen from its own frames and "
             "compared with the best fixed TR on that clip.\n\n")
    text += markdown_table(["FPS", "auto", "auto PSNR", "best fixed", "auto - best (dB)"], auto_rows)
    text += (f"\nWorst shortfall: {worst:+.2f} dB -> the 0.2 dB target "
             f"{'holds' if worst >= -0.2 else 'does not hold'} at every frame rate.\n")
    vs_tr0 = {f: {tr: interval(per_frame[f][tr][0], per_frame[f][0][0]) for tr in trs if tr} for f in RATES} \
        if 0 in trs else {}
    if vs_tr0:
        text += (f"\n## Differences against TR0\n\nPSNR of each TR minus TR0's at each rate (dB), with 95 % intervals "
                 f"from a paired bootstrap over blocks of {BLOCK} consecutive scored frames "
                 "(`jaxsr.paired_interval`): how much the "
                 f"{args.frames} frames chosen move a difference, not how much another training run would (for "
                 "that: --seed-runs).\n\n")
        text += markdown_table(["FPS"] + [f"TR{tr} - TR0" for tr in trs if tr],
                               [[f"{f:g}"] + [format_interval(iv) for iv in vs_tr0[f].values()] for f in RATES])
    text += "\n" + claims(study, trs, vs_tr0) + "\n"
    if seed_runs:
        text += seed_section(per_frame, seed_frames, {n: m.config.tr for n, m in seed_runs.items()}, trs,
                             seed_summary(seed_runs))
    write_atomic(f"{args.out}.md", text)
    write_atomic(f"{args.out}.json", json.dumps(table, indent=1) + "\n")
    plot(f"{args.out}.png", list(RATES), {tr: [study[f][tr][0] for f in RATES] for tr in trs},
         {tr: [study[f][tr][1] for f in RATES] for tr in trs}, [auto[f][1] for f in RATES])
    if args.write_table:
        write_atomic(str(STUDY_TABLE), json.dumps(table, indent=1) + "\n")
        print("wrote", STUDY_TABLE)
    print(f"wrote {args.out}.md, .json, .png ({time.time() - started:.0f} s)")


def seed_section(per_frame, seed_frames, seed_tr, trs, summary) -> str:
    """The TR differences at each rate over every pair of runs (the studied models and the --seed-runs), and the
    two claims read against them."""
    diffs = {f: pairs_differences({tr: per_frame[f][tr][0] for tr in trs}, seed_frames[f], seed_tr)
             for f in RATES}
    others = sorted({tr for d in diffs.values() for tr in d})
    if not others:
        return "\n## Against retraining\n\nNo TR0 run and another TR to compare.\n"
    runs = {tr: sum(t == tr for t in seed_tr.values()) + (tr in trs) for tr in (0, *others)}
    text = ("\n## Against retraining: other runs of the same TRs\n\nThe same clips scored by other trainings "
            f"({summary}). Each TR minus TR0 (dB): the difference of the run means and, in brackets, its lowest and "
            "highest over every pair of a TR-k run and a TR0 run. Runs: "
            + ", ".join(f"TR{tr} {n}" for tr, n in runs.items())
            + "; a TR with one run has its own retraining unmeasured, so its pairs cover TR0's only.\n\n")
    rows = [[f"{f:g}"] + [format_pairs(diffs[f][tr]) if tr in diffs[f] else "" for tr in others] for f in RATES]
    text += markdown_table(["FPS"] + [f"TR{tr} - TR0" for tr in others], rows)
    text += "\nThe claims against every pair of runs:\n"
    text += "- at 1-2.5 FPS TR0 is best: " + "; ".join(
        f"{f:g} FPS: {tr0_best_over_pairs(diffs[f])}" for f in (1.0, 2.5)) + "\n"
    fast = {f: diffs[f][4]["runs"][0] for f in RATES if f >= 20 and 4 in diffs[f]}
    if fast:
        reach = sum(lo >= 0.5 for lo in fast.values())
        text += ("- TR4 - TR0 >= 0.5 dB at >= 20 FPS, lowest over pairs: "
                 + ", ".join(f"{f:g} FPS {lo:+.2f}" for f, lo in fast.items())
                 + (" -> holds for every pair" if reach == len(fast) else
                    f" -> holds for every pair at {reach} of {len(fast)} rates") + "\n")
    return text


def tr0_best_over_pairs(diffs: dict) -> str:
    """Whether TR0 is best at one rate against retraining, from `pairs_differences`: every other TR below every
    TR0 run (holds), some TR above every TR0 run (does not hold), or neither (depends on the runs)."""
    if not diffs:
        return "no TR0 run and another TR to compare"
    above = [tr for tr, d in diffs.items() if d["runs"][0] > 0]
    if above:
        return f"{', '.join(f'TR{tr}' for tr in above)} above every TR0 run -> does not hold"
    if all(d["runs"][1] < 0 for d in diffs.values()):
        return "every other TR below every TR0 run -> holds"
    return "no TR above every TR0 run, not every TR below -> depends on the runs"


def tr0_best_verdict(best, vs_tr0) -> str:
    """Whether TR0 is best at each rate of `best` (FPS -> best TR on the means), and at which rates beyond the
    frame intervals (every other TR's difference to TR0 below zero with its whole interval)."""
    if any(b != 0 for b in best.values()):
        return "does not hold"
    beyond = {f: bool(vs_tr0.get(f)) and all(iv.high < 0 for iv in vs_tr0[f].values()) for f in best}
    if all(beyond.values()):
        return "holds beyond the frame intervals"
    if not any(beyond.values()):
        return "holds on the means only, inside the intervals"
    at = {ok: ", ".join(f"{f:g}" for f in best if beyond[f] == ok) for ok in (True, False)}
    return f"holds beyond the frame intervals at {at[True]} FPS, on the means only at {at[False]} FPS"


def claims(study, trs, vs_tr0) -> str:
    """The paper's Table 2 claims checked on the numbers above: on the means, and beyond the frame intervals."""
    lines = ["Paper claims, measured:"]
    slow = [f for f in (1.0, 2.5) if f in study]
    best_slow = {f: max(trs, key=lambda tr: study[f][tr][0]) for f in slow}
    verdict = tr0_best_verdict(best_slow, vs_tr0)
    lines.append("- at 1-2.5 FPS TR0 is best: best TR " + ", ".join(f"{f:g} FPS: TR{b}" for f, b in best_slow.items())
                 + f" -> {verdict}")
    if 0 in trs and 4 in trs:
        fast = [f for f in study if f >= 20]
        gains = {f: vs_tr0[f][4] for f in fast}
        verdict = ("holds beyond the frame intervals" if all(iv.low >= 0.5 for iv in gains.values()) else
                   "holds on the means only, inside the intervals" if all(iv.mean >= 0.5 for iv in gains.values())
                   else "does not hold")
        lines.append("- TR4 - TR0 >= 0.5 dB at >= 20 FPS: "
                     + ", ".join(f"{f:g} FPS {format_interval(iv)}" for f, iv in gains.items()) + f" -> {verdict}")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
