"""`jaxsr models`: the bundled models, a line each: its name, what it reads, its TR, whether it marks no return,
and when to use it (`jaxsr.app.models.bundled_models`); `--json` prints the same as JSON."""

from __future__ import annotations

import json

from ..app.models import bundled_models


def add_parser(subparsers):
    p = subparsers.add_parser("models", help="list the bundled models and when to use each",
                              description="The bundled models: name, what each reads per pixel, its temporal "
                              "radius, and when to use it. Give a name to --model of jaxsr upscale, or to jaxsr info.")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    rows = bundled_models()
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    width = max(len(r["name"]) for r in rows)
    for r in rows:
        tr = "   " if r["tr"] is None else f"TR{r['tr']}"
        default = f" [default for {' and '.join(r['default_for'])}]" if r["default_for"] else ""
        print(f"{r['name']:<{width}}  {tr}  reads {r['reads']}{', marks no return' if r['marks_no_return'] else ''}"
              f": {r['use']}{default}")
    print("paper-tr0 .. paper-tr4: always the paper's TR0-TR4 (tr0 .. tr4 today)")
    return 0
