"""`jaxsr upscale` with a model that reads the photons behind each depth: histograms feed it its channels
(over any gate, as the library's `super_resolve_histograms` does for the default gate), depth is refused with
a message that says what it needs, and "default" picks the bundled model that fits the input."""

import dataclasses

import jax
import numpy as np
import pytest

from jaxsr.config import ModelConfig, Optics, Sensor
from jaxsr.app import (
    AUTO_AMBIENT_ALPHA,
    AUTO_AMBIENT_MIN_FRAMES,
    AUTO_AMBIENT_MIN_SIGNAL_SNR,
    AUTO_AMBIENT_MIN_SNR,
    AUTO_KEEP_RETURNS,
    DEFAULT_MODELS,
    DEPTH_ENSEMBLE,
    FEW_PHOTONS,
    ModelChoice,
    PhotonRules,
    Reading,
    auto_ambient_alpha,
    photon_levels,
    prepare_upscale,
    upscale,
    upscale_memory,
)
from jaxsr.app.job import ensemble_depth
from jaxsr.app.models import finish_model, plan_model
from jaxsr.inference import fill_holes, super_resolve_histograms
from jaxsr.io.checkpoint import load_model, save_model
from jaxsr.nn import Model, init_model, with_no_return_logit
from jaxsr.sensor import HOLE_PIXELS

SENSOR = Sensor()
TINY = dict(base=8, growth=4, head=16, filter_hidden=16)


def _photon_model(folder, seed: int, head_bias: float):
    """A tiny photon model with a no-return head whose logits are raised by `head_bias`, and its file."""
    cfg = ModelConfig(tr=0, inputs=("depth", "signal", "background"), no_return_head=True, **TINY)
    params, state = init_model(jax.random.key(seed), cfg)
    params["no_return"]["conv2"]["b"] = params["no_return"]["conv2"]["b"] + head_bias
    model = Model(params, state, cfg)
    return model, save_model(folder / "photons.npz", model)


@pytest.fixture(scope="module")
def photon_model(tmp_path_factory):
    # a head that marks some pixels, so that the no-return output is exercised
    return _photon_model(tmp_path_factory.mktemp("m"), 0, 4.0)


@pytest.fixture(scope="module")
def counts():
    return np.asarray(jax.random.poisson(jax.random.key(1), 0.8, (2, 8, 12, 16)), np.float32)


@pytest.fixture(scope="module")
def depth_model(tmp_path_factory):
    """A tiny depth-only model's file (the default "auto" ambient test applies to such models)."""
    cfg = ModelConfig(tr=0, **TINY)
    return save_model(tmp_path_factory.mktemp("d") / "depth.npz", Model(*init_model(jax.random.key(5), cfg), cfg))


def test_histograms_through_a_photon_model_equal_the_library(photon_model, counts):
    """A model with a no-return head marks no return itself: "auto" leaves the ambient test off for it, and with the
    head alone deciding (keep_returns off) the output is the library's."""
    model, path = photon_model
    result = upscale(counts, None, model=path, read=Reading(units="normalised"), photons=PhotonRules(keep_returns=None))
    np.testing.assert_allclose(result.depth, np.clip(super_resolve_histograms(model, counts), 0, 1), atol=1e-6)
    assert result.ambient_alpha is None and result.summary()["ambient_alpha"] is None
    assert prepare_upscale(counts, model=path).ambient_alpha is None  # by default too


def test_depth_to_a_photon_model_is_refused(photon_model):
    depth = np.full((2, 8, 12), 0.5, np.float32)
    with pytest.raises(ValueError, match="histograms or time tags"):
        prepare_upscale(depth, model=photon_model[1])


def test_default_fits_the_input(counts):
    """Histograms get the default photon model, its no return decided by the confidence (keep_returns "auto": the
    head's logit and each pixel's photons; off: the head alone); depth the depth model."""
    job = prepare_upscale(counts)
    assert job.model_name.startswith(DEFAULT_MODELS["histograms"]) and "P(return) < 0.5" in job.model_name
    assert "kept only where" in job.model_name and job.photons.by_probability
    assert job.keep_returns == AUTO_KEEP_RETURNS and job.ambient_alpha is None  # auto: no ambient test for a head
    off = prepare_upscale(counts, photons=PhotonRules(keep_returns=None))
    assert "P(return)" not in off.model_name and "kept" not in off.model_name and not off.photons.by_probability
    assert prepare_upscale(np.full((2, 8, 12), 0.5, np.float32)).model_name == DEFAULT_MODELS["depth"]
    with pytest.raises(TypeError, match="default"):
        prepare_upscale(counts, model=3)


def test_no_return_logit_moves_the_decision_and_is_refused_without_a_head(photon_model, counts):
    """--no-return-logit: a threshold above every logit marks nothing, below every logit everything; the
    library's `with_no_return_logit` gives the same output; a depth-only model refuses it before reading."""
    model, path = photon_model
    never = upscale(counts, None, model=ModelChoice(path, no_return_logit=1e6), read=Reading(units="normalised")).depth
    always = upscale(counts, None, model=ModelChoice(path, no_return_logit=-1e6), read=Reading(units="normalised"), photons=PhotonRules(keep_returns=None)).depth
    assert not (never >= 1.0).any() and (always >= 1.0).all()
    want = super_resolve_histograms(with_no_return_logit(model, 1e6), counts)
    np.testing.assert_allclose(never, np.clip(want, 0, 1), atol=1e-6)
    with pytest.raises(ValueError, match="no-return head"):
        prepare_upscale(counts, model=ModelChoice("tr0", no_return_logit=1.0))
    with pytest.raises(ValueError, match="no-return head"):  # auto picks depth-only models: refused before reading
        prepare_upscale("/nonexistent/input.npy", model=ModelChoice("auto", no_return_logit=1.0))
    assert prepare_upscale(counts, model=ModelChoice("default", no_return_logit=1.0)).model.config.no_return_logit == 1.0  # the default's head
    job = prepare_upscale(counts, model=ModelChoice(path, no_return_logit=2.0), photons=PhotonRules(ambient_alpha=None, keep_returns=None))
    assert job.model.config.no_return_logit == 2.0 and job.model_name.endswith("at no-return logit 2")
    with pytest.raises(ValueError, match="finite number"):
        with_no_return_logit(model, float("nan"))


def test_cli_no_return_logit(photon_model, counts, tmp_path, capsys):
    from jaxsr.cli import main
    src = tmp_path / "counts.npy"
    np.save(src, counts)
    out = tmp_path / "out.npy"
    assert main(["upscale", str(src), "-o", str(out), "--model", str(photon_model[1]), "--no-return-logit", "1e6",
                 "--units", "normalised", "--no-progress"]) == 0
    assert not (np.load(out) >= 1.0).any()
    with pytest.raises(SystemExit) as e:
        main(["upscale", str(src), "-o", str(tmp_path / "b.npy"), "--no-return-logit", "inf"])
    assert e.value.code == 2 and "finite number" in capsys.readouterr().err


def test_a_recording_beyond_the_trained_snr_is_said(photon_model):
    """A photon model on histograms without ambient light (frame SNR beyond the 0.05-20 it was trained on) gets a
    warning that names the SNR and --no-return-logit; the same scene with ambient light at SNR 2 gets none; a
    depth-only model gets none (it has no threshold to set)."""
    import jax.numpy as jnp

    from jaxsr.sensor import calibrated_rates, calibrate, sample_poisson

    depth = np.full((4, 32, 48), 12.0, np.float32)
    depth[:, :, 24:] = 20.0
    intensity = np.full_like(depth, 0.5)
    sensor = Sensor(optics=Optics.of_hr((32, 48)))

    def counts(snr):
        alpha, beta = calibrate(jnp.asarray(depth), jnp.asarray(intensity), sensor, snr=snr, mean_signal=20.0)
        return np.asarray(sample_poisson(jax.random.key(0), calibrated_rates(depth, intensity, alpha, beta, sensor)))

    model, path = photon_model
    dark = prepare_upscale(counts(1e4), model=path)
    (warning,) = [w for w in dark.warnings if "frame SNR" in w]
    assert "0.05-20" in warning and "--no-return-logit" in warning
    assert not [w for w in prepare_upscale(counts(2.0), model=path).warnings if "frame SNR" in w]
    assert not [w for w in prepare_upscale(counts(1e4), model="tr0").warnings if "frame SNR" in w]
    set_logit = prepare_upscale(counts(1e4), model=ModelChoice(path, no_return_logit=3.0)).warnings
    assert [w for w in set_logit if "frame SNR" in w and "set to 3" in w and "such as 2" not in w]
    assert not [w for w in prepare_upscale(counts(1e4), model=path, read=Reading(clip_negative=True)).warnings if "frame SNR" in w]
    # a card whose regime is not what it should be: the bundled range, no failure
    for i, card in enumerate(({"regime": "wide"}, {"regime": {"snr_range": ["a", "b"]}},
                              {"regime": {"snr_range": [20.0, 0.05]}})):
        odd = save_model(path.parent / f"odd{i}.npz", model, card=card)
        assert [w for w in prepare_upscale(counts(1e4), model=odd).warnings if "0.05-20" in w], card
    # a card's own range is the one compared: SNR 2 is well below 10-20
    own = save_model(path.parent / "own.npz", model, card={"regime": {"snr_range": [10.0, 20.0]}})
    assert [w for w in prepare_upscale(counts(2.0), model=own).warnings if "10-20" in w and "this much ambient" in w]


def test_frame_snr_reads_the_calibrated_snr():
    """frame_snr on simulated histograms of a static scene comes within 25 % of the SNR they were calibrated to
    from 1.3 to 20 and within 2x at 0.1 (where ambient noise lifts the peak's window: it reads high), and refuses
    what is not (T, h, w, K) histograms."""
    import jax.numpy as jnp

    from jaxsr.sensor import frame_snr, simulate_histograms

    depth = np.broadcast_to(np.linspace(8.0, 30.0, 48, dtype=np.float32)[None, None], (6, 32, 48)).copy()
    intensity = np.full_like(depth, 0.6)
    sensor = Sensor(optics=Optics.of_hr((32, 48)))
    for snr, within in ((0.1, 1.0), (1.3, 0.25), (5.0, 0.25), (20.0, 0.25)):
        c = simulate_histograms(jax.random.key(1), jnp.asarray(depth), jnp.asarray(intensity), sensor, snr=snr,
                                mean_signal=14.0)
        assert abs(frame_snr(np.asarray(c), sensor) / snr - 1) < within
    with pytest.raises(ValueError, match="histograms"):
        frame_snr(np.zeros((4, 8, 8)))


def test_signal_photons_reads_the_calibrated_signal():
    """signal_photons on simulated histograms of a static scene (6 frames) comes within 30 % of the signal photons
    per pixel they were calibrated to from 14 photons up at SNR 0.3-5, and reads high, not low, at 1-3 photons
    (the returns too faint to be found are left out, and noise lifts the peak's window); NaN without a return."""
    import jax.numpy as jnp

    from jaxsr.sensor import frame_levels, frame_snr, signal_photons, simulate_histograms

    depth = np.broadcast_to(np.linspace(8.0, 30.0, 48, dtype=np.float32)[None, None], (6, 32, 48)).copy()
    intensity = np.full_like(depth, 0.6)
    sensor = Sensor(optics=Optics.of_hr((32, 48)))
    for snr in (0.3, 5.0):
        for photons in (1.0, 3.0, 14.0, 100.0):
            c = simulate_histograms(jax.random.key(1), jnp.asarray(depth), jnp.asarray(intensity), sensor, snr=snr,
                                    mean_signal=photons)
            read = signal_photons(np.asarray(c), sensor)
            assert frame_levels(np.asarray(c), sensor) == (frame_snr(np.asarray(c), sensor), read)  # one scan, both
            assert (abs(read / photons - 1) < 0.3) if photons >= 14 else (photons <= read < 4 * photons), (snr, photons)
    assert np.isnan(signal_photons(np.zeros((2, 8, 8, 16), np.float32)))
    with pytest.raises(ValueError, match="histograms"):
        signal_photons(np.zeros((4, 8, 8)))


@pytest.fixture(scope="module")
def half_sky():
    """17 frames (enough for "auto" to read the SNR) of a surface (left half, 4 signal photons per pixel) beside
    sky (right half), both with 2 ambient photons per pixel; LR 8 x 12."""
    rng = np.random.default_rng(2)
    counts = rng.poisson(2.0 / 16, (17, 8, 12, 16)).astype(np.float32)
    counts[:, :, :6, 7] += rng.poisson(4.0, (17, 8, 6))
    return counts


def test_ambient_alpha_empties_the_sky_and_keeps_the_surface(photon_model, half_sky):
    """The library and `jaxsr upscale` agree; inside the sky every HR pixel is no return, on the surface the
    output is the model's own; the flags are `ambient_only`'s."""
    from jaxsr.sensor import ambient_only

    model, path = photon_model
    plain = super_resolve_histograms(model, half_sky)
    tested = super_resolve_histograms(model, half_sky, ambient_alpha=1e-3)
    flags = np.asarray(ambient_only(half_sky, alpha=1e-3))
    assert not flags[:, :, :6].any() and flags[:, :, 7:].all()  # column 6 sees the surface beside it
    hr_flags = np.repeat(np.repeat(flags, 4, axis=1), 4, axis=2)
    assert (tested[hr_flags] == 1.0).all()
    np.testing.assert_array_equal(tested[~hr_flags], plain[~hr_flags])
    job = prepare_upscale(half_sky, model=path, photons=PhotonRules(ambient_alpha=1e-3))
    assert "alpha 0.001" in job.model_name
    result = upscale(half_sky, None, model=path, read=Reading(units="normalised"), photons=PhotonRules(ambient_alpha=1e-3))
    np.testing.assert_allclose(result.depth, np.clip(tested, 0, 1), atol=1e-6)
    metres = upscale(half_sky, None, model="tr0", photons=PhotonRules(ambient_alpha=1e-3)).depth
    assert np.isinf(metres[hr_flags]).all()  # no return is inf in metres, with a depth-only model too


def test_ambient_alpha_is_refused_for_depth_and_out_of_range(photon_model, half_sky, tmp_path, capsys):
    from jaxsr.cli import main

    with pytest.raises(ValueError, match="histograms or time tags"):
        prepare_upscale(np.full((2, 8, 12), 0.5, np.float32), model="tr0", photons=PhotonRules(ambient_alpha=1e-3))
    for bad in (0.0, 1.0, -1e-3, 1e-35, True, [1e-3]):
        with pytest.raises(ValueError, match=r"false-alarm rate in \[1e-30, 1\)"):
            prepare_upscale("/nonexistent/input.npy", photons=PhotonRules(ambient_alpha=bad))  # before the input is read
    with pytest.raises(ValueError, match=r"false-alarm rate in \[1e-30, 1\)"):
        super_resolve_histograms(photon_model[0], half_sky, ambient_alpha=2.0)
    src = tmp_path / "counts.npy"
    np.save(src, half_sky)
    out = tmp_path / "out.npy"
    assert main(["upscale", str(src), "-o", str(out), "--model", "tr0", "--ambient-alpha", "1e-3", "--units",
                 "normalised", "--no-progress"]) == 0
    assert (np.load(out)[:, :, 32:] == 1.0).all()
    assert main(["upscale", str(src), "-o", str(tmp_path / "b.npy"), "--ambient-alpha", "2"]) == 2
    assert "false-alarm rate" in capsys.readouterr().err


def test_auto_ambient_alpha_tests_from_the_threshold_snr_or_signal_times_snr_up():
    assert auto_ambient_alpha(float("nan")) is None  # no return seen: nothing to tell the sky from
    assert auto_ambient_alpha(float("nan"), 100.0) is None
    assert auto_ambient_alpha(0.0) is None and auto_ambient_alpha(AUTO_AMBIENT_MIN_SNR * 0.99) is None
    assert auto_ambient_alpha(AUTO_AMBIENT_MIN_SNR) == AUTO_AMBIENT_ALPHA
    assert auto_ambient_alpha(float("inf")) == AUTO_AMBIENT_ALPHA  # no ambient photon seen
    # below the SNR threshold, many signal photons still stand out: signal x SNR decides
    low = AUTO_AMBIENT_MIN_SNR / 10
    assert auto_ambient_alpha(low, 0.99 * AUTO_AMBIENT_MIN_SIGNAL_SNR / low) is None
    assert auto_ambient_alpha(low, AUTO_AMBIENT_MIN_SIGNAL_SNR / low) == AUTO_AMBIENT_ALPHA
    assert auto_ambient_alpha(AUTO_AMBIENT_MIN_SNR, 0.01) == AUTO_AMBIENT_ALPHA  # the SNR alone suffices


def test_ambient_alpha_auto_is_the_default_and_follows_the_recording(photon_model, depth_model, half_sky,
                                                                     tmp_path, capsys):
    """By default histograms at a frame SNR of about 2 get the test (said in the model's name, the rate in the job,
    the result and the summary, the output the explicit rate's and what the library's functions compose to), the
    same scene under 20x the ambient light (SNR about 0.1) does not, but does with 25x the photons as well (signal x
    SNR above AUTO_AMBIENT_MIN_SIGNAL_SNR), nor do fewer than AUTO_AMBIENT_MIN_FRAMES
    frames, a model with a no-return head, depth input, counts after --clip-negative and ambient_alpha=None; a
    string other than "auto" is refused naming the choices; the CLI takes auto, off or a rate, and refuses
    anything else with the choices."""
    from jaxsr.cli import main
    from jaxsr.io.checkpoint import load_model

    path = depth_model
    job = prepare_upscale(half_sky, model=path)
    assert f"alpha {AUTO_AMBIENT_ALPHA:g}; auto: frame SNR about" in job.model_name
    assert job.ambient_alpha == AUTO_AMBIENT_ALPHA and job.label == str(path)  # pictures: the model alone
    explicit = upscale(half_sky, None, model=path, read=Reading(units="normalised"), photons=PhotonRules(ambient_alpha=AUTO_AMBIENT_ALPHA)).depth
    result = upscale(half_sky, None, model=path, read=Reading(units="normalised"))
    np.testing.assert_array_equal(result.depth, explicit)
    assert result.summary()["ambient_alpha"] == AUTO_AMBIENT_ALPHA
    composed = super_resolve_histograms(load_model(path), half_sky,
                                        ambient_alpha=auto_ambient_alpha(*photon_levels(half_sky, 16)))
    np.testing.assert_allclose(result.depth, np.clip(composed, 0, 1), atol=1e-6)
    short = prepare_upscale(half_sky[:AUTO_AMBIENT_MIN_FRAMES - 1], model=path)
    assert f"{AUTO_AMBIENT_MIN_FRAMES - 1} frames, too few to read the SNR" in short.model_name
    assert short.ambient_alpha is None
    assert "the model marks no return itself" in prepare_upscale(half_sky, model=photon_model[1]).model_name
    for bad in ("off", "Auto", "0.001"):
        with pytest.raises(ValueError, match="'auto', None"):
            prepare_upscale(half_sky, model=path, photons=PhotonRules(ambient_alpha=bad))
    rng = np.random.default_rng(3)
    bright = half_sky + rng.poisson(40.0 / 16, half_sky.shape).astype(np.float32)
    dim = prepare_upscale(bright, model=path)
    assert "ambient test off: frame SNR about" in dim.model_name and dim._ambient_stream is None
    assert f"signal x SNR below {AUTO_AMBIENT_MIN_SIGNAL_SNR:g}" in dim.model_name
    # the same SNR with 25x the photons (100 signal per pixel against 1000 ambient): the returns stand out, tested
    many = rng.poisson(1000.0 / 16, half_sky.shape).astype(np.float32)
    many[:, :, :6, 7] += rng.poisson(100.0, many.shape[:2] + (6,))
    levels = photon_levels(many, 16)
    assert levels.snr < AUTO_AMBIENT_MIN_SNR and levels.snr * levels.signal >= AUTO_AMBIENT_MIN_SIGNAL_SNR
    bright_many = prepare_upscale(many, model=path)
    assert "; auto: frame SNR about" in bright_many.model_name and bright_many.ambient_alpha == AUTO_AMBIENT_ALPHA
    assert "ambient" not in prepare_upscale(half_sky, model=path, photons=PhotonRules(ambient_alpha=None)).model_name
    assert "ambient" not in prepare_upscale(np.full((2, 8, 12), 0.5, np.float32), model="tr0").model_name
    clipped = prepare_upscale(half_sky, model=path, read=Reading(clip_negative=True))
    assert "ambient test off: background-subtracted" in clipped.model_name
    src = tmp_path / "counts.npy"
    np.save(src, half_sky)
    for setting, tested in (("auto", True), ("off", False), ("1e-3", True)):
        out = tmp_path / f"{setting}.npy"
        assert main(["upscale", str(src), "-o", str(out), "--model", str(path), "--ambient-alpha", setting,
                     "--units", "normalised", "--no-progress"]) == 0
        assert np.array_equal(np.load(out), explicit) == tested, setting
    with pytest.raises(SystemExit) as e:
        main(["upscale", str(src), "-o", str(tmp_path / "b.npy"), "--ambient-alpha", "sometimes"])
    assert e.value.code == 2 and "auto, off or a false-alarm rate" in capsys.readouterr().err


def test_the_test_is_named_where_memory_is_short_and_said_on_clipped_counts(depth_model, half_sky):
    """A job refused for memory names --ambient-alpha off among the ways out when the test runs (its 9 frames);
    a rate given for background-subtracted counts is applied with a warning (the test assumes raw counts)."""
    # 501 MB passes the check from the recording's sizes (about 500 MB) and not the job's own estimate (502 MB)
    with pytest.raises(ValueError, match=r"--ambient-alpha off \(its test sums 9 frames\)"):
        upscale(half_sky, None, model=depth_model, max_memory="501MB")
    with pytest.raises(ValueError) as refused:
        upscale(half_sky, None, model=depth_model, photons=PhotonRules(ambient_alpha=None), max_memory="100MB")
    assert "--ambient-alpha" not in str(refused.value)
    job = prepare_upscale(half_sky, model=depth_model, read=Reading(clip_negative=True), photons=PhotonRules(ambient_alpha=1e-3))
    assert job.ambient_alpha == 1e-3 and [w for w in job.warnings if "background-subtracted counts" in w]
    assert not [w for w in prepare_upscale(half_sky, model=depth_model, read=Reading(clip_negative=True)).warnings
                if "--ambient-alpha" in w]


def test_few_photons_get_a_hint_towards_the_photon_model(photon_model, half_sky):
    """Below FEW_PHOTONS estimated signal photons per pixel, a model reading depth alone (a named TR, auto) gets a
    warning naming tr4-ambient; at 4 photons (half_sky), a photon model (the default among them), and counts
    clipped after background subtraction get none."""
    rng = np.random.default_rng(4)
    dim = rng.poisson(2.0 / 16, half_sky.shape).astype(np.float32)
    dim[:, :, :6, 7] += rng.poisson(1.0, dim.shape[:2] + (6,))
    assert photon_levels(dim, 16).signal < FEW_PHOTONS < photon_levels(half_sky, 16).signal
    for model in ("tr0",):
        (hint,) = [w for w in prepare_upscale(dim, model=model).warnings if "signal photons per pixel" in w]
        assert "tr4-ambient" in hint and "--model default" in hint and f"below {FEW_PHOTONS:g}" in hint
        assert not [w for w in prepare_upscale(half_sky, model=model).warnings if "signal photons per pixel" in w]
    for model in (photon_model[1], "default"):
        assert not [w for w in prepare_upscale(dim, model=model).warnings if "signal photons per pixel" in w]
    assert not [w for w in prepare_upscale(dim, model="tr0", read=Reading(clip_negative=True)).warnings
                if "signal photons per pixel" in w]


@pytest.mark.slow  # 8-10 s on 2 cores: keeps the default suite under 8 minutes
@pytest.mark.parametrize("frames", [1, 3, 9])
def test_iter_ambient_only_streams_what_ambient_only_computes(half_sky, frames):
    """Frame by frame, holding a window, the flags of the whole sequence: short sequences (fewer frames than
    the window) and the ends included; bad frames refused."""
    from jaxsr.inference import iter_ambient_only
    from jaxsr.sensor import ambient_only

    for length in (1, 4, 11):
        counts = half_sky[:length]
        got = np.stack(list(iter_ambient_only(iter(counts), alpha=1e-2, frames=frames)))
        np.testing.assert_array_equal(got, np.asarray(ambient_only(counts, alpha=1e-2, frames=frames)))
    bad = half_sky[:3].copy()
    bad[2, 0, 0, 0] = -1.0
    with pytest.raises(ValueError, match="frame 2 has negative"):
        list(iter_ambient_only(bad, frames=frames))


@pytest.fixture(scope="module")
def sky_everywhere(tmp_path_factory):
    """A photon model whose head calls every pixel no return (the case `keep_returns` is for)."""
    return _photon_model(tmp_path_factory.mktemp("k"), 3, 100.0)


def test_raw_output_streams_depth_and_logit_in_tiles_and_in_the_sequence_form(sky_everywhere, half_sky):
    import jax.numpy as jnp

    from jaxsr.inference import in_form, iter_network_inputs, iter_super_resolve, overrule_no_return
    from jaxsr.nn import apply_model_raw, apply_model_sequence, merge_no_return
    from jaxsr.temporal import windows

    model = sky_everywhere[0]
    x = np.stack(list(iter_network_inputs(half_sky[:5], SENSOR, model.config.inputs)))
    want = np.asarray(jax.jit(apply_model_raw, static_argnames="cfg")(model.params, model.state, windows(x, 0),
                                                                      model.config))
    for tile in (None, 11):  # 11 < 12 LR columns: two tiles stitched
        got = np.stack(list(iter_super_resolve(model, x, raw=True, tile=tile, batch_size=2)))
        assert got.shape == (5, 32, 48, 2)
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
    seq = in_form(model, "sequence")
    got = np.stack(list(iter_super_resolve(seq, x, raw=True)))
    assert got.shape == (5, 32, 48, 2)
    np.testing.assert_allclose(got, apply_model_sequence(seq.params, seq.state, x[None], seq.config, raw=True)[0],
                               rtol=1e-5, atol=1e-5)
    # the decision on the raw stream is the stream's own
    np.testing.assert_allclose(merge_no_return(jnp.asarray(got), seq.config), np.stack(list(iter_super_resolve(seq, x))),
                               rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match=r"\(\.\.\., H, W, 2\)"):  # a merged output is not raw
        overrule_no_return(want[..., 0], np.zeros((5, 8, 12), bool), 0.0)
    with pytest.raises(ValueError, match="no-return head"):
        next(iter_super_resolve(Model(*init_model(jax.random.key(0), ModelConfig(tr=0, **TINY)),
                                      ModelConfig(tr=0, **TINY)), x[..., 0], raw=True))


def test_a_black_patch_in_a_surface_keeps_depth_and_the_sky_stays_no_return(sky_everywhere):
    """The default decision on a surface with a patch (2 x 3 LR pixels returning no laser photon, enclosed by the
    surface) beside sky reaching the frame's edge: the head calls everything no return, the photons of the patch
    and of the sky both pass for ambient light alone; the patch, a hole, is a return and the sky stays no return.
    A black patch (no photon at all amid the surface's ambient light) takes the depth of the surface around it
    (`fill_holes`: harmonic in inverse depth, so filling it again changes nothing); a patch that gets the ambient
    light as the surface does (a dim or far surface) keeps the network's depth."""
    rng = np.random.default_rng(5)
    counts = rng.poisson(2.0 / 16, (9, 10, 14, 16)).astype(np.float32)
    surface = np.zeros((10, 14), bool)
    surface[:, :8] = True
    surface[4:6, 3:6] = False  # the black patch
    counts[:, surface, 7] += rng.poisson(6.0, (9, int(surface.sum())))
    lit = upscale(counts, None, model=sky_everywhere[1], read=Reading(units="normalised"))
    counts[:, 4:6, 3:6] = 0.0  # black
    result = upscale(counts, None, model=sky_everywhere[1], read=Reading(units="normalised"))
    depth = np.asarray(result.depth)
    assert (depth[:, :, 9 * 4:] == 1.0).all()  # the sky, beyond the column beside the surface
    assert (depth[:, 4 * 4:6 * 4, 3 * 4:6 * 4] < 1.0).all()  # the patch
    assert (depth[:, :, :8 * 4] < 1.0).all()
    assert f"more than {HOLE_PIXELS} LR pixels" in result.model_description
    patch = np.zeros((9, 10, 14), bool)
    patch[:, 4:6, 3:6] = True
    np.testing.assert_allclose(np.asarray(fill_holes(depth, patch, result.scale)), depth, rtol=0, atol=2e-6)
    lit_depth = np.asarray(lit.depth)
    assert (lit_depth[:, 4 * 4:6 * 4, 3 * 4:6 * 4] < 1.0).all()  # a return, the network's depth: not filled
    assert np.abs(np.asarray(fill_holes(lit_depth, patch, lit.scale)) - lit_depth).max() > 1e-3
    ring = depth[:, 4 * 4 - 1:6 * 4 + 1, 3 * 4 - 1:6 * 4 + 1].copy()
    ring[:, 1:-1, 1:-1] = np.nan
    inside = depth[:, 4 * 4:6 * 4, 3 * 4:6 * 4]  # the maximum principle: between the surface's depths around it
    assert (inside >= np.nanmin(ring) - 1e-6).all() and (inside <= np.nanmax(ring) + 1e-6).all()


def test_keep_returns_keeps_the_surface_a_head_calls_sky(sky_everywhere, half_sky, tmp_path, capsys):
    """The head calls everything no return; with keep_returns (by default "auto": AUTO_KEEP_RETURNS for a model with
    a head) the surface (4 photons a pixel and frame) comes out as the network's depth and the sky stays no return:
    the flags are `iter_quiet`'s (each pixel's own `ambient_only`, the quiet pixels' pools, no hole). Off
    (None, --keep-returns off), the head decides alone."""
    from jaxsr.cli import main
    from jaxsr.sensor import QUIET_POOLS, ambient_only, black_hole_pixels, hole_pixels, quiet_pixels

    model, path = sky_everywhere
    assert (upscale(half_sky, None, model=path, read=Reading(units="normalised"), photons=PhotonRules(keep_returns=None)).depth == 1.0).all()
    result = upscale(half_sky, None, model=path, read=Reading(units="normalised"), photons=PhotonRules(keep_returns=1e-3))
    assert AUTO_KEEP_RETURNS == 1e-3
    own = np.asarray(ambient_only(half_sky, alpha=1e-3, pixels=1))
    assert own[:, :, :6].mean() < 0.01 and own[:, :, 6:].all()  # one surface pixel of a first frame passes
    quiet = np.asarray(quiet_pixels(half_sky, alpha=1e-3))
    assert not quiet[:, :, :6].any() and quiet[:, :, 6:].all()  # that lone pixel, a hole, is the surface's again
    holes = np.asarray(hole_pixels(ambient_only(half_sky, alpha=1e-3, pixels=1, pools=QUIET_POOLS)))
    assert holes[:, :, :6].sum() == 1 and not holes[:, :, 6:].any()  # ... with the surface's ambient light:
    assert not np.asarray(black_hole_pixels(half_sky, alpha=1e-3)).any()  # not black, the network's depth
    hr_quiet = np.repeat(np.repeat(quiet, 4, axis=1), 4, axis=2)
    depth = super_resolve_histograms(with_no_return_logit(model, 1e6), half_sky)  # the depth under the head
    np.testing.assert_allclose(result.depth, np.clip(np.where(hr_quiet, 1.0, depth), 0, 1), atol=1e-6)
    assert result.summary()["keep_returns"] == 1e-3 and "alpha 0.001" in result.model_description
    np.testing.assert_allclose(np.clip(super_resolve_histograms(model, half_sky, keep_returns=1e-3), 0, 1),
                               result.depth, atol=1e-6)  # the library's form
    for bad, match in (({"keep_returns": 1e-3, "ambient_alpha": 1e-3}, "give one"), ({"keep_returns": 0.0}, "rate")):
        with pytest.raises(ValueError, match=match):
            super_resolve_histograms(model, half_sky, **bad)
    with pytest.raises(ValueError, match="has no head"):
        super_resolve_histograms(load_model("tr0"), half_sky, keep_returns=1e-3)
    src, out = tmp_path / "counts.npy", tmp_path / "out.npy"
    np.save(src, half_sky)
    assert main(["upscale", str(src), "-o", str(out), "--model", str(path), "--keep-returns", "1e-3", "--units",
                 "normalised", "--no-progress"]) == 0
    np.testing.assert_allclose(np.load(out), result.depth, atol=1e-6)
    assert main(["upscale", str(src), "-o", str(tmp_path / "off.npy"), "--model", str(path), "--keep-returns", "off",
                 "--units", "normalised", "--no-progress"]) == 0
    assert (np.load(tmp_path / "off.npy") == 1.0).all()
    capsys.readouterr()
    # refused: without a head, for depth, beside an ambient rate, out of range (each before any work)
    for model_name in ("tr0", "auto"):  # refused before the input is read (auto picks among TR0-TR4)
        with pytest.raises(ValueError, match="has no head"):
            prepare_upscale("/nonexistent/input.npy", model=model_name, photons=PhotonRules(keep_returns=1e-3))
    job = prepare_upscale(half_sky, photons=PhotonRules(keep_returns=2e-3))  # a rate of one's own for the default photon model
    assert job.keep_returns == 2e-3 and "alpha 0.002" in job.model_name
    with pytest.raises(ValueError, match="histograms or time tags"):
        prepare_upscale(np.full((2, 8, 12), 0.5, np.float32), model=path, photons=PhotonRules(keep_returns=1e-3))
    with pytest.raises(ValueError, match="give one"):
        prepare_upscale("/nonexistent/input.npy", photons=PhotonRules(ambient_alpha=1e-3, keep_returns=1e-3))
    with pytest.raises(ValueError, match=r"false-alarm rate in \[1e-30, 1\)"):
        prepare_upscale("/nonexistent/input.npy", photons=PhotonRules(keep_returns=2.0))
    assert main(["upscale", str(src), "-o", str(tmp_path / "b.npy"), "--keep-returns", "0"]) == 2
    assert "false-alarm rate" in capsys.readouterr().err



def test_ensemble_depth_averages_the_returns_and_never_the_decision():
    """The mean of both depths where both hold a return; a pixel either calls no return keeps the decision's
    output; None leaves the output as it is."""
    hr = np.array([[0.2, 1.0], [0.4, 0.995]], np.float32)
    other = np.array([[0.3, 0.3], [1.0, 0.5]], np.float32)
    np.testing.assert_allclose(ensemble_depth(hr, other), np.array([[0.25, 1.0], [0.4, 0.995]], np.float32))
    assert ensemble_depth(hr, other).dtype == np.float32 and ensemble_depth(hr, None) is hr


@pytest.mark.parametrize("signal, snr, ensemble", [
    (DEPTH_ENSEMBLE.min_signal, DEPTH_ENSEMBLE.min_snr, True), (1000.0, 5.0, True),
    (DEPTH_ENSEMBLE.min_signal * 0.9, 5.0, False), (1000.0, DEPTH_ENSEMBLE.min_snr * 0.9, False),
    (float("nan"), float("nan"), False)])
def test_the_default_averages_two_networks_at_high_photon_levels(signal, snr, ensemble):
    """model="default" for histograms: from `DEPTH_ENSEMBLE`'s signal and SNR up, its model too; below either, or
    unmeasured, the default model alone."""
    chosen = finish_model(ModelChoice(), plan_model(ModelChoice()), "histograms", lambda: None, signal, snr)
    assert chosen.name == DEFAULT_MODELS["histograms"]
    assert (chosen.ensemble_model is not None) == ensemble
    if ensemble:
        want, got = load_model(DEPTH_ENSEMBLE.model).config, chosen.ensemble_model
        assert (got.config.tr, got.config.inputs, got.has_no_return_head) == (want.tr, want.inputs, False)


def test_a_named_model_or_depth_frames_run_alone():
    """Only "default" for histograms adds a second network: a model named by the user is the model that runs."""
    named = ModelChoice(DEFAULT_MODELS["histograms"])
    assert finish_model(named, plan_model(named), "histograms", lambda: None, 1000.0, 5.0).ensemble_model is None
    assert finish_model(ModelChoice(), plan_model(ModelChoice()), "depth", lambda: None, 1000.0, 5.0).ensemble_model is None


def _bright_counts():
    """3 frames of 8 x 12 histograms: a surface of ~300 signal photons a pixel over the top rows, ambient light alone
    below (SNR above 1)."""
    rate = np.full((3, 8, 12, 16), 4.0, np.float32)
    rate[..., :6, 5] += 300.0
    return np.random.default_rng(0).poisson(rate).astype(np.float32)


def test_bright_histograms_get_the_second_network_named_and_counted_in_memory():
    """The job names the second network in its model line (not in the pictures' label) and its memory estimate
    counts it."""
    job = prepare_upscale(_bright_counts())
    assert job.ensemble_model is not None and DEPTH_ENSEMBLE.model in job.model_name
    assert DEPTH_ENSEMBLE.model not in job.label
    alone = dataclasses.replace(job, ensemble_model=None)
    assert upscale_memory(job, batch_size=2, in_memory=True) > upscale_memory(alone, batch_size=2, in_memory=True)


@pytest.mark.slow  # five runs of one or two TR4 networks: 20-40 s on 2 cores
@pytest.mark.parametrize("keep_returns", ["auto", None])
def test_bright_histograms_average_the_two_depths_where_the_default_outputs_a_return(keep_returns):
    """A bright surface: the default's output is its model's decision with the mean of its and
    `DEPTH_ENSEMBLE.model`'s depths on the returns, as the two give them run by name; with the confidence's decision
    (keep_returns "auto") and with the head's alone (None, the streamed path without the confidence)."""
    counts = _bright_counts()
    read, rules = Reading(units="normalised"), PhotonRules(keep_returns=keep_returns)
    result = upscale(counts, None, read=read, photons=rules).depth
    own = upscale(counts, None, model=DEFAULT_MODELS["histograms"], read=read, photons=rules).depth
    other = upscale(counts, None, model=DEPTH_ENSEMBLE.model, read=read, photons=PhotonRules(ambient_alpha=None)).depth
    np.testing.assert_allclose(result, ensemble_depth(own, other), atol=1e-6)
    assert (result < 0.99).any() and (result >= 0.99).any()
