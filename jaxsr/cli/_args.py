"""Argument types of the `jaxsr` command: numbers checked when the command line is parsed, so a bad value is
one line (`jaxsr CMD: error: argument --x: ...`) before any work starts."""

from __future__ import annotations

import argparse
import math

from .. import checks
from ..sensor import quantities


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


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


def positive_float(text: str) -> float:
    """An argparse type: a finite number > 0 (not nan, inf, 0 or negative)."""
    value = _number(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def finite_float(text: str) -> float:
    """An argparse type: a finite number (not nan or inf)."""
    value = _number(text)
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _numbers(text: str, count: tuple[int, ...], what: str) -> tuple[float, ...]:
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        values = ()
    if len(values) not in count or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return values


def fields_of_view(text: str):
    """An argparse type for --fov: degrees, horizontal (a number) or horizontal,vertical (a pair); each in (0, 180)
    is checked later, with the camera."""
    values = _numbers(text, (1, 2), "degrees, horizontal or horizontal,vertical, such as 30 or 30,15")
    return values[0] if len(values) == 1 else values


def four_numbers(text: str) -> tuple[float, ...]:
    """An argparse type for intrinsics: four finite numbers separated by commas, fx,fy,cx,cy (checked later)."""
    return _numbers(text, (4,), "four numbers fx,fy,cx,cy in pixels, such as 478,478,127.5,63.5")


def ambient_alpha(text: str):
    """An argparse type for --ambient-alpha: "auto", "off" (None) or a finite number (checked as a rate later)."""
    if text in ("auto", "off"):
        return None if text == "off" else text
    try:
        return finite_float(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected auto, off or a false-alarm rate such as 0.001, got {text!r}") from None


# Random seeds: jax.random.key takes a 64-bit integer; 32 bits are plenty and keep `seed + 1` in range.
seed = int_range(0, 2**32 - 1)


def seed_list(text: str) -> tuple[int, ...]:
    """An argparse type: distinct seeds separated by commas, such as 0,1,2 (each 0..2^32-1, at least one)."""
    parts = [part.strip() for part in text.split(",")]
    if not all(parts):
        raise argparse.ArgumentTypeError(f"expected seeds separated by commas, such as 0,1,2, got {text!r}")
    seeds = tuple(seed(part) for part in parts)
    twice = sorted({s for s in seeds if seeds.count(s) > 1})
    if twice:
        raise argparse.ArgumentTypeError(f"each seed once, got {', '.join(map(str, twice))} more than once in "
                                         f"{text!r}")
    return seeds


# Quantities with their unit (12.5ns, 2.19m): parsed by `jaxsr.sensor.quantities`, whose ValueError becomes
# argparse's one-line error.


def _argument_type(parse, name):
    def wrapped(text: str):
        try:
            return parse(text)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    wrapped.__name__ = name
    return wrapped


range_or_time = _argument_type(quantities.parse_range_or_time, "range_or_time")
range_or_time.__doc__ = """An argparse type: a time (s, ms, us, ns, ps, fs) or a range (m, km, cm, mm) with its unit, as
("s", seconds) or ("m", metres); a bare number is refused (the unit decides how it converts, r = c t / 2)."""
time_unit = _argument_type(quantities.parse_time_unit, "time_unit")
time_unit.__doc__ = "An argparse type: the duration of one unit of time tags, such as 1ps or 8ps (seconds, > 0)."
span = _argument_type(quantities.parse_span, "span")
span.__doc__ = """An argparse type: metres of range mapped onto the network's [0, 1] (a number > 0, with or without m),
or 'gate' (the gate's length)."""
memory = _argument_type(checks.parse_memory, "memory")
memory.__doc__ = "An argparse type: a size with its unit, such as 16GB or 512MiB (bytes > 0)."
