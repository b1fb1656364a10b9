"""The photon-regime data source (jaxsr.training.regime_batches, jaxsr.config.PhotonRegime): per-clip draws in the
regime's ranges, shapes, determinism per key, no-return regions in the ground truth, and that it traces."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr.config import PAPER_REGIME, PhotonRegime, Sensor, TrainConfig
from jaxsr.nn.inputs import PHOTON_SCALE
from jaxsr.training import regime_batches, regime_clips, regime_parameters

SENSOR = Sensor()


def test_regime_is_json_ready_and_checked():
    regime = PhotonRegime()
    card = json.loads(json.dumps(regime.to_dict()))
    assert card["signal_range"] == [0.5, 1000.0] and card["snr_range"] == [0.05, 20.0]
    assert PhotonRegime(**{k: tuple(v) if isinstance(v, list) else v for k, v in card.items()}) == regime
    assert PAPER_REGIME.signal_range == TrainConfig().mean_signal_range
    for change in (dict(signal_range=(0.0, 10.0)), dict(snr_range=(5.0, 1.0)), dict(dark_prob=1.5),
                   dict(no_return_fraction=(0.2, 1.5)), dict(blob_size=0), dict(motion="fast"),
                   dict(irf_sigma_range=(0.3, float("inf"))), dict(thin_prob=1.5), dict(static_prob=1.5), dict(thin_lines_max=0),
                   dict(thin_width_range=(0.0, 2.0)), dict(signal_range=(1.0, 1e300)),
                   dict(signal_range=(1e-300, 1.0)), dict(snr_range=(1.0, 1e5)), dict(snr_range=(1e-4, 1.0))):
        with pytest.raises(ValueError, match="PhotonRegime"):
            PhotonRegime(**change)


def test_parameters_span_the_regime():
    regime = PhotonRegime()
    p = {k: np.asarray(v) for k, v in
         jax.jit(jax.vmap(lambda k: regime_parameters(k, regime)))(jax.random.split(jax.random.key(0), 4000)).items()}
    lo, hi = regime.signal_range
    assert lo <= p["mean_signal"].min() < 0.6 and 800 < p["mean_signal"].max() <= hi
    assert np.median(np.log(p["mean_signal"])) == pytest.approx(np.log(np.sqrt(lo * hi)), abs=0.2)
    assert 0.05 <= p["snr"].min() < 0.06 and 17 < p["snr"].max() <= 20.0
    sigma = p["irf_sigma"]
    assert sigma.min() >= 0.3 - 1e-6 and sigma.max() <= 3.0 + 1e-5 and sigma.max() > 2.5
    assert np.mean(sigma == np.float32(0.4)) == pytest.approx(0.25, abs=0.03)  # the paper's pulse
    assert 0.1 < np.mean(sigma > 1.5) < 0.2  # the long tail
    for name, prob in (("dark", 0.5), ("hot_fraction", 0.3), ("dead_fraction", 0.3),
                       ("no_return_fraction", 0.5)):
        assert np.mean(p[name] > 0) == pytest.approx(prob, abs=0.03), name
    assert p["hot_fraction"].max() <= 0.01 and p["dead_fraction"].max() <= 0.01
    drawn = p["no_return_fraction"][p["no_return_fraction"] > 0]
    assert drawn.min() >= 0.05 and drawn.max() <= 0.6


@pytest.mark.slow  # 8-32 s on 2 cores: keeps the default suite under 8 minutes
def test_default_source_traces():
    cfg = dataclasses.replace(TrainConfig(), batch_size=2, patch=(16, 32))
    make_batch = regime_batches(2, cfg, sensor=SENSOR)
    windows, gt = jax.eval_shape(make_batch, jax.random.key(0))
    assert windows.shape == (2, 5, 16, 32) and gt.shape == (2, 64, 128)
    assert "PhotonRegime" in make_batch.description and make_batch.regime == PhotonRegime().to_dict()
    clips, gt = jax.eval_shape(regime_clips(9, cfg, sensor=SENSOR), jax.random.key(0))
    assert clips.shape == (2, 9, 16, 32) and gt.shape == (2, 9, 64, 128)


@pytest.mark.slow
def test_low_photons_and_no_return_regions():
    """One compiled batch at the low end (0.5 signal photons per pixel at SNR 20, no dark counts: most histograms
    are empty)
    with no-return regions on 30 % of every clip: the ground truth is 1.0 there, the windows mostly no return;
    the same key gives the same batch."""
    regime = dataclasses.replace(PhotonRegime(), signal_range=(0.5, 0.5), snr_range=(20.0, 20.0),
                                 no_return_prob=1.0, no_return_fraction=(0.3, 0.3), motion="drawn", dark_prob=0.0,
                                 hot_prob=0.0)
    cfg = dataclasses.replace(TrainConfig(), batch_size=2, patch=None)
    make_batch = jax.jit(regime_batches(0, cfg, regime, sensor=SENSOR))
    windows, gt = (np.asarray(a) for a in make_batch(jax.random.key(3)))
    assert windows.shape == (2, 1, 32, 64) and gt.shape == (2, 128, 256)
    assert np.all((windows >= 0) & (windows <= 1)) and np.all((gt >= 0) & (gt <= 1))
    assert np.all((gt == 1.0).mean(axis=(1, 2)) >= 0.3 - 1e-3)
    assert (windows == 1.0).mean() > 0.5
    again, _ = make_batch(jax.random.key(3))
    np.testing.assert_array_equal(again, windows)
    other, _ = make_batch(jax.random.key(4))
    assert not np.array_equal(np.asarray(other), windows)


def draws(regime, seed: int, n: int = 2000) -> dict:
    """`regime_parameters` of n keys split from `seed`, as NumPy arrays."""
    keys = jax.random.split(jax.random.key(seed), n)
    return {k: np.asarray(v) for k, v in jax.jit(jax.vmap(lambda k: regime_parameters(k, regime)))(keys).items()}


def assert_drawn_apart(seed: int, name: str, **setting) -> tuple[dict, dict]:
    """The draws with `setting` (e.g. thin_prob=0.5) and without, on the same keys: every parameter but `name`
    (the one `setting` draws) is the same, so older regimes' clips stay as they were; without, `name` is never
    drawn. Returns (without, with)."""
    plain, drawn = draws(PhotonRegime(paper_prob=0.2), seed), draws(PhotonRegime(paper_prob=0.2, **setting), seed)
    for other in plain:
        if other != name:
            np.testing.assert_array_equal(plain[other], drawn[other], err_msg=other)
    assert not plain[name].any()
    return plain, drawn


def test_thin_returns_are_drawn_apart_and_only_across_no_return_regions():
    """thin_prob draws line counts from keys of their own: every other parameter is what thin_prob = 0 draws, so
    older regimes' clips stay as they were; lines come only with drawn no-return regions, and never in clips of
    the paper's regime."""
    _, thin = assert_drawn_apart(1, "thin_lines", thin_prob=0.5)
    lines, holed = thin["thin_lines"], thin["no_return_fraction"] > 0
    assert not lines[~holed].any() and 1 <= lines[lines > 0].min() and lines.max() == PhotonRegime().thin_lines_max
    assert np.mean(lines[holed] > 0) == pytest.approx(0.5, abs=0.05)


@pytest.mark.slow
def test_thin_returns_keep_the_scene_depth_inside_no_return_regions():
    """With every clip holed and crossed, the ground truth holds returns (< 1) where the regions alone would
    have none: the lines show through the sky. (Slow: two whole data sources compiled, about a minute.)"""
    base = dict(signal_range=(20.0, 20.0), snr_range=(5.0, 5.0), no_return_prob=1.0, no_return_fraction=(0.5, 0.5),
                motion="drawn", paper_prob=0.0)
    cfg = dataclasses.replace(TrainConfig(), batch_size=2, patch=None)
    batches = [jax.jit(regime_batches(0, cfg, PhotonRegime(**base, thin_prob=p), sensor=SENSOR))(jax.random.key(3))
               for p in (0.0, 1.0)]
    (_, holed), (_, crossed) = ([np.asarray(a) for a in b] for b in batches)
    sky = holed == 1.0
    assert np.all(sky.mean(axis=(1, 2)) >= 0.5 - 1e-3)
    shows = sky & (crossed < 1.0)
    assert np.all(shows.mean(axis=(1, 2)) > 0.002)  # every clip: some sky crossed
    np.testing.assert_array_equal(crossed[~sky], holed[~sky])  # nothing changes outside the regions


def test_validation_needs_an_snr_if_given_a_grid():
    from jaxsr.training import regime_validation

    with pytest.raises(ValueError, match="snrs"):
        regime_validation(0, TrainConfig(), PAPER_REGIME, batches=2, sensor=SENSOR, snrs=())


@pytest.mark.slow
def test_validation_at_fixed_snrs_shares_the_batches_out_in_turn():
    """regime_validation(snrs=...) draws its batches at each SNR named, in turn: the ambient channel reads far
    higher at SNR 0.1 than at 100, as a regime held at that SNR draws them; without snrs the set is the regime's,
    as before. (Slow: four data sources compiled, about a minute each on a busy core.)"""
    from jaxsr.training import regime_validation

    cfg = dataclasses.replace(TrainConfig(), batch_size=2, patch=(8, 16))
    regime = dataclasses.replace(PAPER_REGIME, signal_range=(20.0, 20.0))
    inputs = ("depth", "signal", "background", "ambient")
    val = regime_validation(0, cfg, regime, batches=3, sensor=SENSOR, inputs=inputs, snrs=(0.1, 100.0))
    ambient = np.asarray(val["windows"])[..., 3].reshape(3, 2, -1).mean(axis=(1, 2))  # per batch
    assert val["windows"].shape == (6, 1, 8, 16, 4) and "SNR 0.1, 100" in val["names"][0]
    assert ambient[0] > 2 * ambient[1] and ambient[2] > 2 * ambient[1]  # 0.1, 100, 0.1
    plain = regime_validation(0, cfg, regime, batches=2, sensor=SENSOR, inputs=inputs)
    assert plain["windows"].shape[0] == 4 and "SNR" not in plain["names"][0]
    source = jax.jit(regime_batches(0, cfg, regime, sensor=SENSOR, inputs=inputs))
    for i in range(2):  # as before: batch i from the fixed key folded with i
        windows, _ = source(jax.random.fold_in(jax.random.key(2**31 - 1), i))
        np.testing.assert_array_equal(np.asarray(plain["windows"][2 * i:2 * i + 2]), np.asarray(windows))
    # the grid's one source (the SNR an argument) draws what a regime held at that SNR draws, with the same keys
    at_100 = jax.jit(regime_batches(0, cfg, dataclasses.replace(regime, snr_range=(100.0, 100.0)), sensor=SENSOR,
                                    inputs=inputs))
    windows, gt = at_100(jax.random.fold_in(jax.random.key(2**31 - 1), 1))
    np.testing.assert_array_equal(np.asarray(val["gt"][2:4]), np.asarray(gt))
    np.testing.assert_array_equal(np.asarray(val["windows"][2:4]), np.asarray(windows))


def test_the_clips_sky_is_the_regions_crossed_by_the_drawn_lines():
    """regime_clips' no-return step (`_regime_no_return`) on a constant depth: without lines it is exactly
    `no_return_regions`; with them, the regions lose the lines' pixels and the scene's depth shows there."""
    from jaxsr.sensor import no_return_regions, thin_returns
    from jaxsr.training.data import _regime_no_return

    h, w = SENSOR.hr_shape
    depth = np.full((2, h, w), 9.0, np.float32)
    regime = PhotonRegime(thin_prob=1.0)
    key = jax.random.key(3)
    p = {"no_return_fraction": 0.5, "sky": 0.5, "thin_lines": 0}
    plain = np.asarray(_regime_no_return(key, depth, p, regime))
    np.testing.assert_array_equal(plain, np.asarray(no_return_regions(key, depth, fraction=0.5, sky=0.5)))
    never = np.asarray(_regime_no_return(key, depth, dict(p, thin_lines=4), PhotonRegime()))  # thin_prob 0
    np.testing.assert_array_equal(never, plain)
    crossed = np.asarray(jax.jit(_regime_no_return, static_argnums=3)(key, depth, dict(p, thin_lines=4), regime))
    lines = np.asarray(thin_returns(jax.random.fold_in(key, 1), (h, w), lines=4))
    sky = np.isinf(plain[0])
    assert (sky & lines).any() and np.all(crossed[:, sky & lines] == 9.0)
    np.testing.assert_array_equal(crossed[:, ~lines], plain[:, ~lines])


def test_static_clips_are_drawn_apart_and_never_from_the_paper_regime():
    """static_prob draws from a key of its own: every other parameter is what static_prob = 0 draws, so older
    regimes' clips stay as they were; about that share of the wide regime's clips are static, none of the
    paper's."""
    assert_drawn_apart(2, "static", static_prob=0.3)
    assert np.mean(draws(PhotonRegime(static_prob=0.3), 2)["static"]) == pytest.approx(0.3, abs=0.04)
    assert not draws(PhotonRegime(paper_prob=1.0, static_prob=1.0), 2)["static"].any()  # the paper's clips move


@pytest.mark.slow
def test_static_clips_repeat_their_centre_frame_under_new_photons():
    """With every clip static the ground truth is one frame repeated, while the photons (the LR inputs) differ
    from frame to frame; without, the frames move. (Slow: two data sources compiled.)"""
    base = dict(signal_range=(20.0, 20.0), snr_range=(5.0, 5.0), no_return_prob=0.0, paper_prob=0.0)
    cfg = dataclasses.replace(TrainConfig(), batch_size=2, patch=None)
    (lr_still, gt_still), (_, gt_moving) = ([np.asarray(a) for a in
                                             jax.jit(regime_clips(3, cfg, PhotonRegime(**base, static_prob=p),
                                                                  sensor=SENSOR))(jax.random.key(5))]
                                            for p in (1.0, 0.0))
    np.testing.assert_array_equal(gt_still, np.broadcast_to(gt_still[:, 1:2], gt_still.shape))
    np.testing.assert_array_equal(gt_still[:, 1], gt_moving[:, 1])  # the centre frame is the moving clip's
    assert not np.array_equal(lr_still[:, 0], lr_still[:, 2])
    assert not np.array_equal(gt_moving[:, 0], gt_moving[:, 2])


@pytest.mark.slow
def test_static_clips_hold_the_centre_frames_intensity_too(monkeypatch):
    """A static clip shows its centre frame's reflectivity in every frame, not only its depth: a flat wall that
    brightens fivefold from the first frame to the last gives the first and last frames about the same signal
    photons when static and a fivefold ratio when moving. (Slow: two data sources compiled.)"""
    import jaxsr.training.data as data

    def brightening(key, frames, *, sensor, shift_range, motion):
        shape = (frames, *sensor.hr_shape)
        return (jnp.full(shape, 10.0), jnp.linspace(0.2, 1.0, frames)[:, None, None] * jnp.ones(shape))

    monkeypatch.setattr(data, "training_clip", brightening)
    base = dict(signal_range=(200.0, 200.0), snr_range=(20.0, 20.0), no_return_prob=0.0, paper_prob=0.0,
                dark_prob=0.0, hot_prob=0.0, dead_prob=0.0)
    cfg = dataclasses.replace(TrainConfig(), batch_size=2, patch=None)

    def last_over_first(static_prob):
        make = regime_clips(3, cfg, PhotonRegime(**base, static_prob=static_prob), sensor=SENSOR,
                            inputs=("depth", "signal"))
        signal = np.expm1(np.asarray(jax.jit(make)(jax.random.key(3))[0])[..., 1] * np.log1p(PHOTON_SCALE))
        return signal[:, 2].mean() / signal[:, 0].mean()

    assert last_over_first(1.0) == pytest.approx(1.0, abs=0.05)
    assert last_over_first(0.0) > 3.0
