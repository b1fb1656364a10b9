"""`jaxsr upscale`: super-resolve a recording (depth, histograms or photon time tags) with a trained model.

Argument parsing and messages only: the flags become the application's four specifications (`jaxsr.app.Reading`,
`ModelChoice`, `PhotonRules`, `Writing`) and the work is `jaxsr.app.upscale`. Frames stream from the input through the model to the output, so a long recording needs memory for a
batch, not for the whole sequence. Everything is checked before the model runs: the options, the output and
preview paths, the model, and every input frame. Histograms and photon time tags are read over a gate (--bins,
--bin-width, --gate-start) and put on the network's scale with the gate's start as its 0 m and --span metres
(default the depth the recording's returns reach) as its 1.0; where that takes the models outside what they
were trained on, a warning line says so. Negative counts (background-subtracted histograms) are refused unless
--clip-negative, which clips them at 0 and says how many, in how many pixels. Outputs are written atomically and never replace an existing
file or write into a non-empty folder without --force. --video writes an .mp4 / .gif to watch (input | output |
--reference) and --points PLY point clouds (a folder of one per frame, or one file), both streamed frame by frame
over the sensor's true range in metres. Prints a JSON summary on stdout (`UpscaleResult.summary()`).
"""

from __future__ import annotations

import argparse
import json
import sys

from ..app import (AUTO_AMBIENT_ALPHA, AUTO_AMBIENT_MIN_FRAMES, AUTO_AMBIENT_MIN_SIGNAL_SNR, AUTO_AMBIENT_MIN_SNR,
                   AUTO_KEEP_RETURNS, DEPTH_UNITS, FRAME_FORMATS, KINDS, ModelChoice, PhotonRules, Reading, Writing,
                   upscale)
from ..config import PRECISIONS
from ..inference import DEFAULT_FORM, DEFAULT_PRECISION, FORMS
from ..checks import MEMORY_SHARE
from ..sensor import HOLE_PIXELS
from ._args import (OldSpelling, add_force, add_output, add_quiet, ambient_alpha, fields_of_view, finite_float,
                    four_numbers, int_range, memory, positive_float, range_or_time, required_output, span, time_unit)


def add_parser(subparsers):
    p = subparsers.add_parser("upscale", help="super-resolve a recording (depth or histograms) x4 with a trained model",
                              description="Super-resolve a recording of any frame size (h, w >= 4). INPUT: .npy / "
                              ".npz array of depth (T, h, w) or photon counts (T, h, w, bins), a folder or quoted glob "
                              "pattern of EXR, PFM, TIFF or 16-bit PNG depth frames, or photon time tags (--kind "
                              "timetags: a MATLAB v4-v7 .mat cell array of per-pixel arrival times, or an .npz table "
                              "'pixel', 'time', 'shape'). -o/--output: .npy / .npz, or a folder of frames "
                              "(--frame-format). Your own sensor, e.g.: jaxsr upscale tags.mat -o out.npz -k timetags "
                              "--time-unit 1ps --sensor my_sensor.toml (or --bins 16 --bin-width 12.5ns --gate-start "
                              "5.18us)")
    p.add_argument("input", help="the recording")
    p.add_argument("old_output", nargs="?", default=None, metavar="OUTPUT",
                   help="the old spelling of -o/--output (goes in the next release)")
    add_output(p, "output .npy, .npz or folder", old_out=False)
    p.add_argument("-m", "--model", default="default", help="default (the bundled model that fits the input), tr0..tr4 "
                   "(bundled weights; paper-tr0..paper-tr4 always the paper's), auto (choose the model from the "
                   "measured motion and, for histograms and time tags, photons), or a checkpoint path")
    p.add_argument("-k", "--kind", dest="input_kind", choices=list(KINDS), default=None,
                   help="what INPUT holds (default: depth or histograms from the data; time tags must be named)")
    p.add_argument("--input", dest="input_kind", choices=list(KINDS), action=OldSpelling, new="-k/--kind",
                   help=argparse.SUPPRESS)
    g = p.add_argument_group("histogram gate (histograms and time tags)")
    g.add_argument("--sensor", default=None, metavar="FILE",
                   help="the sensor's TOML file, as jaxsr finetune --sensor takes it (docs/own-sensor.md): its gate, "
                   "depth scale and pulse, instead of --bins, --bin-width, --gate-start and --span")
    g.add_argument("--bins", type=int_range(2), default=None, help="histogram bins K (default: the histograms' own; 16 for time tags)")
    g.add_argument("--bin-width", type=range_or_time, default=None,
                   help="width of a bin as a time (12.5ns, 250ps) or a range (2.19m); default 35 m / 16, or for time "
                   "tags the photons' span / bins")
    g.add_argument("--gate-start", type=range_or_time, default=None,
                   help="start of the first bin as a time (5.18us) or a range (776m); default 0, or for time tags "
                   "the first photon")
    g.add_argument("--span", type=span, default=None,
                   help="metres of range from the gate start mapped onto the network's [0, 1], or 'gate' (the "
                   "gate's length); default: the depth the first 64 frames' returns reach (their 99th percentile "
                   "plus 10 %%, at least 16 bins, at most the gate)")
    g.add_argument("--time-unit", type=time_unit, default=None,
                   help="time tags: duration of one time unit, such as 1ps (needed unless an .npz says time_unit_s)")
    g.add_argument("--variable", default=None, help="time tags: the .mat cell array to read (default: the only one)")
    g.add_argument("--drop-outside", action="store_true",
                   help="time tags: ignore photons outside the gate (default: refuse them)")
    g.add_argument("--clip-negative", action="store_true",
                   help="histograms: clip negative counts at 0 (background-subtracted histograms, as some published "
                   "data are) and say how many, in how many pixels (default: refuse them)")
    p.add_argument("--units", choices=list(DEPTH_UNITS), default=None,
                   help="depth units of INPUT and OUTPUT: radial metres (inf = no return), mm, cm or km (0 is no "
                   "return too in mm and cm, as in 16-bit depth images), or normalised [0, 1] (1 = no return); "
                   "default: normalised if the first frame lies in [0, 1], else metres, but never a guess for "
                   "integer arrays (mm? cm?) or values that could be km; histograms give metres")
    p.add_argument("--frame-format", choices=list(FRAME_FORMATS), default=None,
                   help="frame files when OUTPUT is a folder (default exr; always metres; 16-bit png holds 1 mm to "
                   "65.535 m)")
    p.add_argument("--batch-size", type=int_range(1), default=None,
                   help="frames per compiled call (default: one per CPU core, each core a JAX device; in the sequence "
                   "form the output frames of a chunk, default 32)")
    p.add_argument("--precision", choices=list(PRECISIONS), default=DEFAULT_PRECISION,
                   help="how the network's convolutions multiply: default (the backend's: float32 on CPU), float32, "
                   "or bfloat16 (bfloat16 operands, float32 sums: within 0.05 dB on the test sequences; faster only "
                   "where the hardware and XLA multiply bfloat16, see docs/cli.md)")
    p.add_argument("--form", choices=list(FORMS), default=DEFAULT_FORM,
                   help="the network's temporal form: auto (default: the model's own form, or the sequence form where "
                   "its card records the two forms measured equivalent, as the bundled tr3 and tr4 do; never the "
                   "recording's length), model (as the checkpoint says), window, or sequence")
    p.add_argument("--no-return-logit", type=finite_float, default=None, metavar="LOGIT",
                   help="models with a no-return head (tr0-photons, tr4-photons, tr0-ambient, tr4-ambient): output "
                   "no return where the logit of the probability of no return is above LOGIT (default the model's, "
                   "0 = P(return) below 0.5). On histograms and time tags (--keep-returns auto) that probability is "
                   "the confidence, which weighs the head's logit with each pixel's photons; with --keep-returns "
                   "off or a rate, the head's own. Higher drops fewer true returns and leaves more sky as depth "
                   "(docs/network.md, photon inputs and no return; the confidence)")
    p.add_argument("--ambient-alpha", type=ambient_alpha, default="auto", metavar="{auto,off,ALPHA}",
                   help="histograms and time tags: also output no return where the photons of 3 x 3 pixels and 9 "
                   "frames around a pixel pass for ambient light alone at false-alarm rate ALPHA, such as 0.001: "
                   "it empties sky that a model shows as depth, and may drop returns too faint to stand out even "
                   "summed (a lower ALPHA empties more and drops more). auto (default): "
                   f"{AUTO_AMBIENT_ALPHA:g} where the recording's frame SNR is {AUTO_AMBIENT_MIN_SNR:g} or more or its "
                   f"signal photons per pixel and frame times that SNR {AUTO_AMBIENT_MIN_SIGNAL_SNR:g} or more, "
                   f"else off, and off for --clip-negative counts, models with a no-return head and recordings of "
                   f"fewer than {AUTO_AMBIENT_MIN_FRAMES} frames (docs/network.md); off: never")
    p.add_argument("--keep-returns", type=ambient_alpha, default="auto", metavar="{auto,off,ALPHA}",
                   help="histograms and time tags, models with a no-return head: how no return is decided. auto "
                   "(default): where the confidence's P(return) (the head's logit and each pixel's photons over 9 "
                   "frames) is below --no-return-logit's threshold (0.5 by default) and the pixel's own photons over "
                   "9 frames, and those of the quiet pixels pooled in the 3 x 3 and 5 x 5 around it, pass for ambient "
                   f"light alone at {AUTO_KEEP_RETURNS:g}, outside the holes that returns enclose (up to "
                   f"{HOLE_PIXELS} LR pixels); the head alone beside an "
                   "--ambient-alpha rate and for --clip-negative counts. ALPHA, such as 0.001: the rule before the "
                   "confidence, the head's own logit in place of P(return) and the photons' test at that "
                   "false-alarm rate. off: the head decides alone (docs/network.md)")
    p.add_argument("--max-memory", type=memory, default=None, metavar="SIZE",
                   help=f"the memory the command may take, such as 16GB (default {MEMORY_SHARE * 100:.0f}%% of this "
                   "machine's RAM): the input's arrays and the work are estimated before they allocate, and refused beyond it")
    p.add_argument("--min-fps", type=positive_float, default=None,
                   help="with --model auto: the slowest acceptable frames/s")
    p.add_argument("--preview", default=None, help="write an input | output PNG strip of the middle frame")
    g = p.add_argument_group("pictures to look at (one colour scale in metres: the recording's depth range, or "
                             "--vmin, --vmax)")
    g.add_argument("--video", default=None, metavar="PATH",
                   help="write an .mp4 or .gif of every frame: input (nearest-neighbour upscaled) | output (| "
                   "reference), one colour scale with a colour bar in metres, no return black, the frame number")
    g.add_argument("--fps", type=positive_float, default=None, metavar="F",
                   help="--video's frames per second (default: the recording's where its .npz says, else 25)")
    g.add_argument("--reference", default=None, metavar="PATH",
                   help="--video: HR depth (T, H, W) to show beside the output, e.g. the ground truth (the "
                   "formats of INPUT's depth; metres or normalised)")
    g.add_argument("--points", default=None, metavar="DIR|FILE.ply",
                   help="write PLY point clouds in metres: one a frame into DIR, or the whole sequence into FILE.ply "
                   "(a frame index per point); no-return pixels left out; coloured by depth")
    g.add_argument("--fov", type=fields_of_view, default=None, metavar="DEG[,DEG]",
                   help="--points: the fields of view in degrees, horizontal or horizontal,vertical (default 30, "
                   "the sensor model's, square pixels)")
    g.add_argument("--intrinsics", type=four_numbers, default=None, metavar="FX,FY,CX,CY",
                   help="--points: the camera's focal lengths and principal point in HR pixels (OpenCV's: pixel "
                   "centres at integers)")
    g.add_argument("--lr-intrinsics", type=four_numbers, default=None, metavar="FX,FY,CX,CY",
                   help="--points: the same for the LR sensor, scaled to HR by the model's scale")
    g.add_argument("--points-depth", choices=["radial", "planar"], default=None,
                   help="--points: the depth is radial range (default, the sensor's) or planar z")
    g.add_argument("--points-axes", choices=["opencv", "opengl"], default=None,
                   help="--points: opencv (default: x right, y down, z forward) or opengl (x right, y up, z "
                   "backward)")
    g.add_argument("--vmin", type=finite_float, default=None, metavar="M",
                   help="the colour scale's first depth in metres (default: the recording's nearest returns)")
    g.add_argument("--vmax", type=finite_float, default=None, metavar="M",
                   help="the colour scale's last depth in metres (default: the recording's farthest returns)")
    g.add_argument("--cmap", default=None, metavar="NAME",
                   help="the colour map of previews, videos and point clouds (a matplotlib name; default turbo)")
    g.add_argument("--points-colour", choices=["depth", "none"], default=None,
                   help="--points: colour the points by depth (default) or write x, y, z only")
    add_force(p, "overwrite the output (and the preview, video and point clouds)")
    add_quiet(p)
    p.set_defaults(func=run)


def run(args) -> int:
    if args.points_colour is not None and args.points is None:
        raise ValueError("--points-colour applies to --points only")
    if args.old_output is not None:
        if args.output is not None:
            raise ValueError(f"two outputs: {args.old_output} and -o/--output {args.output}; give -o/--output alone")
        args.output = args.old_output
        print("jaxsr upscale: warning: OUTPUT after INPUT is the old spelling of -o/--output OUTPUT and goes in the "
              "next release", file=sys.stderr)
    output = required_output(args)
    read = Reading(kind=args.input_kind, bins=args.bins, bin_width=args.bin_width, gate_start=args.gate_start,
                   span=args.span, time_unit=args.time_unit, variable=args.variable, drop_outside=args.drop_outside,
                   clip_negative=args.clip_negative, units=args.units, sensor=args.sensor)
    model = ModelChoice(args.model, form=args.form, precision=args.precision, no_return_logit=args.no_return_logit,
                        min_fps=args.min_fps)
    photons = PhotonRules(ambient_alpha=args.ambient_alpha, keep_returns=args.keep_returns)
    write = Writing(frame_format=args.frame_format, preview=args.preview, video=args.video, fps=args.fps,
                    reference=args.reference, points=args.points, fov_deg=args.fov,
                    intrinsics=args.intrinsics, lr_intrinsics=args.lr_intrinsics, points_depth=args.points_depth,
                    points_axes=args.points_axes,
                    points_colour=None if args.points_colour == "none" else "depth", overwrite=args.force,
                    vmin=args.vmin, vmax=args.vmax, cmap=args.cmap)
    result = upscale(args.input, output, model=model, read=read, photons=photons, write=write,
                     batch_size=args.batch_size, max_memory=args.max_memory, progress=not args.no_progress,
                     report=lambda line: print(f"jaxsr upscale: {line}", file=sys.stderr, flush=True))
    print(json.dumps(result.summary()))
    return 0
