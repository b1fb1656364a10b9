"""The `jaxsr` command: argument parsing and the subcommand runners, nothing else (the work is done by the
library modules they call).

    jaxsr simulate --kind street --frames 20 --fps 25 --snr 1.3 --seed 0 --out DIR [--force]
    jaxsr simulate --input AIRSIM_FOLDER --out DIR [--snr 1.3]
    jaxsr train --tr 4 --preset cpu --out runs/tr4 [--resume]
    jaxsr upscale INPUT OUTPUT [--model tr4|auto|CHECKPOINT] [--preview strip.png]
    jaxsr info tr4 [--json]

Each subcommand is a module here with `add_parser(subparsers)`, which registers its arguments and sets
`func=run`, and `run(args) -> exit status`. To add one, write such a module and list it in `COMMANDS`.
A user error (a missing file, an existing output, a bad value) is printed as `jaxsr CMD: error: ...` and
exits with status 2, as argparse does for bad arguments.
"""

from __future__ import annotations

import argparse
import sys

from . import info, simulate, train, upscale

__all__ = ["COMMANDS", "build_parser", "main"]

COMMANDS = (simulate, train, upscale, info)


def build_parser() -> argparse.ArgumentParser:
    """The `jaxsr` parser with every subcommand of `COMMANDS`; a subcommand is required."""
    parser = argparse.ArgumentParser(prog="jaxsr", description="Video super-resolution for single-photon lidar.")
    subparsers = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add_parser(subparsers)
    return parser


def main(argv=None) -> int:
    """Entry point of the `jaxsr` console script.

    Args: argv (list of str, default sys.argv[1:]). Returns the exit status (0 on success, 2 on a user error
    such as a missing file or an existing output, after printing the message to stderr)."""
    args = build_parser().parse_args(argv)
    if argv is None:  # run as a program (not called from Python, where the user owns JAX's devices)
        from ..runtime import use_cpu_cores

        use_cpu_cores()
    try:
        return args.func(args)
    except (FileNotFoundError, FileExistsError, ValueError) as e:
        print(f"jaxsr {args.command}: error: {e}", file=sys.stderr)
        return 2
