"""`jaxsr info`: describe a model (bundled weights or a checkpoint): config, parameters, FLOPs per frame and its
training card, as text or JSON (`jaxsr.io.checkpoint.model_info`). What the file says is printed escaped (no control
character reaches the terminal raw; JSON escapes them too) and each card entry of the text is cut at
`CARD_LINE_CHARS` characters (`--json` prints it whole)."""

from __future__ import annotations

import json

from ..io.checkpoint import model_info
from ._text import printable, shortened

CARD_LINE_CHARS = 1000


def add_parser(subparsers):
    p = subparsers.add_parser("info", help="describe a model: config, parameters, FLOPs/frame, training card")
    p.add_argument("model", help="tr0..tr4 (bundled weights) or a checkpoint path")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    info = model_info(args.model)
    if args.json:
        print(json.dumps(info, indent=1))  # ASCII: control characters and the rest escaped (\u001b)
        return 0
    cfg = info["config"]
    lines = [info["path"]]
    if "temporal" in info:  # what the architecture describes of itself: a network with temporal forms
        r = info["input_radius"]
        form = (f"window of {info['frames_per_window']} frames" if info["temporal"] == "window" else
                f"sequence form: frame t from frames t-{r} .. t+{r}, stream latency {r} frames")
        lines.append(f"  TR {cfg['tr']} ({form}), x{cfg['scale']}, {info['parameters']:,} parameters, "
                     f"{info['gflops_per_frame']} GFLOP per {info['lr_shape'][0]}x{info['lr_shape'][1]} frame")
    else:
        lines.append(f"  {info['architecture']} (a learned baseline), {info['parameters']:,} parameters")
    lines.append("  config: " + ", ".join(f"{k}={v}" for k, v in cfg.items()))
    card = info["card"]
    if isinstance(card, dict) and card:
        lines.append("  training card:")
        lines += [shortened(f"    {k}: {json.dumps(v)}", CARD_LINE_CHARS) for k, v in card.items()]
    elif card:  # not a JSON object: shown as it is
        lines.append(shortened(f"  training card: {json.dumps(card)}", CARD_LINE_CHARS))
    else:
        lines.append("  no training card")
    for line in lines:
        print(printable(line))
    return 0
