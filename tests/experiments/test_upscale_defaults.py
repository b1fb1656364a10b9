"""experiments/studies/upscale_defaults.py: the rules it scores and the choices it makes, on constructed rows."""

import numpy as np
import pytest
import upscale_defaults as study  # experiments/studies (pytest's pythonpath)

TR4, TEST, PHOTON, PHOTON_TEST = study.TR4, study.TR4_TEST, study.PHOTON, study.PHOTON_TEST


def _row(snr_est, photons_est, tr4, tested, photon=None, photon_tested=None):
    psnr = {TR4: tr4, TEST: tested, PHOTON: tr4 if photon is None else photon,
            PHOTON_TEST: tr4 if photon_tested is None else photon_tested}
    return {"snr_est": snr_est, "photons_est": photons_est, "psnr": psnr}


def test_the_ambient_rule_tests_from_its_threshold_up_and_never_at_nan():
    rows = [_row(0.1, 5, 20.0, 18.0), _row(0.6, 5, 20.0, 19.5), _row(1.2, 5, 20.0, 19.9), _row(4.0, 5, 20.0, 20.4),
            _row(float("nan"), 5, 20.0, 11.0)]
    scores = {s["threshold"]: s for s in study.ambient_rules(rows, thresholds=(0.0, 0.5, 1.0, float("inf")))}
    assert scores[0.0]["picked"] == {TR4: 1, TEST: 4}  # NaN (no return seen) is never tested
    assert scores[0.0]["mean"] == pytest.approx((-2.0 - 0.5 - 0.1 + 0.4) / 5)
    assert scores[0.0]["worst"] == pytest.approx(-2.0) and scores[0.0]["losing"] == 2
    assert scores[1.0]["mean"] == pytest.approx(0.3 / 5) and scores[1.0]["losing"] == 0
    assert scores[float("inf")]["mean"] == 0.0 and scores[float("inf")]["picked"] == {TR4: 5}
    assert study.chosen_snr_threshold(list(scores.values())) == 1.0
    losing = [_row(0.1, 5, 20.0, 19.0), _row(2.0, 5, 20.0, 19.8)]
    assert study.chosen_snr_threshold(study.ambient_rules(losing, (0.0, 1.0, float("inf")))) == float("inf")


def test_the_model_rule_picks_the_photon_model_below_its_threshold():
    rows = [_row(1.3, 1.0, 9.0, 9.0, photon=20.0, photon_tested=17.0),   # 1 photon: the photon model, untested
            _row(1.3, 3.0, 25.0, 25.0, photon=26.0, photon_tested=26.5),
            _row(1.3, 14.0, 30.0, 30.0, photon=29.5, photon_tested=29.5)]  # 14 photons: TR4
    pick = study.model_rule(4.0, test_photon_model=False)
    assert [pick(r) for r in rows] == [PHOTON, PHOTON, TEST]
    assert [study.model_rule(4.0, test_photon_model=True)(r) for r in rows] == [PHOTON_TEST, PHOTON_TEST, TEST]
    assert study.model_rule(4.0, test_photon_model=True)(_row(0.5, 1.0, 9.0, 9.0)) == PHOTON  # below the library's rule
    scores = study.model_rules(rows, thresholds=(0.0, 2.0, 4.0))
    assert len(scores) == 5  # "never" once, then untested and tested at each threshold
    best = study.chosen_model_rule(scores)
    assert (best["threshold"], best["test_photon_model"]) == (4.0, False)
    assert best["mean"] == pytest.approx((11.0 + 1.0) / 3)
    rows.append(_row(1.3, 3.5, 25.0, 25.0, photon=20.0))  # a row the photon model loses at 4, not at 2
    safe = study.chosen_model_rule(study.model_rules(rows, thresholds=(0.0, 2.0, 4.0)), safe=True)
    assert (safe["threshold"], safe["losing"]) == (2.0, 0)


def test_the_library_rule_is_the_combined_rule_at_its_constant_and_tests_many_photons_at_low_snr():
    """SNR >= 1, or signal photons x SNR >= c; NaN estimates (no return seen) never tested, no ambient (inf SNR)
    always; the library's `auto_ambient_alpha` picks what combined_rule(AUTO_AMBIENT_MIN_SIGNAL_SNR) picks."""
    nan, inf = float("nan"), float("inf")
    rows = [_row(0.1, 100.0, 20.0, 20.8), _row(0.1, 10.0, 20.0, 19.0), _row(1.3, 1.0, 20.0, 19.9),
            _row(nan, 100.0, 20.0, 11.0), _row(inf, nan, 20.0, 20.0), _row(0.5, 14.0, 20.0, 20.0)]
    c = study.AUTO_AMBIENT_MIN_SIGNAL_SNR
    assert c in study.SIGNAL_SNR_THRESHOLDS
    library, combined = study.library_rule(), study.combined_rule(c)
    assert [library(r) for r in rows] == [combined(r) for r in rows] == [TEST, TR4, TEST, TR4, TEST, TEST]
    assert [study.combined_rule(inf)(r) for r in rows] == [TR4, TR4, TEST, TR4, TEST, TR4]  # the SNR alone
    scores = {s["threshold"]: s for s in study.combined_rules(rows, thresholds=(0.5, c, inf))}
    assert scores[c]["mean"] == pytest.approx((0.8 - 0.1) / 6) and scores[c]["losing"] == 0
    assert scores[0.5]["losing"] == 1  # 10 photons at SNR 0.1 tested too: -1 dB
    snr_only = study.policy_score(rows, study.ambient_rule(1.0))
    assert study.chosen_signal_snr_threshold(list(scores.values()), snr_only) == c


def test_rows_pair_each_scene_with_its_estimates():
    scores = {m: {"psnr": np.array([[30.0, 32.0], [20.0, 22.0]]) + k} for k, m in enumerate(study.METHODS)}
    results = {"regimes": [{"photons": 3.0, "snr": 1.3, "scores": scores}], "scenes": ["a", "b"]}
    rows = study.rows_of(results, [[(1.2, 3.5), (0.4, 2.0)]])
    assert [(r["scene"], r["snr_est"], r["photons_est"]) for r in rows] == [("a", 1.2, 3.5), ("b", 0.4, 2.0)]
    assert rows[1]["psnr"] == {m: 21.0 + k for k, m in enumerate(study.METHODS)}


def test_json_has_no_non_finite_numbers():
    assert study._finite({"a": [1.0, float("inf")], "b": (float("nan"), 2)}) == {"a": [1.0, None], "b": [None, 2]}


def test_the_report_and_its_json_are_made_from_rows():
    """What `main` writes, from constructed rows (the run itself takes minutes): every section, and JSON that a
    strict parser reads back."""
    import json
    import time

    rows = [{**_row(e, p, 20.0, 20.1, photon=25.0, photon_tested=24.0), "photons": p, "snr": e, "scene": scene}
            for e, p, scene in ((0.3, 1.0, "scene1_street"), (1.3, 3.0, "scene2_road"), (4.0, 14.0, "scene3_courtyard"))]
    tests, models = study.ambient_rules(rows), study.model_rules(rows)
    text = study.report(rows, tests, models, started=time.time(), frames=2, seed=0)
    for part in ("## The ambient-only test, by SNR threshold", "## The model, by photon threshold",
                 "## Per scene and regime", "tr4-photons alone: mean",
                 "## The library's rule: the SNR, or the signal photons times the SNR", "The library (`AUTO_AMBIENT_"):
        assert part in text
    raw = json.loads(json.dumps(study.raw_results(rows, tests, models, frames=2, seed=0), allow_nan=False))
    assert raw["photon_model_tested"]["mean"] == pytest.approx(-2.0 / 3)  # tested in 2 of 3 rows, -1 dB each
    assert raw["chosen_snr"] == 0.0 and raw["frames"] == 2
    assert len(raw["combined_rules"]) == len(study.SIGNAL_SNR_THRESHOLDS)
    assert raw["library_rule"]["picked"] == {TR4: 1, TEST: 2}  # SNR 0.3 x 1 photon: untested
