"""experiments/studies/no_return_edges.py: region growing, edge shares and their interpolation on constructed
histograms."""

import jax.numpy as jnp
import no_return_edges as study  # experiments/studies (pytest's pythonpath)
import numpy as np
import pytest

from jaxsr.config import SensorConfig
from jaxsr.sensor import ambient_only


def edge_scene(sensor: SensorConfig, h: int = 8, w: int = 10, edge_column: int = 4, frames: int = 9):
    """Histograms of `frames` identical frames: LR columns left of `edge_column` hold a return (60 photons in
    bin 5), the column itself half of one (its block half sky, split at its middle), the rest ambient alone (2
    photons a bin); and the (H, W) normalised truth (0.3 for a return, 1 for none)."""
    share = np.zeros((h, w))
    share[:, edge_column] = 0.5
    share[:, edge_column + 1:] = 1.0
    counts = np.full((frames, h, w, sensor.bins), 2.0, np.float32)
    counts[..., 5] += 60.0 * (1.0 - share)
    s = sensor.scale
    gt = np.full((h * s, w * s), 0.3)
    gt[:, edge_column * s + s // 2:] = 1.0
    return jnp.asarray(counts), gt


def test_the_edge_lands_inside_its_block():
    sensor = SensorConfig()
    counts, gt = edge_scene(sensor)
    flags = np.asarray(ambient_only(counts, sensor, alpha=study.TEST_ALPHA))[4]
    said = study.decisions(flags, counts.sum(axis=0), gt, sensor)
    per_lr = said["3x3x9 test"]
    # the 3 x 3 test misses the column of sky next to the half block: two LR columns from the edge stay depth
    assert study.no_return_rates(np.where(per_lr, 1.0, 0.0), gt)[0] > 20.0
    for label in ("grown + edges", study.GUARDED):
        np.testing.assert_array_equal(said[label], gt >= 1.0)  # exact: the share 0.5 puts the edge mid-block
    np.testing.assert_array_equal(said["true shares, interpolated (truth)"], gt >= 1.0)
    # the best decision per LR block paints the half block one way or the other
    assert (said["block majority (truth)"] != (gt >= 1.0)).sum() == 2 * gt.shape[0]


def test_grown_follows_connected_ambient_pixels_only():
    flags = np.zeros((6, 6), bool)
    flags[0, 0] = True
    ambient = np.zeros((6, 6), bool)
    ambient[0, :4] = True  # connected to the flag
    ambient[1, 4] = True  # diagonally
    ambient[5, 5] = True  # alone
    want = ambient.copy()
    want[5, 5] = False
    np.testing.assert_array_equal(study.grown(flags, ambient), want | flags)


def test_edge_shares_reads_the_excess_against_its_neighbours():
    region = np.zeros((3, 5), bool)
    region[:, 3:] = True
    excess = np.array([[40.0, 40.0, 10.0, 0.0, 0.0]] * 3)
    share = study.edge_shares(region, excess, excess > 30.0)
    assert share[1, 2] == pytest.approx(0.75)  # a quarter of the returns' excess: three quarters sky
    assert (share[:, :2] == 0.0).all() and (share[:, 3:] == 1.0).all()
    # no significant pixel around: its own excess is the reference, no sky
    alone = study.edge_shares(region, excess, np.zeros_like(region))
    assert alone[1, 2] == 0.0
