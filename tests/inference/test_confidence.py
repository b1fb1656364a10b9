"""The confidence: P(return) and the depth's std per HR pixel (`jaxsr.inference.confidence`), their fit
(`jaxsr.training.confidence`), their scores (`jaxsr.eval.calibration`) and `jaxsr upscale`'s outputs of them."""

import jax
import numpy as np
import pytest

from jaxsr.app import AUTO_KEEP_RETURNS, ModelChoice, upscale
from jaxsr.config import ModelConfig, Sensor
from jaxsr.eval import auroc, expected_calibration_error, interval_coverage
from jaxsr.inference.confidence import (EVIDENCE_FRAMES, HEAD_FEATURES, PHOTON_FEATURES, STD_FEATURES,
                                        coefficients_for, confidence_frame, iter_count_windows,
                                        load_confidence, no_return_by_probability, no_return_logit_of)
from jaxsr.io.checkpoint import save_model
from jaxsr.sensor import centre_of_mass_std
from jaxsr.nn import Model, init_model
from jaxsr.sensor import quiet_pixels
from jaxsr.training.confidence import fit_depth_std, fit_logistic

SENSOR = Sensor()
TINY = dict(base=8, growth=4, head=16, filter_hidden=16)


def _window(rate, shape=(EVIDENCE_FRAMES, 6, 8, 16), seed=0):
    return np.asarray(jax.random.poisson(jax.random.key(seed), rate, shape), np.float32)


def test_coefficients_load_for_bundled_and_generic_models():
    table = load_confidence()
    assert "command" in table and "confidence_fit.py" in table["command"]
    for name in ("tr4-ambient", "head", "photons"):
        assert name in table["models"]
    c = coefficients_for("tr4-ambient", True)
    assert c.features == HEAD_FEATURES and len(c.probability) == len(HEAD_FEATURES) and len(c.std) == len(STD_FEATURES)
    assert coefficients_for("some/checkpoint.npz", True) == coefficients_for("head", True)
    assert coefficients_for("tr4", False).features == PHOTON_FEATURES  # no entry of its own: the generic one
    assert coefficients_for("tr4-ambient", False).features == PHOTON_FEATURES  # the kind decides


@pytest.mark.parametrize("head", [True, False])
def test_confidence_frame_is_a_probability_and_a_positive_std_at_extremes(head):
    """Columns of LR pixels with no photons, a few, many and float32-sized counts (a return at huge counts)."""
    window = _window(0.3)
    window[:, :, 0:2] = 0.0
    window[:, :, 2:4] = _window(50.0)[:, :, 2:4]
    window[:, :, 4:6] = 1e30
    window[:, :, 4:5, 3] = 3e30
    depth = np.full((24, 32), 0.4, np.float32)
    coeffs = coefficients_for("tr4-ambient" if head else "tr4", head)
    logit = np.linspace(-1e9, 1e9, depth.size, dtype=np.float32).reshape(depth.shape) if head else None
    p, std = confidence_frame(window, depth, coeffs, SENSOR, head_logit=logit)
    assert p.shape == std.shape == (24, 32) and p.dtype == std.dtype == np.float32
    assert np.all(np.isfinite(p)) and p.min() >= 0.0 and p.max() <= 1.0
    assert np.all(np.isfinite(std)) and std.min() > 0


def test_confidence_frame_refuses_nan_negative_counts_and_mismatched_inputs():
    window = _window(0.5)
    depth = np.full((24, 32), 0.4, np.float32)
    coeffs = coefficients_for("tr4-ambient", True)
    for bad in (np.nan, -1.0, np.inf):
        w = window.copy()
        w[4, 0, 0, 0] = bad
        with pytest.raises(ValueError, match="finite and >= 0"):
            confidence_frame(w, depth, coeffs, SENSOR, head_logit=depth)
    with pytest.raises(ValueError, match="head_logit"):
        confidence_frame(window, depth, coeffs, SENSOR)  # a head's coefficients need its logit
    with pytest.raises(ValueError, match="hr_depth"):
        confidence_frame(window, depth[:, :30], coeffs, SENSOR, head_logit=depth[:, :30])
    with pytest.raises(ValueError, match="window"):
        confidence_frame(window[..., :8], depth, coeffs, SENSOR, head_logit=depth)


def test_photons_of_a_return_raise_the_probability_where_the_head_says_no_return():
    """A dim, static return (2 photons a frame in one bin, little ambient light) that an unsure head calls no return:
    summed over the frames its photons stand out, and P(return) rises above one half, an ambient-only pixel's
    stays below."""
    coeffs = coefficients_for("tr4-ambient", True)
    ambient = _window(0.05, seed=3)
    dim = ambient.copy()
    dim[..., 7] += np.asarray(jax.random.poisson(jax.random.key(4), 2.0, dim.shape[:-1]), np.float32)
    depth = np.full((24, 32), 0.45, np.float32)
    logit = np.full((24, 32), 0.5, np.float32)  # the head, unsure: no return (P 0.62)
    p_sky, _ = confidence_frame(ambient, depth, coeffs, SENSOR, head_logit=logit)
    p_dim, _ = confidence_frame(dim, depth, coeffs, SENSOR, head_logit=logit)
    assert np.median(p_dim) > 0.5 > np.median(p_sky)


def test_centre_of_mass_std_falls_with_photons_and_is_the_gates_for_no_photons():
    peak = np.zeros(16, np.float32)
    peak[6:9] = (1.0, 4.0, 1.0)
    counts = np.stack([np.zeros(16, np.float32)] + [peak * s + 0.1 for s in (1.0, 10.0, 100.0)])  # one compilation
    flat, *stds = np.asarray(centre_of_mass_std(counts, SENSOR))
    np.testing.assert_allclose(flat, 16 / np.sqrt(12.0), rtol=1e-5)
    assert stds[0] > stds[1] > stds[2] > 0


def test_count_windows_are_centred_with_zeros_beyond_the_sequence():
    frames = [np.full((4, 4, 16), t + 1.0, np.float32) for t in range(5)]
    windows = list(iter_count_windows(iter(frames), 3))
    assert len(windows) == 5 and windows[0].shape == (3, 4, 4, 16)
    assert [float(w[:, 0, 0, 0].sum()) for w in windows] == [3.0, 6.0, 9.0, 12.0, 9.0]
    assert float(windows[0][0].max()) == 0.0 and float(windows[-1][-1].max()) == 0.0
    with pytest.raises(ValueError, match="odd"):
        list(iter_count_windows(iter(frames), 4))


def test_the_threshold_acts_on_the_probability():
    depth = np.full((2, 3), 0.3, np.float32)
    p = np.array([[0.1, 0.4, 0.49], [0.51, 0.7, 1.0]], np.float32)
    out = no_return_by_probability(depth, p)
    np.testing.assert_array_equal(out >= 1.0, p < 0.5)
    # logit 1: no return only where (1 - p) / p > e, p < 0.269
    np.testing.assert_array_equal(no_return_by_probability(depth, p, 1.0) >= 1.0, p < 1 / (1 + np.e))
    assert np.isinf(no_return_logit_of(np.float32(0.0))) and no_return_logit_of(np.float32(0.5)) == 0.0


def test_calibration_scores():
    rng = np.random.default_rng(0)
    p = rng.uniform(size=200_000)
    y = rng.uniform(size=p.size) < p  # calibrated by construction
    assert expected_calibration_error(p, y) < 0.01
    assert expected_calibration_error(np.clip(p + 0.2, 0, 1), y) > 0.1
    assert auroc(y.astype(float), y) == 1.0 and auroc(np.zeros(p.size), y) == 0.5
    assert 0.70 < auroc(p, y) < 0.9
    e = rng.normal(size=p.size)
    assert abs(interval_coverage(e, np.zeros_like(e), np.ones_like(e)) - 0.9) < 0.01
    with pytest.raises(ValueError, match="in \\[0, 1\\]"):
        expected_calibration_error(p + 1.0, y)


def test_fits_recover_a_logistic_model_and_a_90_percent_scale():
    rng = np.random.default_rng(1)
    x = np.column_stack([np.ones(50_000), rng.normal(size=50_000), rng.normal(size=50_000)])
    beta = np.array([0.5, -2.0, 1.0])
    y = rng.uniform(size=len(x)) < 1 / (1 + np.exp(-(x @ beta)))
    np.testing.assert_allclose(fit_logistic(x, y, l2=0.0), beta, atol=0.08)
    sigma = np.exp(x @ np.array([-1.0, 0.5, 0.0]))
    e = np.abs(rng.normal(size=len(x)) * sigma)
    got = np.exp(x @ fit_depth_std(x, e))
    assert abs(np.mean(e <= 1.6448536 * got) - 0.9) < 0.005
    np.testing.assert_allclose(np.median(got / sigma), 1.0, atol=0.1)  # Gaussian errors: sigma itself


@pytest.fixture(scope="module")
def head_model_file(tmp_path_factory):
    cfg = ModelConfig(tr=0, inputs=("depth", "signal", "background"), no_return_head=True, **TINY)
    params, state = init_model(jax.random.key(0), cfg)
    params["no_return"]["conv2"]["b"] = params["no_return"]["conv2"]["b"] + 1.0
    return save_model(tmp_path_factory.mktemp("m") / "head.npz", Model(params, state, cfg))


@pytest.fixture(scope="module")
def counts():
    rates = np.full((3, 8, 12, 16), 0.3, np.float32)
    rates[:, :5, :, 6] += 3.0  # returns in the top rows, ambient light alone below
    return np.asarray(jax.random.poisson(jax.random.key(1), rates), np.float32)


def test_upscale_returns_and_writes_the_confidence(tmp_path, counts, head_model_file):
    res = upscale(counts, None, model=ModelChoice(head_model_file))
    assert res.confidence.shape == res.depth_std.shape == res.shape == (3, 32, 48)
    assert res.confidence.dtype == np.float32 and 0 <= res.confidence.min() and res.confidence.max() <= 1
    returns = np.isfinite(res.depth)
    assert np.all(np.isnan(res.depth_std[~returns])) and np.all(res.depth_std[returns] > 0)
    upscale(counts, tmp_path / "o.npz", model=ModelChoice(head_model_file))
    with np.load(tmp_path / "o.npz") as z:
        np.testing.assert_allclose(z["confidence"], res.confidence, atol=1e-6)
        np.testing.assert_allclose(z["depth_std"], res.depth_std, atol=1e-6)
    written = upscale(counts, tmp_path / "o.npy", model=ModelChoice(head_model_file))
    assert written.confidence is None  # written beside the output, not kept in memory
    np.testing.assert_allclose(np.load(tmp_path / "o.confidence.npy"), res.confidence, atol=1e-6)
    np.testing.assert_allclose(np.load(tmp_path / "o.depth_std.npy"), res.depth_std, atol=1e-6, equal_nan=True)
    assert [str(tmp_path / f"o.{n}.npy") for n in ("confidence", "depth_std")] == written.summary()["confidence_files"]
    with pytest.raises(FileExistsError, match="confidence"):
        (tmp_path / "p.confidence.npy").write_bytes(b"")
        upscale(counts, tmp_path / "p.npy", model=ModelChoice(head_model_file))
    assert not (tmp_path / "p.npy").exists()  # refused before any work


def test_the_default_decides_no_return_on_the_confidence_at_the_threshold_given(counts, head_model_file):
    """By default (keep_returns "auto") a pixel is no return exactly where the logit of 1 - P(return) is above the
    no-return threshold (0: P(return) < 0.5, unless --no-return-logit moves it) and its LR pixel's own photons over
    9 frames, and those of the quiet pixels pooled around it (QUIET_POOLS), pass for ambient light alone (at
    AUTO_KEEP_RETURNS), and so do one of its neighbours'; the confidence itself does not depend on the threshold."""
    quiet = np.asarray(quiet_pixels(counts, SENSOR, alpha=AUTO_KEEP_RETURNS))
    hr_quiet = np.repeat(np.repeat(quiet, 4, axis=1), 4, axis=2)
    assert 0.2 < hr_quiet.mean() < 0.8
    res = upscale(counts, None, model=ModelChoice(head_model_file))
    np.testing.assert_array_equal(np.isinf(res.depth), (no_return_logit_of(res.confidence) > 0.0) & hr_quiet)
    threshold = float(np.median(no_return_logit_of(res.confidence)[hr_quiet]))
    moved = upscale(counts, None, model=ModelChoice(head_model_file, no_return_logit=threshold))
    np.testing.assert_allclose(moved.confidence, res.confidence, atol=1e-6)
    no_return = (no_return_logit_of(moved.confidence) > threshold) & hr_quiet
    assert 0.2 < no_return[hr_quiet].mean() < 0.8  # both decisions met where the photons leave it to the confidence
    np.testing.assert_array_equal(np.isinf(moved.depth), no_return)


def test_upscale_of_depth_frames_has_no_confidence():
    depth = np.full((2, 8, 12), 0.4, np.float32)
    res = upscale(depth, None, model="tr0")
    assert res.confidence is None and res.depth_std is None
