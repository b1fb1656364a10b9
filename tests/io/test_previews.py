"""Pictures of depth: colour-mapped previews (no return black), comparison strips, grayscale previews."""

import numpy as np
import pytest

from jaxsr import io
from jaxsr.io import previews


def depth_frame(h=32, w=64, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.uniform(0.3, 34.0, (h, w)).astype(np.float32)
    d[0, :3] = np.inf  # no return
    return d


def test_previews(tmp_path):
    d = depth_frame()
    previews.write_preview(tmp_path / "p.png", d)
    img = io.read_image(tmp_path / "p.png")
    assert img.shape == (32, 64, 3)
    np.testing.assert_array_equal(img[0, 0], [0, 0, 0])  # no return is black
    assert img[5, 5].sum() > 0
    lr = np.clip(d[::4, ::4] / 35, 0, 1)
    previews.write_comparison(tmp_path / "c.png", lr, d / 35, gt=d / 35)
    strip = io.read_image(tmp_path / "c.png")
    assert strip.shape == (32 + previews.COLOUR_BAR_HEIGHT, 3 * 64 + 4, 3)  # the colour scale under the panels
    with pytest.raises(ValueError, match="downscale"):
        previews.write_comparison(tmp_path / "c2.png", d[:5, :7], d, gt=d)


def test_normalised_preview_is_the_metres_preview(tmp_path):
    """normalised=True goes through the one normalised -> metres rule: 1.0 (and NaN) black, the rest the same."""
    d = depth_frame()
    norm = np.where(np.isfinite(d), d / 35.0, 1.0).astype(np.float32)
    norm[1, 1] = np.nan
    d[1, 1] = np.inf
    previews.write_preview(tmp_path / "m.png", d)
    previews.write_preview(tmp_path / "n.png", norm, normalised=True)
    m, n = io.read_image(tmp_path / "m.png"), io.read_image(tmp_path / "n.png")
    # the same colour up to the rounding of d / 35 * 35 (at most one 8-bit step)
    assert np.max(np.abs(m - n)) <= 1 / 255 + 1e-6
    np.testing.assert_array_equal(n[[0, 1], [0, 1]], 0.0)


def test_gray_preview_is_8_bit_of_the_clipped_image(tmp_path):
    image = np.linspace(-0.2, 1.2, 16 * 8, dtype=np.float32).reshape(16, 8)
    previews.write_gray_preview(tmp_path / "g.png", image)
    back = io.read_image(tmp_path / "g.png")
    assert back.shape == (16, 8, 1)
    np.testing.assert_array_equal(np.rint(back[..., 0] * 255), np.rint(np.clip(image, 0, 1) * 255))
    with pytest.raises(FileExistsError):
        previews.write_gray_preview(tmp_path / "g.png", image)
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        previews.write_gray_preview(tmp_path / "h.png", np.zeros((2, 3, 3)))
