"""Scene-adaptive TR: the motion estimator on sequences with known motion, and the choice from a study table."""

import numpy as np
import pytest

from jaxsr.inference.adaptive import SEARCH_RADIUS, choose_tr, estimate_motion, load_study


def _blocks(v, *, frames=32, angle=0.0, noise=0.05, seed=0):
    """Three near blocks (0.25) on a textured far plane (0.6) translating at v LR px/frame, rendered at 4x and
    block-averaged (sub-pixel motion is real), plus Gaussian noise."""
    rng = np.random.default_rng(seed)
    h, w = 32 * 4, 64 * 4
    yy, xx = np.mgrid[:h, :w]
    out = []
    for t in range(frames):
        d = 0.6 + 0.02 * np.sin(xx / 7.0)
        for k in range(3):
            cx = (40 + 80 * k + 4 * v * t * np.cos(angle)) % w
            cy = 64 + 4 * v * t * np.sin(angle)
            d = np.where((np.abs(xx - cx) < 16) & (np.abs(yy - cy) < 40), 0.25, d)
        out.append(d.reshape(32, 4, 64, 4).mean((1, 3)) + noise * rng.standard_normal((32, 64)))
    return np.clip(np.asarray(out, np.float32), 0, 1)


@pytest.mark.parametrize("v", [0.25, 0.5, 1.0, 2.0])
def test_estimate_motion_known_translation(v):
    est = estimate_motion(_blocks(v))
    assert est.motion == pytest.approx(v, rel=0.15) and not est.saturated


def test_estimate_motion_diagonal():
    assert estimate_motion(_blocks(1.0, angle=0.5)).motion == pytest.approx(1.0, rel=0.2)


def test_static_scene_has_no_motion_and_fast_motion_saturates():
    assert estimate_motion(_blocks(0.0)).motion == 0.0
    fast = estimate_motion(_blocks(5.0))  # beyond 6 px/frame the blocks, 20 px apart, would alias
    assert fast.saturated and fast.motion >= SEARCH_RADIUS / 2


def test_estimate_motion_bad_input():
    with pytest.raises(ValueError, match="T >= 2"):
        estimate_motion(np.zeros((1, 32, 64)))
    with pytest.raises(ValueError, match="NaN"):
        estimate_motion(np.full((3, 32, 64), np.nan))


TABLE = {  # a made-up study: TR4 best when slow, TR0 best when fast, TR4 too slow for 10 frames/s
    "motion": [0.1, 1.0, 10.0],
    "psnr": {"0": [30.0, 29.0, 27.0], "2": [31.0, 29.5, 26.5], "4": [32.0, 29.2, 25.0]},
    "fps": {"0": 40.0, "2": 12.0, "4": 5.0},
}


@pytest.mark.slow  # about 11 s: the table's every cell through choose_tr
def test_choose_tr_follows_the_table():
    assert choose_tr(_blocks(0.25), table=TABLE).tr == 4
    assert choose_tr(_blocks(1.0), table=TABLE).tr == 2
    assert choose_tr(_blocks(5.0), table=TABLE).tr == 0
    budget = choose_tr(_blocks(0.25), table=TABLE, min_fps=10.0)
    assert budget.tr == 2 and "reach 10" in budget.reason
    nothing = choose_tr(_blocks(0.25), table=TABLE, min_fps=100.0)
    assert nothing.tr == 0 and "fastest" in nothing.reason


def test_load_study_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="fps_study"):
        load_study(tmp_path / "none.json")
    (tmp_path / "bad.json").write_text('{"motion": []}')
    with pytest.raises(ValueError, match="psnr"):
        load_study(tmp_path / "bad.json")


def _photon_scene(v, *, photons, snr, sky, frames=16, seed=0):
    """Centre-of-mass LR frames (T, 32, 64) of a scene through jaxsr's sensor model: a wall sloping from 20 to
    30 m, three boxes 8-12 m away translating at v LR px/frame and, with `sky`, no return in the top quarter
    (ambient light alone there)."""
    import jax

    import jaxsr
    from jaxsr.config import Optics, Sensor

    h, w = 128, 256
    yy, xx = np.mgrid[:h, :w]
    depth, intensity = [], []
    for t in range(frames):
        d = 20.0 + 10.0 * xx / w
        for k in range(3):
            cx = (40 + 80 * k + 4 * v * t) % w
            d = np.where((np.abs(xx - cx) < 16) & (np.abs(yy - 80) < 40), 8.0 + 2.0 * k, d)
        if sky:
            d = np.where(yy < h // 4, np.inf, d)
        depth.append(d)
        intensity.append(0.3 + 0.4 * ((xx // 16 + yy // 16) % 2))
    sensor = Sensor(optics=Optics.of_hr((h, w)))
    counts = jaxsr.simulate_histograms(jax.random.key(seed), np.asarray(depth, np.float32),
                                       np.asarray(intensity, np.float32), sensor, snr=snr, mean_signal=photons)
    return np.asarray(jaxsr.centre_of_mass(counts, sensor), np.float32)


# the extremes of the SNR run by default, with and without sky; the middle two with -m slow (about 4 s each)
@pytest.mark.parametrize("snr", [0.1, pytest.param(0.3, marks=pytest.mark.slow),
                                 pytest.param(1.3, marks=pytest.mark.slow), 5.0])
@pytest.mark.parametrize("sky", [False, True])
def test_a_static_camera_reads_static_whatever_the_ambient_light_and_sky(snr, sky):
    """Ambient light alone (sky, surfaces whose peak drowns) puts a pixel's centre of mass anywhere in the gate
    from frame to frame: noise, not motion. At 3, 14 and 100 signal photons per pixel."""
    for photons in (3.0, 14.0, 100.0):
        est = estimate_motion(_photon_scene(0.0, photons=photons, snr=snr, sky=sky, seed=int(10 * snr + photons)))
        assert est.motion == 0.0 and not est.saturated, (photons, est)


@pytest.mark.parametrize("sky", [False, True])
def test_motion_through_photon_noise_and_sky(sky):
    est = estimate_motion(_photon_scene(1.0, photons=14.0, snr=1.3, sky=sky))
    assert est.motion == pytest.approx(1.0, rel=0.25) and not est.saturated


PHOTON_TABLE = {  # a made-up study: the photon model best at few photons, the paper's TR4 at many and slow motion
    "signal": [3.0, 100.0], "motion": [0.1, 3.0],
    "psnr": {"tr4-ambient": [[25.0, 24.0], [30.0, 29.0]], "tr4": [[20.0, 19.0], [32.0, 28.0]],
             "tr0-ambient": [[24.0, 24.5], [29.0, 29.5]]},
    "lead_se": {"tr4-ambient": [[0.0, 0.0], [0.0, 0.0]], "tr4": [[0.3, 0.3], [0.3, 0.3]],
                "tr0-ambient": [[0.1, 0.1], [0.1, 0.1]]},
    "default": "tr4-ambient",
    "fps": {"tr4-ambient": 5.0, "tr4": 5.0, "tr0-ambient": 40.0},
}


@pytest.mark.slow  # 8-32 s on 2 cores: keeps the default suite under 8 minutes
def test_choose_photon_model_follows_the_table():
    from jaxsr.inference import choose_photon_model

    still = _blocks(0.0)
    assert choose_photon_model(still, 2.0, table=PHOTON_TABLE).model == "tr4-ambient"
    assert choose_photon_model(still, 150.0, table=PHOTON_TABLE).model == "tr4"
    assert choose_photon_model(_blocks(5.0), 150.0, table=PHOTON_TABLE).model == "tr0-ambient"
    assert choose_photon_model(still, float("nan"), table=PHOTON_TABLE).model == "tr4-ambient"  # no return seen
    pick = choose_photon_model(still, 150.0, table=PHOTON_TABLE, min_fps=10.0)
    assert pick.model == "tr0-ambient" and "1 of 3 models reach 10" in pick.reason and "dB" not in pick.reason
    assert choose_photon_model(still, 150.0, table=PHOTON_TABLE, min_fps=100.0).model == "tr0-ambient"


def test_choose_photon_model_leaves_the_default_only_for_a_lead_the_clips_establish():
    """At 100 photons and fast motion tr0-ambient leads the default by 0.5 dB: with a standard error of 0.1 (a lead
    of 5) it is chosen, with 0.3 (1.7, under LEAD_Z = 2) the default stays; from one clip (inf) nothing displaces
    the default. A min_fps the default misses still gets the best that reaches it."""
    from jaxsr.inference import choose_photon_model
    from jaxsr.inference.adaptive import LEAD_Z

    assert LEAD_Z == 2.0
    fast = _blocks(5.0)
    assert choose_photon_model(fast, 100.0, table=PHOTON_TABLE).model == "tr0-ambient"
    for se in (0.3, float("inf")):
        table = {**PHOTON_TABLE, "lead_se": {**PHOTON_TABLE["lead_se"], "tr0-ambient": [[se, se], [se, se]]}}
        pick = choose_photon_model(fast, 100.0, table=table)
        assert pick.model == "tr4-ambient" and "the default" in pick.reason and "2 standard errors" in pick.reason
        assert choose_photon_model(fast, 100.0, table=table, min_fps=10.0).model == "tr0-ambient"
