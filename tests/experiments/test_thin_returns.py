"""experiments/studies/thin_returns.py: the crossed test depth and the three shares, on constructed outputs."""

from types import SimpleNamespace

import numpy as np

import thin_returns  # experiments/studies (pytest's pythonpath)
from jaxsr.config import SensorConfig


def wall(frames=3):
    h, w = SensorConfig().hr_shape
    depth = np.full((frames, h, w), 12.0, np.float32)
    return SimpleNamespace(name="wall", depth=depth, intensity=np.full_like(depth, 0.5), fps=30.0, snr=1.3)


def test_lines_cross_the_regions_only_and_keep_the_scene_depth():
    seqs, masks = thin_returns.crossed({"wall": wall()}, lines=4, widths=(2.0, 4.0))
    depth, on = seqs["wall"].depth, masks["wall"]
    assert on.any() and np.all(depth[:, on] == 12.0)  # the lines show the wall
    regions = np.isinf(depth).all(0)
    assert 0.2 < (regions | on).mean() < 0.4  # the benchmark's 30 % of sky, lines taken out of it
    assert not (regions & on).any()


def test_shares_count_each_kind_of_pixel():
    gt = np.full((1, 4, 4), 0.5, np.float32)
    gt[0, 0] = 1.0  # a row of sky
    lines = np.zeros((4, 4), bool)
    lines[1, :2] = True  # two line pixels (gt < 1)
    sr = gt.copy()
    sr[0, 1, 0] = 1.0  # one line pixel dropped
    sr[0, 0, :3] = 0.3  # three of four sky pixels as depth
    sr[0, 3, 3] = np.nan  # one other return lost (NaN is no return)
    s = thin_returns.shares(sr, gt, lines)
    assert s["lines_dropped"] == 50.0 and s["sky_as_depth"] == 75.0 and s["line_pixels"] == 2
    assert s["returns_dropped"] == 100.0 / 10


def test_the_block_majority_reference_decides_per_block_from_the_truth():
    gt = np.full((1, 8, 8), 0.4, np.float32)
    gt[0, :, :3] = 1.0  # sky on three quarters of the first block column
    out, truth = thin_returns.majority_output(SimpleNamespace(gt=gt, scored=np.array([0])))
    assert np.all(out[0, :, :4] == 1.0)  # the whole block column: no return, a return pixel included
    np.testing.assert_array_equal(out[0, :, 4:], gt[0, :, 4:])
    np.testing.assert_array_equal(truth, gt)
