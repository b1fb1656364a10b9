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


# --- the command's conventions, the same in every subcommand (docs/cli.md, "Conventions"): the input positional,
# the output -o/--output, the model -m/--model, -f/--force, -q/--quiet; old spellings kept for one release --------

class OldSpelling(argparse.Action):
    """A flag's old spelling: it stores what the new one stores and notes a warning, which `jaxsr.cli.main` prints
    once the command starts (`jaxsr CMD: warning: ...`)."""

    def __init__(self, option_strings, dest, new: str, **kwargs):
        self.new = new
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, values)
        note_old_spelling(namespace, option_string, self.new)


def note_old_spelling(namespace, old: str, new: str) -> None:
    """Note on the parsed arguments that `old` was given for `new` (printed as a warning by `jaxsr.cli.main`)."""
    notes = list(getattr(namespace, "old_spellings", ()))
    notes.append(f"{old} is the old spelling of {new} and goes in the next release")
    namespace.old_spellings = notes


def add_output(p, what: str, *, old_out: bool = True) -> None:
    """-o/--output (the output: `what`), and the old --out."""
    p.add_argument("-o", "--output", default=None, metavar="PATH", help=f"{what} (required)")
    if old_out:
        p.add_argument("--out", dest="output", action=OldSpelling, new="-o/--output", help=argparse.SUPPRESS)


def add_force(p, what: str, group=None) -> None:
    """-f/--force."""
    (group or p).add_argument("-f", "--force", action="store_true", help=what)


def add_quiet(p) -> None:
    """-q/--quiet, and --no-progress (the same: no progress bar)."""
    p.add_argument("-q", "--quiet", "--no-progress", dest="no_progress", action="store_true",
                   help="no progress bar")


def required_output(args) -> str:
    """The output the arguments give; ValueError (one line, exit 2) when none is."""
    if args.output is None:
        raise ValueError("the output is required: -o/--output PATH")
    return args.output
