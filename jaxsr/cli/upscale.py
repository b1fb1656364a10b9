"""`jaxsr upscale`: super-resolve a recording (depth or histograms) with a trained model, streaming.

Frames stream from the input through the model to the output (see `jaxsr.recordings`), so a long recording
needs memory for a batch, not for the whole sequence (an .npz output holds the result; an .npy output is
written through a memory map). Everything is
checked before the model runs: the options, the output and preview paths, the model, and every input frame
(one pass; only the sensor's 32 x 64 LR frames are accepted for now). Outputs are written atomically (a folder
of frames into a hidden `.NAME.XXXX.partial` sibling, renamed when complete) and never replace an existing
file or write into a non-empty folder without --force.
"""

from __future__ import annotations

import json
import sys

import numpy as np
from tqdm.auto import tqdm

from .. import io
from .._files import atomic_folder, atomic_path
from ..adaptive import resolve_model
from ..checkpoint import load_model, resolve_model_path
from ..config import SensorConfig
from ..inference import iter_centre_of_mass, iter_super_resolve
from ..previews import write_comparison
from ..recordings import (
    ARRAY_FORMATS,
    check_frames,
    check_output,
    check_preview,
    guess_units,
    normalised_frames,
    open_recording,
    to_units,
)
from ..runtime import enable_compilation_cache
from ._args import int_range, positive_float

HEAD_FRAMES = 64  # frames --model auto measures the motion on


def add_parser(subparsers):
    p = subparsers.add_parser("upscale", help="super-resolve a recording (depth or histograms) x4 with a trained model",
                              description="Super-resolve a recording. INPUT: .npy / .npz array, or a folder or "
                              "quoted glob pattern of EXR, PFM, TIFF or 16-bit PNG depth frames. OUTPUT: .npy / "
                              ".npz, or a folder of frames (--frame-format).")
    p.add_argument("input", help="the recording")
    p.add_argument("output", help="output .npy, .npz or folder")
    p.add_argument("--model", default="tr4", help="tr0..tr4 (bundled weights), auto (choose TR from the measured "
                   "motion), or a checkpoint path (default tr4)")
    p.add_argument("--input", dest="input_kind", choices=["depth", "histograms"], default=None,
                   help="what INPUT holds (default: from the data)")
    p.add_argument("--units", choices=["m", "normalised"], default=None,
                   help="depth units of INPUT and OUTPUT: radial metres (inf = no return) or normalised [0, 1] "
                   "(1 = no return); default: normalised if the first frame lies in [0, 1], else metres; "
                   "histograms give metres")
    p.add_argument("--frame-format", choices=["exr", "pfm", "tif", "png"], default="exr",
                   help="frame files when OUTPUT is a folder (default exr; always metres)")
    p.add_argument("--batch-size", type=int_range(1), default=None,
                   help="frames per compiled call (default: one per CPU core, each core a JAX device)")
    p.add_argument("--min-fps", type=positive_float, default=None,
                   help="with --model auto: the slowest acceptable frames/s")
    p.add_argument("--preview", default=None, help="write an input | output PNG strip of the middle frame")
    p.add_argument("--force", action="store_true", help="overwrite OUTPUT (and the preview)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _lr_source(rec, units_arg, sensor):
    """(units, a function returning a fresh stream of LR normalised frames) for an opened recording, after
    checking every frame (`check_frames`)."""
    if rec.kind == "histograms":
        units = "m" if units_arg is None else units_arg
        check_frames(rec, units, sensor)
        return units, lambda: iter_centre_of_mass(rec, sensor)
    units = guess_units(rec) if units_arg is None else units_arg
    check_frames(rec, units, sensor)
    return units, lambda: normalised_frames(rec, units, sensor)


def _fixed_model(args):
    """The model named by --model, loaded and checked now (None for auto, which needs the input first; its
    bundled weights are looked up now)."""
    if args.model == "auto":
        resolve_model_path("tr0")
        return None
    if args.min_fps is not None:
        raise ValueError("--min-fps applies to --model auto only (a fixed model runs at its own speed)")
    return load_model(args.model)


def _head(frames, n):
    """The first n frames of an iterable, stacked."""
    head = []
    for f in frames:
        head.append(f)
        if len(head) == n:
            break
    return np.stack(head)


def run(args) -> int:
    # Every check before any work: options, output and preview paths, the model, then every input frame.
    out = check_output(args.output, force=args.force)
    if args.preview:
        check_preview(args.preview, force=args.force, output=out)
    fixed = _fixed_model(args)
    sensor = SensorConfig() if fixed is None or fixed.config.scale == 4 else SensorConfig(scale=fixed.config.scale)
    rec = open_recording(args.input, kind=args.input_kind)
    units, lr_stream = _lr_source(rec, args.units, sensor)
    enable_compilation_cache()
    if fixed is None:
        model, described = resolve_model("auto", _head(lr_stream(), HEAD_FRAMES), min_fps=args.min_fps)
    else:
        model, described = fixed, str(args.model)
    print(f"jaxsr upscale: {rec.frames} frames {rec.kind} {tuple(rec.shape)} from {args.input}, units {units}, "
          f"model {described}", file=sys.stderr)
    r = model.config.scale
    hr_shape = (rec.shape[0] * r, rec.shape[1] * r)
    preview_t = rec.frames // 2
    preview_lr = []  # the preview's LR frame, kept as it streams past (no second pass over the input)

    def keep_preview(frames):
        for t, f in enumerate(frames):
            if t == preview_t:
                preview_lr.append(f)
            yield f

    stream = iter_super_resolve(model, keep_preview(lr_stream()), batch_size=args.batch_size)
    bar = tqdm(stream, total=rec.frames, unit="frame", disable=args.no_progress, desc="upscale")
    preview = []

    def write_preview():  # inside the output's atomic block: a failed preview leaves no output either
        if args.preview:
            write_comparison(args.preview, preview_lr[0], np.clip(preview[0], 0, 1), d_max=float(sensor.d_max),
                             labels=("input (centre of mass)" if rec.kind == "histograms" else "input", described),
                             overwrite=args.force)

    if out.suffix.lower() == ".npy":  # streamed to disk: memory for a batch, not for the whole result
        with atomic_path(out, overwrite=args.force) as tmp:
            result = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.float32, shape=(rec.frames, *hr_shape))
            for t, hr in enumerate(bar):
                result[t] = to_units(hr, units, sensor)
                preview += [hr] if t == preview_t else []
            result.flush()
            del result
            write_preview()
    elif out.suffix.lower() in ARRAY_FORMATS:
        result = np.empty((rec.frames, *hr_shape), np.float32)
        for t, hr in enumerate(bar):
            result[t] = to_units(hr, units, sensor)
            preview += [hr] if t == preview_t else []
        with atomic_path(out, overwrite=args.force) as tmp:
            io.write_sequence(tmp, result, overwrite=True, units=units, model=described, input=str(args.input),
                              scale=r)
            write_preview()
    else:
        ext = "." + args.frame_format
        with atomic_folder(out) as tmp:
            for t, hr in enumerate(bar):
                io.write_depth(tmp / f"frame_{t:06d}{ext}", to_units(hr, "m", sensor))
                preview += [hr] if t == preview_t else []
            write_preview()
    print(json.dumps({"frames": rec.frames, "output": str(out), "shape": [rec.frames, *hr_shape],
                      "units": units, "model": described}))
    return 0
