"""Argument types of the `jaxsr` command: numbers checked when the command line is parsed, so a bad value is
one line (`jaxsr CMD: error: argument --x: ...`) before any work starts."""

from __future__ import annotations

import argparse
import math


def int_range(lo: int, hi: int | None = None, why: str = ""):
    """An argparse type: an integer in [lo, hi] (no upper bound when hi is None); `why` explains the bound."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < lo or (hi is not None and value > hi):
            want = f">= {lo}" if hi is None else f"from {lo} to {hi}"
            raise argparse.ArgumentTypeError(f"expected an integer {want}, got {value}" + (f" ({why})" if why else ""))
        return value

    return parse


def positive_float(text: str) -> float:
    """An argparse type: a finite number > 0 (not nan, inf, 0 or negative)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


# Random seeds: jax.random.key takes a 64-bit integer; 32 bits are plenty and keep `seed + 1` in range.
seed = int_range(0, 2**32 - 1)
