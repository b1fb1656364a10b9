"""experiments/studies/ambient_rule.py: the rule's scores and the threshold it picks, on constructed rows."""

import ambient_rule as study  # experiments/studies (pytest's pythonpath)
import numpy as np
import pytest


def _rows(pairs):
    return [{"estimate": e, "change": c} for e, c in pairs]


def test_rule_scores_count_what_each_threshold_tests():
    rows = _rows([(0.1, -2.0), (0.6, -0.5), (1.2, -0.1), (4.0, 0.4), (float("nan"), -9.0)])
    scores = {s["threshold"]: s for s in study.rule_scores(rows, thresholds=(0.0, 0.5, 1.0, float("inf")))}
    assert scores[0.0]["tested"] == 4  # NaN (no return seen) is never tested
    assert scores[0.0]["mean"] == pytest.approx((-2.0 - 0.5 - 0.1 + 0.4) / 5)
    assert scores[0.0]["worst"] == -2.0 and scores[0.0]["losing"] == 2
    assert scores[1.0]["tested"] == 2 and scores[1.0]["mean"] == pytest.approx(0.3 / 5)
    assert scores[1.0]["losing"] == 0 and scores[1.0]["worst"] == pytest.approx(-0.1)
    assert scores[float("inf")]["tested"] == 0 and scores[float("inf")]["mean"] == 0.0


def test_the_chosen_threshold_is_the_lowest_that_costs_nothing_on_average():
    rows = _rows([(0.1, -2.0), (0.6, -0.5), (1.2, -0.1), (4.0, 0.4)])
    thresholds = (0.0, 0.5, 1.0, float("inf"))
    assert study.chosen_threshold(study.rule_scores(rows, thresholds)) == 1.0
    losing = _rows([(0.1, -1.0), (2.0, -0.2)])
    assert study.chosen_threshold(study.rule_scores(losing, thresholds)) == float("inf")  # never test


def test_rows_pair_each_scene_with_its_estimate():
    psnr = {"TR4": np.array([[30.0, 31.0], [20.0, 22.0]]), "TR4+ambient": np.array([[30.0, 31.0], [21.0, 23.0]])}
    results = {"regimes": [{"photons": 3.0, "snr": 1.3, "scores": {m: {"psnr": v} for m, v in psnr.items()}}],
               "scenes": ["a", "b"], "spacing": 100.0}
    rows = study.rows_of(results, [[1.2, 0.4]])
    assert [(r["scene"], r["estimate"]) for r in rows] == [("a", 1.2), ("b", 0.4)]
    assert rows[0]["change"] == pytest.approx(0.0) and rows[1]["change"] == pytest.approx(1.0)
    lo, hi = rows[1]["interval"]
    assert lo <= 1.0 <= hi


def test_json_has_no_non_finite_numbers():
    assert study._finite({"a": [1.0, float("inf")], "b": (float("nan"), 2)}) == {"a": [1.0, None], "b": [None, 2]}
