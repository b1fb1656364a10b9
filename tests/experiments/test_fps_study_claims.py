"""The frame-rate study's verdicts on the paper's "TR0 is best at 1-2.5 FPS" (experiments/paper/fps_study.py), against
the frame intervals and against other runs (differences over pairs of runs), on synthetic data with a known answer."""

import numpy as np
import pytest

import fps_study  # experiments/paper (pytest's pythonpath)
from _seeds import pairs_differences

from jaxsr.eval.stats import Interval


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


def test_differences_over_pairs_of_runs_and_the_verdict_on_them():
    """Per-frame PSNR with known means: TR0 runs at 30.0 (main) and 30.4 (another seed), TR1 at 30.2, TR4 at
    30.6: TR1 - TR0 lies between the runs (-0.2 .. +0.2), TR4 is above both (+0.2 .. +0.6)."""
    frames = np.linspace(-0.05, 0.05, 20)
    main = {0: 30.0 + frames, 1: 30.2 + frames, 4: 30.6 + frames}
    d = pairs_differences(main, {"s1": 30.4 + frames}, {"s1": 0})
    assert d[1]["runs"] == pytest.approx((-0.2, 0.2)) and d[1]["mean"] == pytest.approx(0.0)
    assert d[4]["runs"] == pytest.approx((0.2, 0.6))
    assert d[4]["beyond"] is None  # TR4 has one run: its own retraining is not measured
    assert fps_study.tr0_best_over_pairs(d) == "TR4 above every TR0 run -> does not hold"
    assert fps_study.tr0_best_over_pairs({1: d[1]}) == \
        "no TR above every TR0 run, not every TR below -> depends on the runs"
    assert fps_study.tr0_best_over_pairs({}) == "no TR0 run and another TR to compare"
    below = pairs_differences({0: 30.0 + frames, 1: 29.5 + frames}, {"s1": 29.9 + frames}, {"s1": 0})
    assert fps_study.tr0_best_over_pairs(below) == "every other TR below every TR0 run -> holds"
