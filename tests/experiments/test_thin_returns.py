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
    holed = thin_returns.with_no_return({"wall": wall()})["wall"].depth
    regions = np.isinf(holed).all(0)
    seqs, masks = thin_returns.crossed({"wall": wall()}, lines=4, widths=(2.0, 4.0))
    depth, on = seqs["wall"].depth, masks["wall"]
    assert on.any() and np.all(on <= regions)  # inside the benchmark's regions only
    assert np.all(depth[:, on] == 12.0)  # the wall shows through on the lines
    np.testing.assert_array_equal(depth[:, ~on], holed[:, ~on])  # the rest as the benchmark has it


def test_shares_count_each_kind_of_pixel_and_pool_scenes():
    gt = np.full((1, 4, 4), 0.5, np.float32)
    gt[0, 0] = 1.0  # a row of sky
    lines = np.zeros((4, 4), bool)
    lines[1, :2] = True  # two line pixels (gt < 1)
    sr = gt.copy()
    sr[0, 1, 0] = 1.0  # one line pixel dropped
    sr[0, 0, :3] = 0.3  # three of four sky pixels as depth
    sr[0, 3, 3] = np.nan  # one other return lost (NaN is no return)
    one = thin_returns.shares(sr, gt, lines)
    assert one == {"lines": 2, "lines_dropped": 1, "sky": 4, "sky_as_depth": 3, "returns": 10, "returns_dropped": 1}
    # a second scene without lines: pooled by pixels, not averaged by scene (no NaN from its empty lines)
    both = thin_returns.pooled_shares([one, thin_returns.shares(gt, gt, np.zeros((4, 4), bool))])
    assert both["lines_dropped"] == 50.0 and both["line_pixels"] == 2
    assert both["sky_as_depth"] == 100.0 * 3 / 8 and both["returns_dropped"] == 100.0 / 22


def test_the_block_majority_reference_decides_per_block_from_the_truth():
    gt = np.full((1, 8, 8), 0.4, np.float32)
    gt[0, :, :3] = 1.0  # sky on three quarters of the first block column
    out, truth = thin_returns.majority_output(SimpleNamespace(gt=gt, scored=np.array([0])))
    assert np.all(out[0, :, :4] == 1.0)  # the whole block column: no return, a return pixel included
    np.testing.assert_array_equal(out[0, :, 4:], gt[0, :, 4:])
    np.testing.assert_array_equal(truth, gt)
