"""`jaxsr upscale`: super-resolve a recording (depth or histograms) with a trained model, streaming.

Frames stream from the input through the model to the output (see `jaxsr.recordings`), so a long recording
needs memory for a batch, not for the whole sequence (an .npy / .npz output holds the result). Outputs are
written atomically and never replace an existing file or a non-empty folder without --force.
"""

from __future__ import annotations

import json
import sys

import numpy as np
from tqdm.auto import tqdm

from .. import io
from ..adaptive import resolve_model
from ..config import SensorConfig
from ..inference import iter_centre_of_mass, iter_super_resolve
from ..previews import write_comparison
from ..recordings import ARRAY_FORMATS, check_output, guess_units, normalised_frames, open_recording, to_units
from ..runtime import enable_compilation_cache

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
    p.add_argument("--batch-size", type=int, default=None, help="frames per compiled call (default: one per CPU core, each core a JAX device)")
    p.add_argument("--min-fps", type=float, default=None, help="with --model auto: the slowest acceptable frames/s")
    p.add_argument("--preview", default=None, help="write an input | output PNG strip of the middle frame")
    p.add_argument("--force", action="store_true", help="overwrite OUTPUT (and the preview)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _lr_source(rec, units_arg, sensor, source):
    """(units, a function returning a fresh stream of LR normalised frames) for an opened recording."""
    if rec.kind == "histograms":
        if rec.shape[-1] != sensor.bins:
            raise ValueError(f"{source}: histograms have {rec.shape[-1]} bins, the sensor model has {sensor.bins}")
        return ("m" if units_arg is None else units_arg), lambda: iter_centre_of_mass(rec, sensor)
    units = guess_units(rec) if units_arg is None else units_arg
    return units, lambda: normalised_frames(rec, units, sensor)


def _head(frames, n):
    """The first n frames of an iterable, stacked."""
    head = []
    for f in frames:
        head.append(f)
        if len(head) == n:
            break
    return np.stack(head)


def run(args) -> int:
    enable_compilation_cache()
    sensor = SensorConfig()
    out = check_output(args.output, force=args.force)
    rec = open_recording(args.input, kind=args.input_kind)
    units, lr_stream = _lr_source(rec, args.units, sensor, args.input)
    model, described = resolve_model(args.model, _head(lr_stream(), HEAD_FRAMES), min_fps=args.min_fps)
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
    preview = None
    if out.suffix.lower() in ARRAY_FORMATS:
        result = np.empty((rec.frames, *hr_shape), np.float32)
        for t, hr in enumerate(bar):
            result[t] = to_units(hr, units, sensor)
            preview = hr if t == preview_t else preview
        if out.suffix.lower() == ".npy":
            io.write_sequence(out, result, overwrite=args.force)
        else:
            io.write_sequence(out, result, overwrite=args.force, units=units, model=described, input=str(args.input),
                              scale=r)
    else:
        out.mkdir(parents=True, exist_ok=True)
        ext = "." + args.frame_format
        for t, hr in enumerate(bar):
            io.write_depth(out / f"frame_{t:06d}{ext}", to_units(hr, "m", sensor), overwrite=args.force)
            preview = hr if t == preview_t else preview
    if args.preview:
        write_comparison(args.preview, preview_lr[0], np.clip(preview, 0, 1), d_max=float(sensor.d_max),
                         labels=("input (centre of mass)" if rec.kind == "histograms" else "input", described),
                         overwrite=args.force)
    print(json.dumps({"frames": rec.frames, "output": str(out), "shape": [rec.frames, *hr_shape],
                      "units": units, "model": described}))
    return 0
