"""`jaxsr upscale` with a model that reads the photons behind each depth: histograms feed it its channels
(over any gate, as the library's `super_resolve_histograms` does for the default gate), depth is refused with
a message that says what it needs, and "default" picks the bundled model that fits the input."""

import jax
import numpy as np
import pytest

from jaxsr.config import ModelConfig, SensorConfig
from jaxsr.inference import DEFAULT_MODELS, prepare_upscale, super_resolve_histograms, upscale
from jaxsr.io.checkpoint import save_model
from jaxsr.nn import Model, init_model, with_no_return_logit

SENSOR = SensorConfig()
TINY = dict(base=8, growth=4, head=16, filter_hidden=16)


@pytest.fixture(scope="module")
def photon_model(tmp_path_factory):
    cfg = ModelConfig(tr=0, inputs=("depth", "signal", "background"), no_return_head=True, **TINY)
    params, state = init_model(jax.random.key(0), cfg)
    # a head that marks some pixels, so that the no-return output is exercised
    params["no_return"]["conv2"]["b"] = params["no_return"]["conv2"]["b"] + 4.0
    model = Model(params, state, cfg)
    return model, save_model(tmp_path_factory.mktemp("m") / "photons.npz", model)


@pytest.fixture(scope="module")
def counts():
    return np.asarray(jax.random.poisson(jax.random.key(1), 0.8, (2, 8, 12, 16)), np.float32)


def test_histograms_through_a_photon_model_equal_the_library(photon_model, counts):
    model, path = photon_model
    result = upscale(counts, None, model=path, units="normalised")
    want = super_resolve_histograms(model, counts)
    np.testing.assert_allclose(result.depth, np.clip(want, 0, 1), atol=1e-6)


def test_depth_to_a_photon_model_is_refused(photon_model):
    depth = np.full((2, 8, 12), 0.5, np.float32)
    with pytest.raises(ValueError, match="histograms or time tags"):
        prepare_upscale(depth, model=photon_model[1])


def test_default_fits_the_input(counts):
    assert prepare_upscale(counts).model_name == DEFAULT_MODELS["histograms"]
    assert prepare_upscale(np.full((2, 8, 12), 0.5, np.float32)).model_name == DEFAULT_MODELS["depth"]
    with pytest.raises(TypeError, match="default"):
        prepare_upscale(counts, model=3)


def test_no_return_logit_moves_the_decision_and_is_refused_without_a_head(photon_model, counts):
    """--no-return-logit: a threshold above every logit marks nothing, below every logit everything; the
    library's `with_no_return_logit` gives the same output; a depth-only model refuses it before reading."""
    model, path = photon_model
    never = upscale(counts, None, model=path, units="normalised", no_return_logit=1e6).depth
    always = upscale(counts, None, model=path, units="normalised", no_return_logit=-1e6).depth
    assert not (never >= 1.0).any() and (always >= 1.0).all()
    want = super_resolve_histograms(with_no_return_logit(model, 1e6), counts)
    np.testing.assert_allclose(never, np.clip(want, 0, 1), atol=1e-6)
    with pytest.raises(ValueError, match="no-return head"):
        prepare_upscale(counts, model="tr0", no_return_logit=1.0)
    for spec in ("default", "auto"):  # they pick depth-only models: refused before the input is read
        with pytest.raises(ValueError, match="no-return head"):
            prepare_upscale("/nonexistent/input.npy", model=spec, no_return_logit=1.0)
    job = prepare_upscale(counts, model=path, no_return_logit=2.0)
    assert job.model.config.no_return_logit == 2.0 and job.model_name.endswith("at no-return logit 2")
    with pytest.raises(ValueError, match="finite number"):
        with_no_return_logit(model, float("nan"))


def test_cli_no_return_logit(photon_model, counts, tmp_path, capsys):
    from jaxsr.cli import main
    src = tmp_path / "counts.npy"
    np.save(src, counts)
    out = tmp_path / "out.npy"
    assert main(["upscale", str(src), str(out), "--model", str(photon_model[1]), "--no-return-logit", "1e6",
                 "--units", "normalised", "--no-progress"]) == 0
    assert not (np.load(out) >= 1.0).any()
    with pytest.raises(SystemExit) as e:
        main(["upscale", str(src), str(tmp_path / "b.npy"), "--no-return-logit", "inf"])
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
    sensor = SensorConfig(hr_shape=(32, 48))

    def counts(snr):
        alpha, beta = calibrate(jnp.asarray(depth), jnp.asarray(intensity), sensor, snr=snr, mean_signal=20.0)
        return np.asarray(sample_poisson(jax.random.key(0), calibrated_rates(depth, intensity, alpha, beta, sensor)))

    model, path = photon_model
    dark = prepare_upscale(counts(1e4), model=path)
    (warning,) = [w for w in dark.warnings if "frame SNR" in w]
    assert "0.05-20" in warning and "--no-return-logit" in warning
    assert not [w for w in prepare_upscale(counts(2.0), model=path).warnings if "frame SNR" in w]
    assert not [w for w in prepare_upscale(counts(1e4), model="tr0").warnings if "frame SNR" in w]
    set_logit = prepare_upscale(counts(1e4), model=path, no_return_logit=3.0).warnings
    assert [w for w in set_logit if "frame SNR" in w and "set to 3" in w and "such as 2" not in w]
    assert not [w for w in prepare_upscale(counts(1e4), model=path, clip_negative=True).warnings if "frame SNR" in w]
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
    sensor = SensorConfig(hr_shape=(32, 48))
    for snr, within in ((0.1, 1.0), (1.3, 0.25), (5.0, 0.25), (20.0, 0.25)):
        c = simulate_histograms(jax.random.key(1), jnp.asarray(depth), jnp.asarray(intensity), sensor, snr=snr,
                                mean_signal=14.0)
        assert abs(frame_snr(np.asarray(c), sensor) / snr - 1) < within
    with pytest.raises(ValueError, match="histograms"):
        frame_snr(np.zeros((4, 8, 8)))
