"""The result-file header of the experiment scripts (experiments/harness/reports.py): CPU steal accounting."""

import pytest

from harness import reports


def test_steal_share_is_stolen_over_total_ticks_between_readings():
    assert reports.steal_share((10, 1_000), (60, 2_000)) == pytest.approx(0.05)
    assert reports.steal_share((10, 1_000), (10, 1_000)) is None  # no time passed
    assert reports.steal_share(None, (10, 1_000)) is None


@pytest.mark.skipif(reports.cpu_times() is None, reason="no /proc/stat on this system")
def test_cpu_times_and_header_report_the_steal_of_this_machine():
    steal, total = reports.cpu_times()
    assert 0 <= steal <= total
    text = reports.header("t", started=0.0)
    assert "- CPU steal during the run: " in text and text.endswith("\n\n")
