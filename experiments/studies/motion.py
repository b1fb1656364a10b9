"""How much of each sequence moves: the test sequences, the frame-rate study's walkers at each of its rates, and
the training clips, before and after the scenes were made to keep their motion in view.

    python experiments/studies/motion.py [--clips 400] [--frames 500] [--before /path/to/older/checkout]

A pixel moves between two consecutive frames when its ground-truth radial depth changes by more than 1 cm, with
no return (sky, beyond the gate) counted as d_max = 35 m: a change the sensor could see, however small, so
the count covers whole moving silhouettes, not just their edges. The share of moving pixels is also given at
0.01 in normalised depth (35 cm), the threshold of temporal_use.py, where only the edges of objects against
what is behind them count.

Motion in LR pixels per frame is given two ways: `mean_lr_shift` (what fps_study.py calls the exact motion:
every moving object near the frame) and `in_view_lr_shift` (only what is in sight: the nearest hit on a grid of
rays); a sequence's in-view motion is its mean over the frames where something in sight moves.

Training clips: `--clips` draws of `training_clip` (keys `jax.random.key(s)` for s = 500, 501, ..., 3 frames;
the first 40 are the seeds 500-539 of the original check). Per clip: the largest depth change (a clip whose
largest change is <= 1 cm is static), the share of moving pixels, and the in-view motion at the middle frame.

Before: with `--before DIR` (a checkout of the code before the change, e.g. `git worktree add DIR <commit>`),
a subprocess with PYTHONPATH=DIR draws that code's stored walkers and scene 2 and its training scenes (scene,
frame rate, start time), and this process renders and measures them with the same functions as the new ones.
The old sampler starts its clips at the drawn time; the new one centres them on it.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxsr.config import Sensor
from jaxsr.scenes import (
    TEST_SEQUENCES,
    empty_scene,
    in_view_lr_shift,
    mean_lr_shift,
    render_sequence,
    test_scene,
    training_scene,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import SEQUENCE_FRAMES  # noqa: E402
from harness.reports import hand_written_tail, header, markdown_table, write_atomic  # noqa: E402
from harness.scoring import FRAME_RATES as RATES  # noqa: E402

# fps_study.py's frames per rate (its --span), from t0 = 0 s and (held out) 60 s
STUDY_FRAMES, STUDY_T0 = SEQUENCE_FRAMES, (0.0, 60.0)
CHANGED = ("walkers_100fps", "scene2_road")  # the sequences this change redrew
MOVING_M = 0.01  # m of radial depth
MOVING_NORM = 0.01  # normalised depth (temporal_use.py)
CLIP_FRAMES = 3
FIRST_SEED = 500
QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)
SENSOR = Sensor()
READING = "## Reading"  # the hand-written commentary at the end of the results file, kept by a re-run

_render = jax.jit(render_sequence, static_argnames=("sensor",))
_render_clips = jax.jit(jax.vmap(lambda s, t: render_sequence(s, t, sensor=SENSOR)))
_in_view_at = jax.jit(jax.vmap(lambda s, fps, t: in_view_lr_shift(s, fps, sensor=SENSOR, t=t), in_axes=(None, None, 0)))
_in_view_clips = jax.jit(jax.vmap(lambda s, fps, t: in_view_lr_shift(s, fps, sensor=SENSOR, t=t)))
_draw_training = jax.jit(jax.vmap(lambda k: training_scene(k, sensor=SENSOR)))

# Run in the older checkout: its stored test scenes and training scenes as arrays (the Scene pytree's leaves).
_DUMP_BEFORE = r"""
import sys
import jax, jax.numpy as jnp, numpy as np
from jaxsr import scenes
path, names, first, n = sys.argv[1], sys.argv[2].split(","), int(sys.argv[3]), int(sys.argv[4])
out = {}
for name in names:
    scene, _ = scenes.test_scene(name)
    out.update({f"test/{name}/{i}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(scene))})
keys = jnp.stack([jax.random.key(s) for s in range(first, first + n)])
scene, fps, t0 = jax.jit(jax.vmap(scenes.training_scene))(keys)
shift = jax.jit(jax.vmap(lambda s, f, t: scenes.mean_lr_shift(s, f, t=t)))(scene, fps, t0)
out.update({f"train/{i}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(scene))})
out.update(fps=np.asarray(fps), start=np.asarray(t0), drawn_shift=np.asarray(shift))
np.savez(path, **out)
"""


def _unflatten(leaves):
    return jax.tree.unflatten(jax.tree.structure(empty_scene()), [jnp.asarray(x) for x in leaves])


def _leaves(data, prefix):
    n = len([k for k in data.files if k.startswith(prefix)])
    return [data[f"{prefix}{i}"] for i in range(n)]


def draw_before(checkout, n_clips):
    """The older checkout's stored changed scenes and training draws: ({name: Scene}, training dict)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "before.npz")
        env = dict(os.environ, PYTHONPATH=os.path.abspath(checkout))
        subprocess.run([sys.executable, "-c", _DUMP_BEFORE, path, ",".join(CHANGED), str(FIRST_SEED), str(n_clips)],
                       env=env, check=True, cwd=checkout)
        data = np.load(path)
        tests = {name: _unflatten(_leaves(data, f"test/{name}/")) for name in CHANGED}
        train = {"scene": _unflatten(_leaves(data, "train/")), "fps": data["fps"], "start": data["start"],
                 "drawn_shift": data["drawn_shift"]}
    return tests, train


def draw_after(n_clips):
    keys = jnp.stack([jax.random.key(s) for s in range(FIRST_SEED, FIRST_SEED + n_clips)])
    scene, fps, t = _draw_training(keys)
    start = t - (CLIP_FRAMES - 1) / 2 / fps  # the clip is centred on the drawn time
    drawn = _in_view_clips(scene, fps, t)
    return {"scene": scene, "fps": np.asarray(fps), "start": np.asarray(start), "drawn_shift": np.asarray(drawn)}


# ---------------------------------------------------------------------------------------------------------
# Measures


def clipped(depth):
    """Radial depth with no return (inf, NaN, beyond the gate) as d_max: what the sensor can tell apart."""
    return np.clip(np.nan_to_num(np.asarray(depth), nan=SENSOR.d_max, posinf=SENSOR.d_max), 0.0, SENSOR.d_max)


def frame_changes(depth):
    """(T-1, H, W) absolute depth change (m) between consecutive frames."""
    return np.abs(np.diff(clipped(depth), axis=0))


def motion_row(depth, shifts):
    """Share of moving pixels (mean over frame pairs, at 1 cm and at 0.01 normalised), the smallest share of a
    pair, pairs with no moving pixel, and the in-view motion (mean over frames where something in sight moves)."""
    change = frame_changes(depth)
    share = (change > MOVING_M).mean(axis=(1, 2))
    share_norm = (change > MOVING_NORM * SENSOR.d_max).mean(axis=(1, 2))
    shifts = np.asarray(shifts)
    in_view = shifts[shifts > 0].mean() if (shifts > 0).any() else 0.0
    return [f"{100 * share.mean():.2f} %", f"{100 * share_norm.mean():.2f} %", f"{100 * share.min():.2f} %",
            f"{int((share == 0).sum())} / {len(share)}", f"{in_view:.3f}", f"{100 * (shifts > 0).mean():.0f} %"]


def sequence_motion(scene, fps, times):
    depth = np.concatenate([np.asarray(_render(scene, times[i:i + 50], sensor=SENSOR)[0])
                            for i in range(0, len(times), 50)])
    exact = float(mean_lr_shift(scene, fps, sensor=SENSOR, t=float(times[0])))
    return depth, np.asarray(_in_view_at(scene, fps, times)), exact


def training_motion(draws):
    """Per clip: largest depth change (m), share of moving pixels, in-view motion at the middle frame."""
    n = len(draws["fps"])
    times = draws["start"][:, None] + np.arange(CLIP_FRAMES)[None, :] / draws["fps"][:, None]
    largest, share = [], []
    for i in range(0, n, 50):
        chunk = slice(i, i + 50)
        scene = jax.tree.map(lambda x, chunk=chunk: x[chunk], draws["scene"])
        depth = np.asarray(_render_clips(scene, jnp.asarray(times[chunk], jnp.float32))[0])
        change = np.abs(np.diff(clipped(depth), axis=1))
        largest.append(change.max(axis=(1, 2, 3)))
        share.append((change > MOVING_M).mean(axis=(1, 2, 3)))
    middle = jnp.asarray(times[:, CLIP_FRAMES // 2], jnp.float32)
    in_view = np.asarray(_in_view_clips(draws["scene"], jnp.asarray(draws["fps"]), middle))
    moving_camera = np.asarray(jnp.abs(draws["scene"].camera.velocity[:, 0]) > 0)
    return {"largest": np.concatenate(largest), "share": np.concatenate(share), "in_view": in_view,
            "drawn": draws["drawn_shift"], "moving_camera": moving_camera, "fps": draws["fps"]}


def training_rows(label, m, lo=0.2, hi=5.0):
    static = m["largest"] <= MOVING_M
    first40 = int(static[:40].sum())
    v = m["in_view"]
    q = np.quantile(v, QUANTILES)
    quarters = np.histogram(np.log(v[v > 0]), np.linspace(np.log(lo), np.log(hi), 5))[0] / len(v)
    return [label, str(len(v)), f"{100 * static.mean():.1f} % ({first40} of 40)", f"{100 * (v == 0).mean():.1f} %",
            " / ".join(f"{x:.2f}" for x in q), f"{100 * ((v >= lo) & (v <= hi)).mean():.0f} %",
            " / ".join(f"{100 * x:.0f}" for x in quarters),
            f"{100 * np.mean(v[v > 0] < lo):.0f} / {100 * np.mean(v[v > 0] > hi):.0f} %",
            f"{100 * np.median(m['share']):.2f} %", f"{100 * m['moving_camera'].mean():.0f} %"]


# ---------------------------------------------------------------------------------------------------------


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=400, help="training clips to draw (default 400)")
    parser.add_argument("--frames", type=int, default=500, help="frames per test sequence (default 500, all)")
    parser.add_argument("--before", default=None, help="a checkout of the code before the change, to compare")
    parser.add_argument("--out", default="experiments/results/motion")
    args = parser.parse_args()
    started = time.time()
    before_tests, before_train = draw_before(args.before, args.clips) if args.before else ({}, None)

    seq_cols = ["sequence", "FPS", "frames", "moving pixels (1 cm)", "moving pixels (0.01 norm.)",
                "fewest in a pair", "pairs with none", "in-view motion (LR px/frame)", "frames with motion in sight",
                "mean_lr_shift at t = 0"]
    seq_rows = []
    for name, recipe in TEST_SEQUENCES.items():
        fps = recipe[2]
        times = jnp.arange(args.frames, dtype=jnp.float32) / fps
        versions = [("before", before_tests[name])] if name in before_tests else []
        versions.append(("after" if name in before_tests else "", test_scene(name)[0]))
        for label, scene in versions:
            depth, shifts, exact = sequence_motion(scene, fps, times)
            seq_rows.append([f"{name} {label}".strip(), f"{fps:g}", str(args.frames)] + motion_row(depth, shifts)
                            + [f"{exact:.3f}"])

    walk_cols = ["walkers", "FPS", "from t0 (s)"] + seq_cols[3:]
    walk_rows = []
    walkers = ([("before", before_tests["walkers_100fps"])] if before_tests else []) + [
        ("after" if before_tests else "", test_scene("walkers_100fps")[0])]
    for label, scene in walkers:
        for fps in RATES:
            for t0 in STUDY_T0:
                times = t0 + jnp.arange(STUDY_FRAMES, dtype=jnp.float32) / fps
                depth, shifts, exact = sequence_motion(scene, fps, times)
                walk_rows.append([label, f"{fps:g}", f"{t0:g}"] + motion_row(depth, shifts) + [f"{exact:.3f}"])

    train_cols = ["training clips", "clips", "static (no pixel > 1 cm)", "nothing moving in sight",
                  "in-view motion quantiles 5/25/50/75/95 % (LR px/frame)", "in 0.2-5",
                  "in each quarter of log(0.2-5), %", "below 0.2 / above 5 (of those moving)",
                  "median share of moving pixels",
                  "moving camera"]
    train_rows = []
    measured = {}
    for label, draws in ([("before", before_train)] if before_train else []) + [("after", draw_after(args.clips))]:
        measured[label] = training_motion(draws)
        train_rows.append(training_rows(label, measured[label]))

    text = header("Motion in view: moving pixels of the test sequences, the frame-rate study and the training clips",
                  started)
    text += (f"A pixel moves when its radial depth (no return = {SENSOR.d_max:g} m) changes by more than "
             f"{100 * MOVING_M:g} cm between consecutive frames; the second share uses {MOVING_NORM:g} in normalised "
             f"depth ({100 * MOVING_NORM * SENSOR.d_max:g} cm, as temporal_use.py). In-view motion: "
             "`in_view_lr_shift` (moving objects in sight), the mean over the frames where something in sight "
             "moves; `mean_lr_shift`: every moving object within half a frame of the view (fps_study.py's exact "
             "motion). ")
    if args.before:
        text += (f"before: the stored scenes and the training sampler of the checkout `{args.before}` (commit "
                 f"{_commit(args.before)}), drawn in a subprocess and measured here with the same code.\n\n")
    else:
        text += "\n\n"
    text += (f"## Test sequences at their frame rate ({args.frames} frames each)\n\n"
             + markdown_table(seq_cols, seq_rows))
    text += (f"\n## The frame-rate study's walkers at each rate ({STUDY_FRAMES} frames from t0, as fps_study.py)\n\n"
             + markdown_table(walk_cols, walk_rows))
    text += (f"\n## Training clips ({CLIP_FRAMES} frames; keys {FIRST_SEED}-{FIRST_SEED + args.clips - 1})\n\n"
             "In-view motion at the clip's middle frame. The sampler draws its target shift log-uniform in 0.2-5 "
             "LR px/frame, so a quarter of the clips would fall in each quarter of the log range if the frame-rate "
             "clip to [1, 2000] never bound.\n\n" + markdown_table(train_cols, train_rows))
    if "before" in measured:
        b, a = measured["before"], measured["after"]
        drawn_ratio = lambda m: np.median(m["in_view"][m["drawn"] > 0] / m["drawn"][m["drawn"] > 0])
        text += (f"\nMedian ratio of the in-view motion to the shift the sampler drew: before {drawn_ratio(b):.2f} "
                 f"(it drew `mean_lr_shift` at the clip's first frame, objects beside the frame included), after "
                 f"{drawn_ratio(a):.2f} (it draws `in_view_lr_shift` at the middle frame).\n")
    text += hand_written_tail(f"{args.out}.md", READING)
    write_atomic(f"{args.out}.md", text)
    print(text)


def _commit(checkout):
    try:
        return subprocess.run(["git", "-C", checkout, "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


if __name__ == "__main__":
    main()
