"""`jaxsr upscale` and `jaxsr info`: run a model on a recording, and describe a model.

Inputs stream frame by frame where the format allows (a folder or pattern of image frames, or an .npy read
through a memory map), so a long recording needs memory for a batch, not for the whole sequence. Outputs are
written atomically and never replace an existing file or a non-empty folder without `--force`.
"""

from __future__ import annotations

import glob
import json
import sys
from pathlib import Path

import numpy as np

from . import io
from .config import SensorConfig
from .previews import write_comparison
from .sensor import denormalise_depth, normalise_depth

FRAME_FORMATS = (".exr", ".pfm", ".tif", ".tiff", ".png")
ARRAY_FORMATS = (".npy", ".npz")


# ---------------------------------------------------------------------------------------------------------
# Input


class Recording:
    """A recording opened for reading: `kind` ("depth" or "histograms"), `frames` (the number of frames),
    `shape` (of one frame) and `__iter__` over frames (NumPy, as stored)."""

    def __init__(self, kind, frames, shape, reader, source):
        self.kind, self.frames, self.shape, self._reader, self.source = kind, frames, shape, reader, source

    def __iter__(self):
        return self._reader()

    def head(self, n):
        """The first n frames as one array."""
        out = []
        for f in self:
            out.append(np.asarray(f))
            if len(out) == n:
                break
        return np.stack(out)


def _frame_files(spec: str) -> list[Path]:
    p = Path(spec)
    if p.is_dir():
        files = sorted(f for f in p.iterdir() if f.suffix.lower() in FRAME_FORMATS)
        if not files:
            raise ValueError(f"{spec}: no depth frames ({', '.join(FRAME_FORMATS)}) in this folder")
        return files
    if any(c in spec for c in "*?["):
        files = sorted(Path(f) for f in glob.glob(spec))
        if not files:
            raise FileNotFoundError(f"{spec}: the pattern matches no file")
        bad = [f.name for f in files if f.suffix.lower() not in FRAME_FORMATS]
        if bad:
            raise ValueError(f"{spec}: matches files that are not depth frames ({', '.join(FRAME_FORMATS)}): "
                             f"{bad[:3]}")
        return files
    raise FileNotFoundError(f"no such file or folder: {spec}")


def _kind_of(ndim, requested, source):
    kind = requested or {3: "depth", 4: "histograms"}.get(ndim)
    want = {"depth": 3, "histograms": 4}
    if kind is None or ndim != want[kind]:
        raise ValueError(f"{source}: expected depth (T, h, w) or histograms (T, h, w, bins), got {ndim} "
                         f"dimensions" + (f" for --input {requested}" if requested else ""))
    return kind


def open_recording(spec, *, kind: str | None = None) -> Recording:
    """Open INPUT: an .npy array, an .npz from `write_sequence` (depth) or `write_histograms` (counts), or a
    folder or glob pattern of EXR / PFM / TIFF / 16-bit PNG depth frames (sorted by name).
    kind: "depth", "histograms" or None (from the data: 4 dimensions or a `counts` array = histograms)."""
    spec = str(spec)
    p = Path(spec)
    suffix = p.suffix.lower()
    if suffix in ARRAY_FORMATS and not any(c in spec for c in "*?["):
        if not p.is_file():
            raise FileNotFoundError(f"no such file: {spec}")
        if suffix == ".npy":
            try:
                arr = np.load(p, mmap_mode="r", allow_pickle=False)
            except (ValueError, OSError) as e:
                raise ValueError(f"cannot read {spec}: truncated or not an NPY file ({e})") from e
        else:
            z = io.read_npz_arrays(p)
            name = "counts" if "counts" in z and kind != "depth" else "depth"
            if name not in z:
                raise ValueError(f"{spec}: expected an array 'depth' or 'counts', found {sorted(z)}")
            arr = z[name]
        if arr.ndim == 2 and kind != "histograms":  # one frame
            arr = arr[None]
        k = _kind_of(arr.ndim, kind, spec)
        if arr.shape[0] < 1:
            raise ValueError(f"{spec}: the recording has no frames")
        return Recording(k, arr.shape[0], arr.shape[1:], lambda: iter(arr), spec)
    if suffix in ARRAY_FORMATS:
        raise ValueError(f"{spec}: patterns select image frames ({', '.join(FRAME_FORMATS)}), not {suffix} arrays")
    if kind == "histograms":
        raise ValueError(f"{spec}: histograms are read from .npy or .npz arrays, not from image frames")
    files = _frame_files(spec)
    first = io.read_depth(files[0])

    def frames():
        for f in files:
            d = io.read_depth(f)
            if d.shape != first.shape:
                raise ValueError(f"{f}: frame of shape {d.shape}, expected {first.shape} like {files[0].name}")
            yield d

    return Recording("depth", len(files), first.shape, frames, spec)


def normalised_frames(recording: Recording, units: str, sensor: SensorConfig):
    """Depth frames of a recording as LR normalised depth, checked: metres -> `normalise_depth`."""
    for t, f in enumerate(recording):
        f = np.asarray(f, np.float32)
        if np.any(np.isnan(f)):
            raise ValueError(f"{recording.source}: frame {t} holds NaN; expected depth (inf = no return)")
        if units == "m":
            yield np.asarray(normalise_depth(f, sensor))
        else:
            if not np.all((f >= 0) & (f <= 1)):
                raise ValueError(f"{recording.source}: frame {t} has values outside [0, 1]; for depth in metres "
                                 "pass --units m")
            yield f


def guess_units(recording: Recording) -> str:
    """"normalised" when the first frame is finite and within [0, 1] (no lidar scene lies within a metre), else "m"."""
    f = np.asarray(recording.head(1)[0], np.float32)
    return "normalised" if np.all(np.isfinite(f)) and f.min() >= 0 and f.max() <= 1 else "m"


# ---------------------------------------------------------------------------------------------------------
# Output


def check_output(spec, *, force: bool) -> Path:
    """OUTPUT: .npy / .npz (one array) or a folder (one frame file per frame). Refuses to replace an existing
    file or a non-empty folder unless `force`."""
    out = Path(spec)
    if out.suffix.lower() in ARRAY_FORMATS:
        if out.exists() and not force:
            raise FileExistsError(f"{out} exists; pass --force to overwrite it")
        if not out.parent.is_dir():
            raise FileNotFoundError(f"no such folder for the output: {out.parent}")
    elif out.suffix:
        raise ValueError(f"{out}: OUTPUT is an .npy or .npz file, or a folder for frames (see --frame-format)")
    elif out.is_file() or (out.is_dir() and any(out.iterdir()) and not force):
        raise FileExistsError(f"{out} exists and is not an empty folder; pass --force to write into it")
    return out


def to_units(hr, units, sensor):
    """Network output (normalised) -> the input's units: clipped to [0, 1], or metres with inf for no
    return (`jaxsr.sensor.denormalise_depth`)."""
    if units == "normalised":
        return np.clip(hr, 0.0, 1.0)
    return np.asarray(denormalise_depth(hr, sensor), np.float32)


# ---------------------------------------------------------------------------------------------------------
# Commands


def _load(spec):
    from .checkpoint import load_model

    return load_model(spec)


def resolve_model(spec, lr_head, *, min_fps=None):
    """--model: tr0..tr4 (bundled), a checkpoint path, or auto (`jaxsr.adaptive.choose_tr` on the first frames).
    Returns (model, description)."""
    if spec == "auto":
        from .adaptive import choose_tr

        choice = choose_tr(lr_head, min_fps=min_fps)
        return _load(f"tr{choice.tr}"), f"tr{choice.tr} (auto: {choice.reason})"
    return _load(spec), str(spec)


def run_upscale(args) -> int:
    from tqdm.auto import tqdm

    from .inference import iter_centre_of_mass, iter_super_resolve
    from .runtime import enable_compilation_cache

    enable_compilation_cache()
    sensor = SensorConfig()
    out = check_output(args.output, force=args.force)
    rec = open_recording(args.input, kind=args.input_kind)
    if rec.kind == "histograms":
        if rec.shape[-1] != sensor.bins:
            raise ValueError(f"{args.input}: histograms have {rec.shape[-1]} bins, the sensor model has {sensor.bins}")
        units = "m" if args.units is None else args.units

        def lr_stream():
            return iter_centre_of_mass(rec, sensor)
    else:
        units = guess_units(rec) if args.units is None else args.units

        def lr_stream():
            return normalised_frames(rec, units, sensor)
    head = []
    for f in lr_stream():
        head.append(f)
        if len(head) == 64:
            break
    model, described = resolve_model(args.model, np.stack(head), min_fps=args.min_fps)
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


def add_upscale(subparsers):
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
    p.set_defaults(func=run_upscale)


def model_info(spec, *, lr_shape=(32, 64)) -> dict:
    """Config, parameter count, FLOPs per frame at `lr_shape` and the training card of a model."""
    from .checkpoint import _resolve, read_metadata
    from .model import count_params, flops_per_frame

    model = _load(spec)
    meta = read_metadata(_resolve(spec))
    cfg = model.config
    return {
        "path": str(_resolve(spec)),
        "config": json.loads(json.dumps(meta["config"])),
        "frames_per_window": cfg.frames,
        "parameters": count_params(model.params),
        "lr_shape": list(lr_shape),
        "gflops_per_frame": round(flops_per_frame(cfg, lr_shape) / 1e9, 3),
        "card": meta.get("card", {}),
    }


def run_info(args) -> int:
    info = model_info(args.model)
    if args.json:
        print(json.dumps(info, indent=1))
        return 0
    cfg = info["config"]
    print(f"{info['path']}\n  TR {cfg['tr']} (window of {info['frames_per_window']} frames), x{cfg['scale']}, "
          f"{info['parameters']:,} parameters, {info['gflops_per_frame']} GFLOP per {info['lr_shape'][0]}x"
          f"{info['lr_shape'][1]} frame")
    print("  config: " + ", ".join(f"{k}={v}" for k, v in cfg.items()))
    card = info["card"]
    if card:
        print("  training card:")
        for k, v in card.items():
            print(f"    {k}: {json.dumps(v)}")
    else:
        print("  no training card")
    return 0


def add_info(subparsers):
    p = subparsers.add_parser("info", help="describe a model: config, parameters, FLOPs/frame, training card")
    p.add_argument("model", help="tr0..tr4 (bundled weights) or a checkpoint path")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run_info)
