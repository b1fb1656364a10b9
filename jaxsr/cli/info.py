"""`jaxsr info`: describe a model (bundled weights or a checkpoint) in a few lines: its file, what it is for (the
bundled models' `BUNDLED_USES`, a fine-tune's sensor file, or a card's "purpose"), what it is and reads, its
parameters and GFLOP per frame, and its validation score; `--json` prints all of
`jaxsr.io.checkpoint.model_info`, the config and the whole training card included. What the file says is printed
escaped (no control character reaches the terminal raw; JSON escapes them too) and each line of the text is cut
at `CARD_LINE_CHARS` characters."""

from __future__ import annotations

import json
import math
from pathlib import Path

from ..app.models import BUNDLED_USES, DEFAULT_MODELS
from ..io.checkpoint import model_info
from ._text import printable, shortened

CARD_LINE_CHARS = 1000
WEIGHTS = Path(__file__).resolve().parents[1] / "weights"


def add_parser(subparsers):
    p = subparsers.add_parser("info", help="describe a model: what it is for, what it reads, parameters, FLOPs/frame, "
                                           "validation score (--json: the config and the whole training card)")
    p.add_argument("model", help="tr0..tr4, tr4-ambient, ... (bundled weights: jaxsr models), a checkpoint path or a "
                                 "run folder")
    p.add_argument("--json", action="store_true", help="print everything as JSON, the whole training card included")
    p.set_defaults(func=run)


def _finite(value):
    """`value` with every NaN or infinite float (a card may hold one: Python's json reads NaN and Infinity) as None,
    null in JSON, which has no such numbers."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def run(args) -> int:
    info = model_info(args.model)
    if args.json:
        # ASCII: control characters and the rest escaped (\u001b); strict JSON, which jq and browsers parse
        print(json.dumps(_finite(info), indent=1, allow_nan=False))
        return 0
    for line in summary(info, args.model):
        print(printable(shortened(line, CARD_LINE_CHARS)))
    return 0


def summary(info: dict, asked) -> list[str]:
    """The text of `jaxsr info`: a few lines from `model_info`'s dict (`asked`: the name or path given)."""
    card = info["card"] if isinstance(info["card"], dict) else {}
    name = _bundled_name(info["path"])
    lines = [f"{name}: bundled weights, {info['path']}" if name else info["path"]]
    purpose = _purpose(name, card)
    if purpose:
        lines.append(f"  use: {purpose}")
    reads = info.get("reads")
    reads = ("photon histograms with the HR intensity" if reads == "histograms" else
             _listed([str(c) for c in reads]) + " per LR pixel" if isinstance(reads, list) and reads else None)
    if "temporal" in info:  # what the architecture describes of itself: a network with temporal forms
        cfg, r = info["config"], info["input_radius"]
        n = info["frames_per_window"]
        form = (f"window of {n} frame{'s' * (n != 1)}" if info["temporal"] == "window" else
                f"sequence form: frame t from frames t-{r} .. t+{r}, stream latency {r} frames")
        lines.append(f"  {info['architecture'].upper()} network, TR {cfg['tr']} ({form}), x{cfg['scale']}"
                     + (f", reads {reads}" if reads else "")
                     + ("; marks no return" if info.get("marks_no_return") else ""))
        lines.append(f"  {info['parameters']:,} parameters, {info['gflops_per_frame']} GFLOP per "
                     f"{info['lr_shape'][0]}x{info['lr_shape'][1]} frame")
    else:
        lines.append(f"  {info['architecture']} (a learned baseline)" + (f", reads {reads}" if reads else ""))
        lines.append(f"  {info['parameters']:,} parameters")
    validation = _validation(card.get("validation"))
    if validation:
        lines.append(f"  validation: {validation}")
    lines.append(f"  more (config, training card): jaxsr info {asked} --json" if card or info["card"] else
                 f"  no training card; config: jaxsr info {asked} --json")
    return lines


def _bundled_name(path) -> str | None:
    """The bundled model's name when `path` is one of jaxsr/weights, else None."""
    p = Path(path)
    return p.stem if p.suffix == ".npz" and p.stem in BUNDLED_USES and p.resolve().parent == WEIGHTS else None


def _purpose(name, card: dict) -> str | None:
    """What the model is for: a bundled model's use (and what `jaxsr upscale` gives it by default), a fine-tune's
    sensor file, or a card's own "purpose" text."""
    if name:
        defaults = [kind for kind, model in DEFAULT_MODELS.items() if model == name]
        return BUNDLED_USES[name] + "".join(f"; jaxsr upscale's default for {kind} input" for kind in defaults)
    if isinstance(card.get("purpose"), str) and card["purpose"]:
        return card["purpose"]
    sensor = card.get("sensor_file")
    if isinstance(sensor, dict) and sensor.get("path"):
        start = card.get("finetune", {}).get("from") if isinstance(card.get("finetune"), dict) else None
        return (f"the sensor of {sensor['path']}" + (f": {sensor['description']}" if sensor.get("description") else "")
                + (f" (fine-tuned from {start})" if start else ""))
    return None


def _listed(words: list[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def _number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _validation(v) -> str | None:
    """'25.86 dB PSNR (bicubic 13.36 dB), 1500 frames of val1_street, ...' from a card's "validation", if any."""
    if not isinstance(v, dict) or not _number(v.get("psnr")):
        return None
    text = f"{v['psnr']:.2f} dB PSNR"
    if _number(v.get("bicubic_psnr")):
        text += f" (bicubic {v['bicubic_psnr']:.2f} dB)"
    frames, sequences = v.get("frames"), v.get("sequences")
    where = ", ".join(map(str, sequences)) if isinstance(sequences, list) else None
    if _number(frames) or where:
        text += ", " + (f"{frames:,} frames" if _number(frames) else "") + (" of " if _number(frames) and where else "")
        text += where or ""
    return text
