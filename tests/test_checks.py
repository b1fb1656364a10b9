"""`jaxsr.checks`: sizes as people read them in memory refusals, and the one check of "one finite number > 0"
that options such as a time unit or a span share."""

import re

import numpy as np
import pytest

from jaxsr.checks import format_bytes, one_positive_number, require_memory


@pytest.mark.parametrize("n,text", [(7.24e9, "7.2 GB"), (3.5e8, "350 MB"), (131_072, "131 kB"), (512, "512 B"),
                                    (0, "0 B")])
def test_sizes_are_written_in_the_unit_that_fits(n, text):
    """Sizes below 1 MB were all "1 MB"."""
    assert format_bytes(n) == text


@pytest.mark.parametrize("need,budget,said", [
    (131_072, 100_000, "needs about 131 kB of memory, more than the 100 kB allowed"),
    (1_050_000, 1_000_000, "needs about 1.1 MB of memory, more than the 1.0 MB allowed"),
    (1.22e9, 1.2e9, "needs about 1.22 GB of memory, more than the 1.20 GB allowed"),
    (2.5e9, 1.2e9, "needs about 2.5 GB of memory, more than the 1.2 GB allowed"),
])
def test_a_memory_refusal_writes_the_need_and_the_budget_differently(need, budget, said):
    """`--max-memory 100kB` said "needs about 1 MB of memory, more than the 1 MB allowed"."""
    with pytest.raises(ValueError, match=re.escape(f"work {said} by --max-memory")):
        require_memory(need, "work", budget)


@pytest.mark.parametrize("value", [2, 1e-12, np.float32(0.5), np.array(3.0), np.array([4])])
def test_one_positive_number_is_taken_as_a_float(value):
    assert one_positive_number(value, "x", "one number > 0") == float(np.asarray(value).item())


@pytest.mark.parametrize("value,got", [(0, "0"), (-1.5, "-1.5"), (np.float64(np.nan), "nan"), (np.inf, "inf"),
                                       (np.array([1.0, 2.0]), "an array of shape (2,)"), ("1ps", "'1ps'"),
                                       (None, "None"), (True, "True")])
def test_anything_but_one_positive_number_is_refused_in_the_callers_words(value, got):
    with pytest.raises(ValueError, match=re.escape(f"span: expected one value > 0 in metres, got {got}")):
        one_positive_number(value, "span", "one value > 0 in metres")


def test_the_time_unit_and_the_upscale_options_share_the_check():
    """`jaxsr.app.specs._positive` (time_unit, span of `Reading`) and `timetags._time_unit` each had their own copy."""
    from jaxsr.app.specs import _positive
    from jaxsr.sensor.quantities import parse_time_unit
    from jaxsr.sensor.timetags import _time_unit

    assert _positive("1ps", "time_unit", parse_time_unit, "seconds") == pytest.approx(1e-12)
    with pytest.raises(ValueError, match=r"^time_unit: expected one value > 0 in seconds, got -1.0$"):
        _positive(np.float64(-1.0), "time_unit", parse_time_unit, "seconds")
    with pytest.raises(ValueError, match=r"^t.npz: expected one number of seconds per time unit, > 0 .* got -1.0$"):
        _time_unit(np.float64(-1.0), "t.npz")
