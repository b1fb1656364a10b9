"""The frame-rate study's verdict on the paper's "TR0 is best at 1-2.5 FPS" (experiments/fps_study.py), on
synthetic intervals with a known answer."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))

import fps_study  # noqa: E402
from jaxsr.stats import Interval  # noqa: E402


def _iv(mean, low, high):
    return Interval(mean, low, high)


def test_tr0_best_verdict_says_at_which_rates_it_holds_beyond_the_intervals():
    below = _iv(-0.3, -0.4, -0.2)  # another TR below TR0 with its whole interval
    touching = _iv(-0.04, -0.09, 0.01)  # below on the mean, interval reaching over zero
    tr0_best = {1.0: 0, 2.5: 0}
    assert fps_study.tr0_best_verdict(tr0_best, {1.0: {1: below, 4: below}, 2.5: {1: below, 4: below}}) \
        == "holds beyond the frame intervals"
    assert fps_study.tr0_best_verdict(tr0_best, {1.0: {1: touching, 4: below}, 2.5: {1: below, 4: below}}) \
        == "holds beyond the frame intervals at 2.5 FPS, on the means only at 1 FPS"
    assert fps_study.tr0_best_verdict(tr0_best, {1.0: {1: touching}, 2.5: {1: touching}}) \
        == "holds on the means only, inside the intervals"
    assert fps_study.tr0_best_verdict({1.0: 0, 2.5: 1}, {}) == "does not hold"
    # TR0 alone (no other TR to compare) is not "beyond the intervals"
    assert fps_study.tr0_best_verdict(tr0_best, {}) == "holds on the means only, inside the intervals"
