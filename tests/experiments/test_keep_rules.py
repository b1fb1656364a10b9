"""experiments/studies/keep_rules.py: each rule's decision on hand-made head outputs, the blocks' signal, and the
study's photon video and scores against experiments/studies/real_photons.py's (skipped without the recordings)."""

import numpy as np
import pytest

import jaxsr
import keep_rules  # experiments/studies (pytest's pythonpath)
import real_photons


def _blocks(cells, shape=(12, 12), r=4):
    m = np.zeros(shape, bool)
    for y, x in cells:
        m[r * y:r * y + r, r * x:r * x + r] = True
    return m


def test_rules_decide_as_described():
    """3 x 3 blocks of 4 x 4 at threshold 0, the photons showing a return but in (0, 2):
    (0, 0) dropped whole, logit 5, 40 signal photons a frame; (0, 1) its left half dropped, logit 5, 5 photons;
    (0, 2) dropped whole, logit 1, its photons passing for ambient light; (1, 0) dropped whole, logit 3, 20
    photons; the rest kept (logit -5)."""
    depth = np.full((1, 12, 12), 0.3, np.float32)
    logit = np.full((1, 12, 12), -5.0, np.float32)
    logit[0, :4, :4] = 5.0
    logit[0, :4, 4:6] = 5.0
    logit[0, :4, 8:] = 1.0
    logit[0, 4:8, :4] = 3.0
    quiet = np.zeros((1, 3, 3), bool)
    quiet[0, 0, 2] = True
    signal = np.full((1, 3, 3), 5.0)
    signal[0, 0, 0], signal[0, 1, 0] = 40.0, 20.0
    out = keep_rules.rules(depth, logit, quiet, signal, 0.0)
    dropped = {name: sr[0] == 1.0 for name, sr in out.items()}
    half = np.zeros((12, 12), bool)
    half[:4, 4:6] = True
    quiet_block = _blocks([(0, 2)])
    np.testing.assert_array_equal(dropped["head"], _blocks([(0, 0), (0, 2), (1, 0)]) | half)
    np.testing.assert_array_equal(dropped["keep"], quiet_block)  # only where the photons pass for ambient light
    np.testing.assert_array_equal(dropped["split blocks"], quiet_block | half)  # and the edge it placed
    np.testing.assert_array_equal(dropped["signal >= 10"], quiet_block | _blocks([(0, 0), (1, 0)]))
    np.testing.assert_array_equal(dropped["signal >= 30"], quiet_block | _blocks([(0, 0)]))
    np.testing.assert_array_equal(dropped["+2 where a return"], quiet_block | _blocks([(0, 0), (1, 0)]) | half)
    np.testing.assert_array_equal(dropped["+4 where a return"], quiet_block | _blocks([(0, 0)]) | half)
    for sr in out.values():  # elsewhere the network's depth
        np.testing.assert_array_equal(sr[0][sr[0] != 1.0], np.float32(0.3))


def test_block_signal_less_the_ambient_per_frame_summed():
    """12 frames of 1 ambient photon per bin everywhere, and 8 signal photons in one pixel in frame 0 only: the
    9-frame windows that hold frame 0 (t = 0..4, cut at the start: 5..9 frames) read 8 / their frames there,
    the others and every other pixel 0."""
    counts = np.ones((12, 4, 4, 16), np.float32)
    counts[0, 1, 2, 5] += 8.0
    signal = keep_rules.block_signal(counts, jaxsr.SensorConfig())
    assert signal.shape == (12, 4, 4)
    expected = np.zeros((12, 4, 4))
    expected[:5, 1, 2] = 8.0 / np.arange(5, 10)
    np.testing.assert_allclose(signal, expected, atol=1e-4)


DATA = real_photons.DEFAULT_DATA


@pytest.mark.skipif(not (DATA / real_photons.SOURCES[0].file).is_file(),
                    reason=f"the real recording tower.mat is not in {DATA}; it is not part of the project")
def test_the_same_video_and_scores_as_real_photons():
    """On a crop of tower, the head alone and the keep rule score as real_photons.evaluate scores the model alone
    and with --keep-returns: the same photon video, the same reference (tr0-ambient: a head, compiles fast)."""
    rec = real_photons.read_recording(DATA, real_photons.SOURCES[0], crop=(64, 64, 48))
    model = jaxsr.load_model("tr0-ambient")
    ours = keep_rules.evaluate(rec, model, levels=[2.0], max_frames=2, log=lambda _: None)[0]
    theirs = real_photons.evaluate([rec], {"A": model, "A+keep": model}, levels=[2.0], max_frames=2, tv=False,
                                   ambient={"A+keep": ("keep", keep_rules.KEEP_ALPHA)}, log=lambda _: None)
    scores = theirs[rec.name]["levels"][0]["scores"]
    for rule, label in (("head", "A"), ("keep", "A+keep")):
        for key in ("psnr", "no_return", "sky_as_depth", "edge_sky_as_depth"):
            np.testing.assert_allclose(ours["scores"][rule][key], scores[label][key], atol=1e-3, err_msg=key)
    for s in ours["scores"].values():
        share = s["edge_sky_as_depth"]
        assert np.all(np.isnan(share) | ((share >= 0) & (share <= 1)))
