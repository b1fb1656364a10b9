"""The network's sequence form and its stream against the windowed network: speed and what the bundled weights give.

    python experiments/studies/sequence_form.py [--frames 32] [--rounds 2] [--trs 0 1 2 3 4]

Speed: HR frames/s end to end from photon histograms (centre of mass included) on the first --frames frames of
Scene 1, TR0-TR4, in four ways, timed in interleaved rounds after one warm-up call each (best round kept):
window (`super_resolve_histograms` of the bundled window-form model, default batch), sequence (the same
weights as a sequence-form model: chunks of `DEFAULT_SEQUENCE_CHUNK` outputs overlapping by 2R), stream (loop:
`Stream.push` one frame at a time, a jitted step per frame) and stream (scan: the same step over the whole
edge-padded sequence in one `lax.scan`). Accuracy: the bundled TR4 and TR1 weights run in the sequence form,
against the definition (a loop over edge-padded windows of 2R + 1 frames, every block temporally valid) and,
by PSNR / SSIM on 100 frames of Scene 1 at its SNR, against the same weights in their window form.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxsr
from jaxsr.inference import DEFAULT_SEQUENCE_CHUNK, Stream, iter_centre_of_mass, super_resolve
from jaxsr.nn import apply_model, edge_pad_sequence, flops_per_frame, sequence_radius
from jaxsr.runtime import compiler_options
from jaxsr.nn.streaming import stream_init, stream_step
from jaxsr.temporal import windows as temporal_windows

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.scoring import score, test_clips  # noqa: E402
from harness.reports import header, markdown_table, write_atomic  # noqa: E402

FORMS = ("window", "sequence", "stream (loop)", "stream (scan)")


def _streamed(model, counts, sensor):
    """HR frames through `Stream`, fed from the centre of mass of each histogram frame as it comes."""
    stream = Stream(model)
    pushed = (stream.push(lr) for lr in iter_centre_of_mass(counts, sensor))
    return np.stack([hr for hr in pushed if hr is not None] + stream.flush())


def _scan_fn(model):
    """counts (T, h, w, K) -> HR (T, H, W): centre of mass, edge padding (R + 1 copies of the first frame,
    R of the last) and `stream_step` in a `lax.scan` over the padded sequence, in one jitted call."""
    r = sequence_radius(model.config)

    def run(model, counts, sensor):
        lr = jaxsr.centre_of_mass(counts, sensor)
        padded = edge_pad_sequence(lr[None], r)[0]

        def step(buffers, frame):
            return stream_step(model.params, model.state, buffers, frame, model.config)

        _, hr = jax.lax.scan(step, stream_init(model.config, lr.shape[1:]), padded[:, None])
        return hr[2 * r :, 0]

    return jax.jit(run, compiler_options=compiler_options())


def _runners(tr, counts, sensor):
    """{form: a function returning the HR frames of `counts`} for the bundled TR`tr` weights."""
    window = jaxsr.load_model(f"tr{tr}")
    sequence = jaxsr.load_model(f"tr{tr}", temporal="sequence")
    scan = _scan_fn(sequence)
    return {
        "window": lambda: jaxsr.super_resolve_histograms(window, counts, sensor, form="model"),
        "sequence": lambda: jaxsr.super_resolve_histograms(sequence, counts, sensor, form="model"),
        "stream (loop)": lambda: _streamed(sequence, counts, sensor),
        "stream (scan)": lambda: np.asarray(scan(sequence, jnp.asarray(counts), sensor)),
    }


def measure_speed(trs, counts, sensor, rounds):
    """{(tr, form): best frames/s over `rounds` interleaved rounds}, and {(tr, form): warm-up seconds}, and the
    largest difference of each form's frames from the sequence form's (float32 rounding)."""
    runners = {tr: _runners(tr, counts, sensor) for tr in trs}
    warm, outputs = {}, {}
    for tr in trs:
        for form, fn in runners[tr].items():
            t0 = time.perf_counter()
            outputs[tr, form] = fn()
            warm[tr, form] = time.perf_counter() - t0
            print(f"TR{tr} {form}: compiled and ran once in {warm[tr, form]:.0f} s", flush=True)
    best = {}
    for _ in range(rounds):
        for tr in trs:
            for form, fn in runners[tr].items():
                t0 = time.perf_counter()
                fn()
                fps = len(counts) / (time.perf_counter() - t0)
                best[tr, form] = max(best.get((tr, form), 0.0), fps)
    agree = {(tr, form): float(np.abs(outputs[tr, form] - outputs[tr, "sequence"]).max())
             for tr in trs for form in FORMS[2:]}
    return best, warm, agree


def definition_gap(model, lr, *, batch: int = 4) -> float:
    """Largest |sequence form - window loop| over lr (T, h, w): the loop applies the same weights, every block
    temporally valid (the windowed network with same_blocks=0 and radius R), to each edge-padded window, with
    XLA's 3D convolutions ("native") where the sequence form sums 2D convolutions over the temporal taps."""
    r = sequence_radius(model.config)
    cfg = dataclasses.replace(model.config, tr=r, same_blocks=0, temporal="window")
    f = jax.jit(lambda m, w: apply_model(m.params, m.state, w, cfg, conv3d_impl="native"),
                compiler_options=compiler_options())
    wins = temporal_windows(jnp.asarray(lr), r)
    loop = np.concatenate([np.asarray(f(model, wins[i : i + batch])) for i in range(0, len(lr), batch)])
    return float(np.abs(super_resolve(model, lr, form="model") - loop).max())


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=32, help="frames per timed call (Scene 1)")
    parser.add_argument("--rounds", type=int, default=2, help="timed rounds, interleaved over TR and form")
    parser.add_argument("--trs", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--score-frames", type=int, default=100, help="frames of Scene 1 for PSNR / SSIM")
    parser.add_argument("--gap-frames", type=int, default=24, help="frames for the window-loop comparison")
    parser.add_argument("--out", default="experiments/results/sequence_form.md")
    args = parser.parse_args()
    started = time.time()
    sensor = jaxsr.Sensor()
    clip = test_clips(max(args.score_frames, args.frames, args.gap_frames), names=["scene1_street"])["scene1_street"]

    speed, warm, agree = measure_speed(args.trs, clip.counts[: args.frames], sensor, args.rounds)
    accuracy = []
    for tr in (4, 1):
        window = jaxsr.load_model(f"tr{tr}")
        sequence = jaxsr.load_model(f"tr{tr}", temporal="sequence")
        gap = definition_gap(sequence, clip.lr[: args.gap_frames])
        lr, gt = clip.lr[: args.score_frames], clip.gt[: args.score_frames]
        (pw, sw), (ps, ss) = score(super_resolve(window, lr, form="model"), gt), score(
            super_resolve(sequence, lr, form="model"), gt)
        accuracy.append([f"TR{tr}", f"{gap:.1e}", f"{pw:.3f}", f"{ps:.3f}", f"{ps - pw:+.3f}", f"{sw:.3f}",
                         f"{ss:.3f}"])
        print(accuracy[-1], flush=True)

    text = header("Sequence form and streaming against the windowed network", started)
    text += (
        f"Weights: the bundled window-form models (jaxsr/weights), run in either form (`load_model(name, "
        f"temporal=...)`). Speed: {args.frames} frames of Scene 1 (SNR {clip.snr}) per call, end to end from "
        f"photon histograms (32 x 64 x 16), frames/s of the best of {args.rounds} interleaved rounds after a "
        f"warm-up call; window = `super_resolve_histograms` (default batch: one frame per JAX CPU device), "
        f"sequence = the same of a sequence-form model (chunks of {DEFAULT_SEQUENCE_CHUNK} outputs, 2R = 2(3 + TR) "
        "frames of overlap), stream (loop) = `Stream.push` per frame (one jitted step each), stream (scan) = the "
        "same step in one `lax.scan` over the edge-padded sequence. The streams and the sequence form compute "
        "the same frames (largest difference below; 0 when XLA sums each output's three temporal taps in the "
        f"same order in both). GFLOP per frame: `flops_per_frame`; for a {args.frames}-"
        "frame call the sequence form and the streams compute 2R extra frames at the ends (the edge padding) "
        "on top of that.\n\n"
    )
    rows = []
    for tr in args.trs:
        w, s = jaxsr.ModelConfig(tr=tr), jaxsr.ModelConfig(tr=tr, temporal="sequence")
        rows.append([f"TR{tr}", f"{flops_per_frame(w) / 1e9:.1f}", f"{flops_per_frame(s) / 1e9:.1f}",
                     *(f"{speed[tr, f]:.1f}" for f in FORMS), f"{speed[tr, 'sequence'] / speed[tr, 'window']:.2f}",
                     f"{speed[tr, 'stream (loop)'] / speed[tr, 'window']:.2f}",
                     f"{max(agree[tr, f] for f in FORMS[2:]):.1e}"])
    text += markdown_table(["model", "GFLOP window", "GFLOP sequence", *(f"{f} fps" for f in FORMS),
                            "sequence / window", "stream (loop) / window", "max abs stream - sequence"], rows)
    text += "\nWarm-up call (compilation and one run), seconds: " + "; ".join(
        f"TR{tr} " + ", ".join(f"{f} {warm[tr, f]:.0f}" for f in FORMS) for tr in args.trs) + ".\n\n"
    text += (
        f"Accuracy: max |sequence form - window loop| over the first {args.gap_frames} frames (ends included; "
        "the loop is the definition of the sequence form, run with XLA's 3D convolutions), "
        "and PSNR (dB) / SSIM of the same weights in the "
        f"window and the sequence form on the first {args.score_frames} frames of Scene 1 at its SNR "
        "(`experiments/harness/scoring.py` `test_clips`, `score`: output clipped to [0, 1]).\n\n"
    )
    text += markdown_table(["weights", "max abs vs window loop", "PSNR window", "PSNR sequence", "delta",
                            "SSIM window", "SSIM sequence"], accuracy)
    write_atomic(args.out, text)
    print(text)


if __name__ == "__main__":
    main()
