"""Depth videos (`jaxsr.io.write_depth_video`): as many video frames as depth frames, in MP4 and GIF; one colour
scale over the true range; no return black; atomic, no overwrite without asking."""

import imageio_ffmpeg
import matplotlib
import numpy as np
import pytest

from jaxsr import io
from jaxsr.io.video import DepthVideoWriter

# reading a video back starts ffmpeg (fork + exec at once) in a process where JAX runs threads
pytestmark = pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")


def frames(t=5, start=0.0):
    """(lr (t, 8, 16), sr (t, 32, 64), gt) in metres from `start`, with no-return pixels."""
    rng = np.random.default_rng(0)
    sr = (start + rng.uniform(1.0, 34.0, (t, 32, 64))).astype(np.float32)
    sr[:, :4] = np.inf
    sr[:, 4:8, :8] = np.nan
    return sr[:, ::4, ::4], sr, sr + 0.5


def video_frames(path):
    """Every frame of a video, decoded by ffmpeg: (n, height, width, 3) uint8."""
    gen = imageio_ffmpeg.read_frames(str(path))
    meta = gen.__next__()
    w, h = meta["size"]
    return np.stack([np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in gen])


@pytest.mark.parametrize("suffix", [".mp4", ".gif"])
def test_one_video_frame_per_depth_frame(tmp_path, suffix):
    lr, sr, gt = frames(7)
    path = tmp_path / f"v{suffix}"
    assert io.write_depth_video(path, lr, sr, gt, fps=10) == 7
    decoded = video_frames(path)
    assert decoded.shape[0] == 7
    assert imageio_ffmpeg.count_frames_and_secs(str(path))[0] == 7
    # two panels from iterables (streamed), the frame count unknown
    assert io.write_depth_video(tmp_path / f"w{suffix}", iter(lr), (f for f in sr)) == 7
    assert video_frames(tmp_path / f"w{suffix}").shape[0] == 7


def test_frame_colours_span_the_true_range(tmp_path):
    """Panels share one colour scale from d_min to d_max metres (a gate starting at 776 m); no return is black;
    the input is nearest-neighbour upscaled."""
    lr, sr, gt = frames(1, start=776.0)
    writer = DepthVideoWriter(tmp_path / "x.mp4", (32, 64), labels=("in", "out", "ref"), d_min=776.0, d_max=811.0,
                              zoom=2)
    img = writer.frame(lr[0], sr[0], gt[0])
    assert img.dtype == np.uint8 and img.shape[0] % 16 == 0 and img.shape[1] % 16 == 0
    turbo = matplotlib.colormaps["turbo"]
    for (x, y), panel in zip(writer._panel_xy, (np.repeat(np.repeat(lr[0], 4, 0), 4, 1), sr[0], gt[0])):
        r, c = 20, 30
        want = np.round(np.asarray(turbo((panel[r, c] - 776.0) / 35.0)[:3]) * 255)
        np.testing.assert_allclose(img[y + 2 * r, x + 2 * c], want, atol=1)
        assert np.all(img[y, x] == 0)  # row 0: no return (inf)
        assert np.all(img[y + 2 * 5, x + 2 * 2] == 0)  # NaN: no return
    assert not (tmp_path / "x.mp4").exists()  # nothing written outside a `with` block


def test_no_overwrite_and_nothing_left_on_failure(tmp_path):
    lr, sr, gt = frames(3)
    path = tmp_path / "v.mp4"
    path.write_bytes(b"keep me")
    with pytest.raises(FileExistsError):
        io.write_depth_video(path, lr, sr)
    assert path.read_bytes() == b"keep me"
    assert io.write_depth_video(path, lr, sr, overwrite=True) == 3
    with pytest.raises(ValueError, match="differ in length"):
        io.write_depth_video(tmp_path / "bad.mp4", lr, sr[:2])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]
    with pytest.raises(ValueError, match=r"\.mp4 or \.gif"):
        io.write_depth_video(tmp_path / "v.avi", lr, sr)
    with pytest.raises(FileExistsError):
        io.check_video(path, force=False)


def test_previews_span_the_true_range(tmp_path):
    """A gated recording's preview: colours from the gate's start (d_min) to start + span, in metres or
    normalised on that scale alike."""
    d = np.full((8, 16), 776.0 + 17.5, np.float32)
    d[0] = np.inf
    io.write_comparison(tmp_path / "m.png", d[::4, ::4], d, d_min=776.0, d_max=811.0, labels=())
    io.write_comparison(tmp_path / "n.png", np.full((2, 4), 0.5), np.where(np.isfinite(d), 0.5, 1.0),
                        d_min=776.0, d_max=811.0, labels=())
    want = np.round(np.asarray(matplotlib.colormaps["turbo"](0.5)[:3]) * 255)
    for name in ("m.png", "n.png"):
        img = np.round(np.asarray(io.read_image(tmp_path / name), np.float64) * 255)
        np.testing.assert_allclose(img[6, 20], want, atol=1)  # the output panel, a return at mid-range
        assert np.all(img[0, 20] == 0)  # no return: black
    with pytest.raises(ValueError, match="d_min < d_max"):
        io.write_preview(tmp_path / "x.png", d, d_min=40.0, d_max=35.0)


@pytest.mark.parametrize("suffix", [".mp4", ".gif"])
def test_an_interrupted_video_reports_the_interrupt_and_leaves_nothing(tmp_path, suffix, caplog):
    """Ctrl-C before (or between) frames: the KeyboardInterrupt goes on (the command's exit 130), not "no frames to
    write" (exit 2), with no word of imageio-ffmpeg's and no file."""
    path = tmp_path / f"v{suffix}"
    with pytest.raises(KeyboardInterrupt):
        with DepthVideoWriter(path, (32, 64), labels=("in", "out"), frames=3):
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []
    assert "No frames have been written" not in caplog.text
