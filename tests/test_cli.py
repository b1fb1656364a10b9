"""The `jaxsr simulate` command on a tiny case (3 frames) and its user errors."""

import json

import numpy as np
import pytest

from jaxsr import cli, io


def test_simulate_scene(tmp_path, capsys):
    out = tmp_path / "sim"
    rc = cli.main(["simulate", "--kind", "walkers", "--frames", "3", "--fps", "25", "--snr", "1.3", "--seed", "0",
                   "--out", str(out)])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["counts_shape"] == [3, 32, 64, 16] and summary["snr"] == 1.3
    h = io.read_histograms(out / "histograms.npz")
    assert h["counts"].shape == (3, 32, 64, 16) and h["depth"].shape == (3, 128, 256)
    assert h["config"]["bins"] == 16 and h["metadata"]["kind"] == "walkers"
    com = np.load(out / "com_depth.npy")
    assert com.shape == (3, 32, 64) and 0 <= com.min() and com.max() <= 1
    gt = np.load(out / "gt_depth.npy")
    # The centre-of-mass depth follows the ground truth where there is a return (coarse check, 16 bins).
    gt_lr = np.clip(gt.reshape(3, 32, 4, 64, 4).mean((2, 4)) / 35.0, 0, 1)
    assert np.median(np.abs(com - gt_lr)[gt_lr < 0.9]) < 0.1
    for name in ("preview_gt.png", "preview_com.png", "preview_intensity.png"):
        assert io.read_image(out / name).shape[:2] in {(128, 256), (32, 64)}
    assert io.read_image(out / "preview_strip.png").shape[:2] == (128, 3 * 256 + 4)
    # The reported baseline score is the PSNR of bicubic(centre of mass) against the normalised ground truth.
    from jaxsr import bicubic, normalise_depth, psnr

    want = float(np.mean(psnr(bicubic(com, scale=4), normalise_depth(gt))))
    assert summary["bicubic_psnr_db"] == pytest.approx(want, abs=0.01)
    # A second run refuses to overwrite, then overwrites with --force.
    assert cli.main(["simulate", "--kind", "walkers", "--frames", "3", "--out", str(out)]) == 2
    assert "--force" in capsys.readouterr().err
    assert cli.main(["simulate", "--kind", "walkers", "--frames", "3", "--out", str(out), "--force"]) == 0


def test_simulate_missing_input_is_a_clear_error(tmp_path, capsys):
    assert cli.main(["simulate", "--input", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    assert "airsim_rec.txt" in capsys.readouterr().err


def test_parser_needs_a_command():
    with pytest.raises(SystemExit):
        cli.main([])
