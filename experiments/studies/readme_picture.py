"""The README's picture: an animated GIF of a test scene, LR input | TR4 | truth, from the bundled weights.

    python experiments/studies/readme_picture.py [--frames 20] [--fps 8] [--out experiments/results/readme.gif]

The street test scene (`jaxsr.scenes.test_sequences`, its first frames), photons simulated at the scene's SNR
with noise seed 0, centre-of-mass depth (the 32 x 64 LR input, nearest-neighbour upscaled) and the bundled TR4
network (128 x 256), beside the ground truth: one colour scale in metres (0-35 m, the sensor's range), no return
black (`jaxsr.io.write_depth_video`). Refuses to grow past --max-kb (default 1000: the README's picture stays
under 1 MB); about half a minute on 2 CPU cores.
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import numpy as np

import jaxsr
from jaxsr import io, scenes


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20, help="frames of the scene (default 20)")
    parser.add_argument("--fps", type=float, default=8.0, help="frames per second of the GIF (default 8)")
    parser.add_argument("--out", default="experiments/results/readme.gif", help="the GIF (replaced if there)")
    parser.add_argument("--max-kb", type=float, default=1000.0, help="largest size allowed, kB (default 1000)")
    args = parser.parse_args()
    started = time.time()
    seq = scenes.test_sequences(n_frames=args.frames, names=["scene1_street"])["scene1_street"]
    sensor = jaxsr.Sensor()
    counts = jaxsr.simulate_histograms(jax.random.key(0), seq.depth, seq.intensity, sensor, snr=seq.snr)
    lr = jaxsr.centre_of_mass(counts, sensor)
    hr = jaxsr.super_resolve(jaxsr.load_model("tr4"), lr, form="model")
    metres = lambda n: np.asarray(jaxsr.denormalise_depth(np.clip(n, 0, 1), sensor))  # noqa: E731
    gt = np.asarray(jaxsr.denormalise_depth(jaxsr.normalise_depth(seq.depth, sensor), sensor))
    n = io.write_depth_video(args.out, metres(lr), metres(hr), gt, fps=args.fps, d_min=0.0,
                             d_max=float(sensor.d_max), labels=("LR input (32 x 64)", "TR4 (128 x 256)", "truth"),
                             overwrite=True)
    kb = os.path.getsize(args.out) / 1000
    if kb > args.max_kb:
        os.remove(args.out)
        raise SystemExit(f"{args.out}: {kb:.0f} kB is over --max-kb {args.max_kb:g}; fewer --frames")
    print(f"wrote {args.out}: {n} frames, {kb:.0f} kB ({time.time() - started:.0f} s)")


if __name__ == "__main__":
    main()
