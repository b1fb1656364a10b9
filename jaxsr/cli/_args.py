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


# Units of the quantities a sensor is described by: seconds of round-trip time, or metres of radial range.
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9, "ps": 1e-12, "fs": 1e-15}
RANGE_UNITS = {"m": 1.0, "km": 1e3, "cm": 1e-2, "mm": 1e-3}


def _split_quantity(text: str, units: dict, what: str):
    """(number, unit factor) of a quantity such as 12.5ns, or None if its unit is not in `units`."""
    for unit in sorted(units, key=len, reverse=True):
        if text.strip().endswith(unit):
            number = text.strip()[: -len(unit)].strip()
            try:
                value = float(number)
            except ValueError:
                raise argparse.ArgumentTypeError(f"expected {what} such as 12.5ns or 2.19m, got {text!r}") from None
            if not math.isfinite(value):
                raise argparse.ArgumentTypeError(f"expected a finite {what}, got {text!r}")
            return value * units[unit]
    return None


def range_or_time(text: str) -> tuple[str, float]:
    """An argparse type: a time (s, ms, us, ns, ps, fs) or a range (m, km, cm, mm) with its unit, as ("s", seconds)
    or ("m", metres); a bare number is refused (the unit decides how it converts, r = c t / 2)."""
    seconds = _split_quantity(text, TIME_UNITS, "a time or range")
    if seconds is not None:
        return "s", seconds
    metres = _split_quantity(text, RANGE_UNITS, "a time or range")
    if metres is not None:
        return "m", metres
    raise argparse.ArgumentTypeError(f"expected a time or range with its unit (s, ms, us, ns, ps, fs; m, km, cm, mm), "
                                     f"such as 12.5ns or 2.19m, got {text!r}")


def time_unit(text: str) -> float:
    """An argparse type: the duration of one unit of time tags, such as 1ps or 8ps (seconds, > 0)."""
    seconds = _split_quantity(text, TIME_UNITS, "a duration")
    if seconds is None or not seconds > 0:
        raise argparse.ArgumentTypeError(f"expected a duration > 0 with its unit (s, ms, us, ns, ps, fs), such as "
                                         f"1ps, got {text!r}")
    return seconds


def span(text: str) -> float | str:
    """An argparse type: metres of range mapped onto the network's [0, 1] (a number > 0, with or without m), or
    'gate' (the gate's length)."""
    if text.strip() == "gate":
        return "gate"
    metres = _split_quantity(text, RANGE_UNITS, "a range")
    if metres is None:
        metres = positive_float(text)
    if not (math.isfinite(metres) and metres > 0):
        raise argparse.ArgumentTypeError(f"expected a range > 0 in metres or 'gate', got {text!r}")
    return metres
