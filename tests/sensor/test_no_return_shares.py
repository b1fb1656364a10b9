"""jaxsr.sensor.no_return: the share of each LR pixel without a return, placed to within an LR block (named apart
from tests/training/test_no_return.py: pytest imports test files by their base name)."""

import jax
import numpy as np
import pytest

import jaxsr
from jaxsr.config import Sensor
from jaxsr.inference import no_return_where
from jaxsr.sensor import ambient_only, no_return_shares, share_of_window

CFG = Sensor()
K = CFG.bins


def split_scene(signal: float, ambient: float, *, frames: int = 9, h: int = 8, w: int = 10, edge: int = 4,
                seed=None):
    """Counts (frames, h, w, K): LR columns left of `edge` hold a return of `signal` photons per frame in bin 5,
    column `edge` half of one (its block half sky, split down its middle), the rest ambient light alone
    (`ambient` photons per frame over the gate); expected counts, or Poisson draws with `seed`. And the (H, W)
    truth: True where an HR pixel has no return."""
    share = np.zeros((h, w))
    share[:, edge] = 0.5
    share[:, edge + 1:] = 1.0
    rates = np.full((frames, h, w, K), ambient / K)
    rates[..., 5] += signal * (1.0 - share)
    counts = rates if seed is None else np.random.default_rng(seed).poisson(rates)
    truth = np.zeros((h * CFG.scale, w * CFG.scale), bool)
    truth[:, edge * CFG.scale + CFG.scale // 2:] = True
    return counts.astype(np.float32), truth


def test_the_edge_falls_inside_its_block():
    """The 3 x 3 test leaves the sky's first column as depth and paints the half block one way; the shares
    grow the region to its edge and, interpolated, put the edge where it is, mid-block."""
    counts, truth = split_scene(60.0, 32.0)
    flags = np.asarray(ambient_only(counts))[4]
    blocks = np.kron(flags, np.ones((4, 4), bool))
    assert (blocks != truth).sum() >= 5 * truth.shape[0]  # a column of sky blocks and half of the edge's block
    shares = np.asarray(no_return_shares(counts))[4]
    assert shares.dtype == np.float32 and shares.min() >= 0.0 and shares.max() <= 1.0
    np.testing.assert_allclose(shares[:, 4], 0.5, atol=1e-6)  # half the neighbours' excess
    marked = no_return_where(np.zeros(truth.shape, np.float32), shares) == 1.0
    np.testing.assert_array_equal(marked, truth)
    # booleans, and 0/1 integers, still paint blocks
    np.testing.assert_array_equal(no_return_where(np.zeros(truth.shape, np.float32), flags) == 1.0, blocks)
    np.testing.assert_array_equal(no_return_where(np.zeros(truth.shape, np.float32), flags.astype(np.uint8)) == 1.0,
                                  blocks)


def test_where_the_photons_cannot_tell_the_test_alone_decides():
    """The guard, on either side of its threshold. 60 signal photons a frame against 32 ambient: the sky's first
    column, which the 3 x 3 test leaves, joins the region. 14 against 400: the returns are significant pixel by
    pixel (p <= 0.001 over 9 frames) and the half block passes for ambient light beside the flagged sky, but half a
    return would not stand out there (p > DETECTABLE_AT): nothing joins, no share, the shares are the test's
    flags. A faint return in bright light (1 against 40): no reference at all, the same."""
    counts, _ = split_scene(60.0, 32.0)
    flags = np.asarray(ambient_only(counts))
    assert not flags[4, :, 5].any() and (np.asarray(no_return_shares(counts))[4, :, 5] == 1.0).all()
    counts, _ = split_scene(14.0, 400.0)
    log_p = np.asarray(jaxsr.sensor.return_significance(counts.sum(axis=0)))
    assert (log_p[:, :4] <= np.log(1e-3)).all() and (log_p[:, 4] > np.log(0.01)).all()
    flags = np.asarray(ambient_only(counts))
    assert flags[4, :, 5].all() and not flags[4, :, 4].any()
    np.testing.assert_array_equal(np.asarray(no_return_shares(counts)), flags.astype(np.float32))
    counts, _ = split_scene(1.0, 40.0, seed=3)
    np.testing.assert_array_equal(np.asarray(no_return_shares(counts)), np.asarray(ambient_only(counts)).astype(np.float32))


def test_at_a_few_photons_drawn_the_sky_empties_and_the_surface_stays():
    """Poisson draws at 30 signal photons per pixel and frame, SNR 1: the surface is kept, the sky beyond the
    half block is marked."""
    counts, truth = split_scene(30.0, 30.0, seed=4)
    shares = np.asarray(no_return_shares(counts))
    marked = no_return_where(np.zeros((9, *truth.shape), np.float32), shares) == 1.0
    assert not marked[:, :, : 4 * CFG.scale].any()  # the surface
    assert marked[:, :, 5 * CFG.scale:].mean() > 0.99  # the sky beyond the half block


@pytest.mark.slow  # 8-10 s on 2 cores: keeps the default suite under 8 minutes
def test_one_window_computes_what_the_whole_does():
    """A frame's share from its nine frames summed; the ends of the sequence sum fewer (cut, not replicated)."""
    counts, _ = split_scene(20.0, 20.0, frames=11, seed=5)
    whole = np.asarray(no_return_shares(counts))
    np.testing.assert_allclose(np.asarray(share_of_window(counts[:5].sum(axis=0))), whole[0], atol=1e-6)
    window = counts[1:10].sum(axis=0)  # frame 5's nine frames
    np.testing.assert_allclose(np.asarray(share_of_window(window)), whole[5], atol=1e-6)


def test_extremes_are_finite_or_refused():
    """No photons: nothing to see, all no return. Huge counts stay finite. NaN refused eagerly, and traced a
    histogram holding one adds no photons."""
    assert (np.asarray(no_return_shares(np.zeros((9, 8, 10, K), np.float32))) == 1.0).all()
    huge, _ = split_scene(1e36, 1e36)
    shares = np.asarray(no_return_shares(huge))
    assert np.isfinite(shares).all() and (shares[:, :, :4] == 0.0).all() and (shares[:, :, 6:] == 1.0).all()
    counts, _ = split_scene(20.0, 20.0, seed=6)
    bad = counts.copy()
    bad[1, 0, 9, 2] = np.nan
    with pytest.raises(ValueError, match="no_return_shares: counts must be finite"):
        no_return_shares(bad)
    zeroed = counts.copy()
    zeroed[1, 0, 9] = 0.0
    traced = jax.jit(no_return_shares)
    np.testing.assert_array_equal(np.asarray(traced(bad)), np.asarray(traced(zeroed)))


@pytest.mark.parametrize("kwargs,match", [({"pixels": 2}, "odd integer"), ({"alpha": 0.0}, "false-alarm rate")])
def test_bad_settings_and_shapes_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        no_return_shares(np.zeros((2, 4, 4, K), np.float32), **kwargs)
    with pytest.raises(ValueError, match=match):
        share_of_window(np.zeros((4, 4, K), np.float32), **kwargs)
    with pytest.raises(ValueError, match=r"\(T, h, w, 16\)"):
        no_return_shares(np.zeros((4, 4, K), np.float32))
    with pytest.raises(ValueError, match=r"\(h, w, 16\) histograms of one frame"):
        share_of_window(np.zeros((2, 4, 4, K), np.float32))


def test_public_names():
    assert jaxsr.sensor.no_return_shares is no_return_shares
    assert jaxsr.inference.no_return_where is no_return_where
