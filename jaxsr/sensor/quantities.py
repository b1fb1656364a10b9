"""Quantities a sensor is described by, written with their unit: a time of round trip (12.5ns, 5.18us) or a
radial range (2.19m, 776m), converted with r = c t / 2. The `jaxsr` command parses its options with these;
`jaxsr.upscale` takes the same strings, or plain numbers in metres and seconds."""

from __future__ import annotations

import math

from ..config import METRES_PER_SECOND

__all__ = ["TIME_UNITS", "RANGE_UNITS", "parse_range_or_time", "parse_time_unit", "parse_span", "range_metres"]

# seconds of round-trip time, or metres of radial range, per unit
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9, "ps": 1e-12, "fs": 1e-15}
RANGE_UNITS = {"m": 1.0, "km": 1e3, "cm": 1e-2, "mm": 1e-3}


def _split_quantity(text: str, units: dict, what: str):
    """The value of a quantity such as 12.5ns in units of `units` (seconds or metres), or None if its unit is not
    one of them. Raises ValueError for a bad or non-finite number."""
    for unit in sorted(units, key=len, reverse=True):
        if text.strip().endswith(unit):
            number = text.strip()[: -len(unit)].strip()
            try:
                value = float(number)
            except ValueError:
                raise ValueError(f"expected {what} such as 12.5ns or 2.19m, got {text!r}") from None
            if not math.isfinite(value):
                raise ValueError(f"expected a finite {what}, got {text!r}")
            return value * units[unit]
    return None


def parse_range_or_time(text: str) -> tuple[str, float]:
    """A time (s, ms, us, ns, ps, fs) or a range (m, km, cm, mm) with its unit -> ("s", seconds) or ("m", metres).
    A bare number is refused (the unit decides how it converts, r = c t / 2): ValueError."""
    seconds = _split_quantity(text, TIME_UNITS, "a time or range")
    if seconds is not None:
        return "s", seconds
    metres = _split_quantity(text, RANGE_UNITS, "a time or range")
    if metres is not None:
        return "m", metres
    raise ValueError(f"expected a time or range with its unit (s, ms, us, ns, ps, fs; m, km, cm, mm), such as 12.5ns "
                     f"or 2.19m, got {text!r}")


def parse_time_unit(text: str) -> float:
    """The duration of one unit of time tags, such as 1ps or 8ps -> seconds (> 0); ValueError otherwise."""
    seconds = _split_quantity(text, TIME_UNITS, "a duration")
    if seconds is None or not seconds > 0:
        raise ValueError(f"expected a duration > 0 with its unit (s, ms, us, ns, ps, fs), such as 1ps, got {text!r}")
    return seconds


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"expected a finite number > 0, got {text!r}")
    return value


def parse_span(text: str) -> float | str:
    """Metres of range mapped onto the network's [0, 1] (a number > 0, with or without a range unit) -> metres, or
    'gate' (the gate's length); ValueError otherwise."""
    if text.strip() == "gate":
        return "gate"
    metres = _split_quantity(text, RANGE_UNITS, "a range")
    if metres is None:
        metres = _positive(text)
    if not (math.isfinite(metres) and metres > 0):
        raise ValueError(f"expected a range > 0 in metres or 'gate', got {text!r}")
    return metres


def range_metres(value, what: str) -> float | None:
    """A range in metres from a number (metres), a ("s", seconds) / ("m", metres) pair as `parse_range_or_time`
    gives, or a string with its unit (12.5ns, 2.19m); None stays None. Raises ValueError naming `what`."""
    if value is None:
        return None
    if isinstance(value, str):
        try:
            value = parse_range_or_time(value)
        except ValueError as e:
            raise ValueError(f"{what}: {e}") from None
    if isinstance(value, tuple):
        unit, number = value
        return float(number) * METRES_PER_SECOND if unit == "s" else float(number)
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"{what}: expected a finite range in metres, got {value!r}")
    return number
