"""`jaxsr info`: describe a model (bundled weights or a checkpoint): config, parameters, FLOPs per frame and its
training card, as text or JSON (`jaxsr.io.checkpoint.model_info`)."""

from __future__ import annotations

import json

from ..io.checkpoint import model_info


def add_parser(subparsers):
    p = subparsers.add_parser("info", help="describe a model: config, parameters, FLOPs/frame, training card")
    p.add_argument("model", help="tr0..tr4 (bundled weights) or a checkpoint path")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    info = model_info(args.model)
    if args.json:
        print(json.dumps(info, indent=1))
        return 0
    cfg = info["config"]
    if info["architecture"] == "duf":
        r = info["input_radius"]
        form = (f"window of {info['frames_per_window']} frames" if info["temporal"] == "window" else
                f"sequence form: frame t from frames t-{r} .. t+{r}, stream latency {r} frames")
        print(f"{info['path']}\n  TR {cfg['tr']} ({form}), x{cfg['scale']}, "
              f"{info['parameters']:,} parameters, {info['gflops_per_frame']} GFLOP per {info['lr_shape'][0]}x"
              f"{info['lr_shape'][1]} frame")
    else:
        print(f"{info['path']}\n  {info['architecture']} (a learned baseline), {info['parameters']:,} parameters")
    print("  config: " + ", ".join(f"{k}={v}" for k, v in cfg.items()))
    card = info["card"]
    if card:
        print("  training card:")
        for k, v in card.items():
            print(f"    {k}: {json.dumps(v)}")
    else:
        print("  no training card")
    return 0
