"""`jaxsr upscale`: super-resolve a recording (depth or histograms) with a trained model, streaming.

Frames stream from the input through the model to the output (see `jaxsr.io.recordings`), so a long recording
needs memory for a batch, not for the whole sequence (an .npz output holds the result; an .npy output is
written through a memory map). Everything is
checked before the model runs: the options, the output and preview paths, the model, and every input frame
(one pass; frames of any size h, w >= 4, large ones run in spatial tiles). Histograms and photon time tags are
read over a gate (--bins, --bin-width, --gate-start) and put on the network's scale with the gate's start as its
0 m and --span metres (default the trained 35 m) as its 1.0; where that takes the models outside what they were
trained on, a warning line says so. Outputs are written atomically (a folder
of frames into a hidden `.NAME.XXXX.partial` sibling, renamed when complete) and never replace an existing
file or write into a non-empty folder without --force.
"""

from __future__ import annotations

import json
import sys

import numpy as np
from tqdm.auto import tqdm

from .. import io
from ..io.files import atomic_folder, atomic_path
from ..inference.adaptive import resolve_model
from ..io.checkpoint import load_model, resolve_model_path
from ..config import METRES_PER_SECOND, TRAINED_RANGE_M, DepthScale, Gate, SensorConfig
from ..sensor.gates import gate_warnings
from ..inference.super_resolve import iter_centre_of_mass, iter_super_resolve
from ..sensor.timetags import TIME_TAG_FORMATS, gate_of_tags, read_time_tags
from ..io.previews import write_comparison
from ..io.recordings import (
    ARRAY_FORMATS,
    check_frames,
    check_output,
    check_preview,
    gate_frames,
    guess_units,
    normalised_frames,
    open_recording,
    time_tag_recording,
    to_units,
)
from ..runtime import enable_compilation_cache
from ._args import int_range, positive_float, range_or_time, span, time_unit

HEAD_FRAMES = 64  # frames --model auto measures the motion on


def add_parser(subparsers):
    p = subparsers.add_parser("upscale", help="super-resolve a recording (depth or histograms) x4 with a trained model",
                              description="Super-resolve a recording of any frame size (h, w >= 4). INPUT: .npy / "
                              ".npz array of depth (T, h, w) or photon counts (T, h, w, bins), a folder or quoted glob "
                              "pattern of EXR, PFM, TIFF or 16-bit PNG depth frames, or photon time tags (--input "
                              "timetags: a MATLAB v4-v7 .mat cell array of per-pixel arrival times, or an .npz table "
                              "'pixel', 'time', 'shape'). OUTPUT: .npy / .npz, or a folder of frames (--frame-format). "
                              "Your own sensor, e.g.: jaxsr upscale tags.mat out.npz --input timetags --time-unit 1ps "
                              "--bins 16 --bin-width 12.5ns --gate-start 5.18us")
    p.add_argument("input", help="the recording")
    p.add_argument("output", help="output .npy, .npz or folder")
    p.add_argument("--model", default="tr4", help="tr0..tr4 (bundled weights), auto (choose TR from the measured "
                   "motion), or a checkpoint path (default tr4)")
    p.add_argument("--input", dest="input_kind", choices=["depth", "histograms", "timetags"], default=None,
                   help="what INPUT holds (default: depth or histograms from the data; time tags must be named)")
    g = p.add_argument_group("histogram gate (histograms and time tags)")
    g.add_argument("--bins", type=int_range(2), default=None, help="histogram bins K (default 16)")
    g.add_argument("--bin-width", type=range_or_time, default=None,
                   help="width of a bin as a time (12.5ns, 250ps) or a range (2.19m); default 35 m / 16, or for time "
                   "tags the photons' span / bins")
    g.add_argument("--gate-start", type=range_or_time, default=None,
                   help="start of the first bin as a time (5.18us) or a range (776m); default 0, or for time tags "
                   "the first photon")
    g.add_argument("--span", type=span, default=None,
                   help=f"metres of range from the gate start mapped onto the network's [0, 1] (default "
                   f"{TRAINED_RANGE_M:g}, the models' training range), or 'gate' (the gate's length: for time tags "
                   "whose unit is unknown)")
    g.add_argument("--time-unit", type=time_unit, default=None,
                   help="time tags: duration of one time unit, such as 1ps (needed unless an .npz says time_unit_s)")
    g.add_argument("--variable", default=None, help="time tags: the .mat cell array to read (default: the only one)")
    g.add_argument("--drop-outside", action="store_true",
                   help="time tags: ignore photons outside the gate (default: refuse them)")
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


def _metres(quantity) -> float | None:
    """A parsed --bin-width / --gate-start, ("s", seconds) or ("m", metres), in metres (r = c t / 2)."""
    if quantity is None:
        return None
    unit, value = quantity
    return value * METRES_PER_SECOND if unit == "s" else value


def _gate_options(args) -> bool:
    return any(v is not None for v in (args.bins, args.bin_width, args.gate_start, args.span)) or args.drop_outside


def _open(args):
    """(recording, gate) for INPUT: time tags histogrammed over their gate, histograms with theirs, or depth
    (gate options refused there)."""
    width, start, bins = _metres(args.bin_width), _metres(args.gate_start), args.bins or 16
    tag_only = [o for o, v in (("--time-unit", args.time_unit), ("--variable", args.variable),
                               ("--drop-outside", args.drop_outside or None)) if v is not None]
    if args.input_kind == "timetags":
        if not str(args.input).lower().endswith(TIME_TAG_FORMATS):
            raise ValueError(f"{args.input}: time tags are read from a MATLAB .mat cell array (v4-v7) or an .npz "
                             "table ('pixel', 'time', 'shape')")
        tags = read_time_tags(args.input, variable=args.variable, time_unit_s=args.time_unit)
        if (width is None) != (start is None):
            raise ValueError("give both --bin-width and --gate-start, or neither (the gate then spans the photons)")
        gate = gate_of_tags(tags, bins=bins) if width is None else Gate(bins, width, start)
        return time_tag_recording(tags, gate, outside="drop" if args.drop_outside else "error"), gate
    if tag_only:
        raise ValueError(f"{', '.join(tag_only)} applies to --input timetags only")
    rec = open_recording(args.input, kind=args.input_kind)
    if rec.kind == "depth" and _gate_options(args):
        raise ValueError("--bins, --bin-width, --gate-start and --span apply to histograms and time tags only")
    default = Gate()
    return rec, Gate(bins, default.bin_width if width is None else width, 0.0 if start is None else start)


def _lr_source(rec, units_arg, sensor, gate, scale):
    """(units, a function returning a fresh stream of LR normalised frames) for an opened recording, after
    checking every frame (`check_frames`)."""
    if rec.kind == "histograms":
        units = "m" if units_arg is None else units_arg
        check_frames(rec, units, gate)
        return units, lambda: gate_frames(iter_centre_of_mass(rec, SensorConfig(bins=gate.bins)), gate, scale)
    units = guess_units(rec) if units_arg is None else units_arg
    check_frames(rec, units, gate)
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
    rec, gate = _open(args)
    if rec.kind == "histograms":
        scale = DepthScale.for_gate(gate, gate.length if args.span == "gate" else args.span)
        for warning in gate_warnings(gate, scale):
            print(f"jaxsr upscale: warning: {warning}", file=sys.stderr)
    else:
        scale = DepthScale(0.0, float(sensor.d_max))
    units, lr_stream = _lr_source(rec, args.units, sensor, gate, scale)
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
            write_comparison(args.preview, preview_lr[0], np.clip(preview[0], 0, 1), d_max=float(scale.span),
                             labels=("input (centre of mass)" if rec.kind == "histograms" else "input", described),
                             overwrite=args.force)

    if out.suffix.lower() == ".npy":  # streamed to disk: memory for a batch, not for the whole result
        with atomic_path(out, overwrite=args.force) as tmp:
            result = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.float32, shape=(rec.frames, *hr_shape))
            for t, hr in enumerate(bar):
                result[t] = to_units(hr, units, scale)
                preview += [hr] if t == preview_t else []
            result.flush()
            del result
            write_preview()
    elif out.suffix.lower() in ARRAY_FORMATS:
        result = np.empty((rec.frames, *hr_shape), np.float32)
        for t, hr in enumerate(bar):
            result[t] = to_units(hr, units, scale)
            preview += [hr] if t == preview_t else []
        with atomic_path(out, overwrite=args.force) as tmp:
            io.write_sequence(tmp, result, overwrite=True, units=units, model=described, input=str(args.input),
                              scale=r)
            write_preview()
    else:
        ext = "." + args.frame_format
        with atomic_folder(out) as tmp:
            for t, hr in enumerate(bar):
                io.write_depth(tmp / f"frame_{t:06d}{ext}", to_units(hr, "m", scale))
                preview += [hr] if t == preview_t else []
            write_preview()
    summary = {"frames": rec.frames, "output": str(out), "shape": [rec.frames, *hr_shape], "units": units,
               "model": described}
    if rec.kind == "histograms":  # the gate and the scale the metres were read and written with
        summary.update(gate={"bins": gate.bins, "bin_width_m": float(gate.bin_width), "start_m": float(gate.start)},
                       scale={"offset_m": float(scale.offset), "span_m": float(scale.span)})
    print(json.dumps(summary))
    return 0
