"""`jaxsr upscale --video / --fps / --reference / --points / --fov / --intrinsics`: a video with one frame per depth
frame, one PLY per frame (or one for the sequence) with one vertex per valid output pixel, all over the sensor's
true range (the gate's start included); nothing is overwritten without --force, and options that need --video say so."""

import json

import imageio_ffmpeg
import jax
import numpy as np
import pytest

from jaxsr import cli, io
from jaxsr.config import Optics, Sensor
from jaxsr.sensor.forward import pixel_rays

SENSOR = Sensor()
# reading a video back starts ffmpeg (fork + exec at once) in a process where JAX runs threads
pytestmark = pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")
T = 3


def upscale(*args):
    return cli.main(["upscale", str(args[0]), "-o", *map(str, args[1:]), "--no-progress"])


def read_ply(path):
    """The vertices of a binary little-endian PLY, parsed by hand."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    assert header[1] == "format binary_little_endian 1.0"
    types = {"float": "<f4", "uchar": "u1", "uint": "<u4"}
    fields = [(line.split()[2], types[line.split()[1]]) for line in header if line.startswith("property")]
    n = int(next(line.split()[2] for line in header if line.startswith("element vertex")))
    vertices = np.frombuffer(data[end:], dtype=fields)
    assert len(vertices) == n
    return vertices


@pytest.fixture(scope="module")
def gated(tmp_path_factory):
    """Histograms of a gate that starts at 100 m (16 bins of 2.1875 m), with a 10 frames/s rate in the metadata."""
    folder = tmp_path_factory.mktemp("gated")
    counts = np.array(jax.random.poisson(jax.random.key(2), 1.5, (T, 32, 64, SENSOR.bins)))
    counts[:, 8:24, 16:48, 5] += 40  # a target at bin 5
    io.write_histograms(folder / "h.npz", counts, sensor=SENSOR, fps=10.0)
    return folder / "h.npz"


@pytest.mark.slow  # 8-10 s on 2 cores: keeps the default suite under 8 minutes
def test_video_and_points_of_a_gated_recording(tmp_path, model_path, gated, capsys):
    gt = np.full((T, 128, 256), 112.0, np.float32)
    gt[:, :10] = np.inf
    np.save(tmp_path / "gt.npy", gt)
    assert upscale(gated, tmp_path / "out.npz", "--model", model_path, "--gate-start", "100m",
                   "--bin-width", "2.1875m", "--video", tmp_path / "v.mp4", "--reference", tmp_path / "gt.npy",
                   "--points", tmp_path / "pts", "--preview", tmp_path / "p.png") == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["video"] == str(tmp_path / "v.mp4") and summary["points"] == str(tmp_path / "pts")
    out = io.read_sequence(tmp_path / "out.npz")["depth"]
    assert out.shape == (T, 128, 256)
    assert imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "v.mp4"))[0] == T
    files = sorted((tmp_path / "pts").iterdir())
    assert [f.name for f in files] == [f"frame_{t:06d}.ply" for t in range(T)]
    dx, dy, _ = (np.asarray(a) for a in pixel_rays(Sensor(optics=Optics.of_hr((128, 256), 1))))
    for f, d in zip(files, out):
        v = read_ply(f)
        valid = np.isfinite(d)
        assert len(v) == valid.sum() > 0
        xyz = np.stack([v["x"], v["y"], v["z"]], -1).astype(np.float64)
        r = np.linalg.norm(xyz, axis=1)
        np.testing.assert_allclose(r, d[valid], rtol=1e-5)
        assert r.min() >= 100.0 - 1e-3  # the true range: the gate's start included
        rows, cols = np.nonzero(valid)
        np.testing.assert_allclose(xyz[:, 0] / xyz[:, 2], dx[cols], rtol=1e-4, atol=1e-6)
        assert {"red", "green", "blue"} <= set(v.dtype.names)


def test_gif_fps_fov_and_no_overwrite(tmp_path, model_path, gated, capsys):
    args = [gated, tmp_path / "out.npy", "--model", model_path, "--video", tmp_path / "v.gif", "--fps", "5",
            "--points", tmp_path / "pts", "--fov", "60", "--points-colour", "none"]
    assert upscale(*args) == 0
    capsys.readouterr()
    assert imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "v.gif"))[0] == T
    meta = next(imageio_ffmpeg.read_frames(str(tmp_path / "v.gif")))
    assert meta["fps"] == pytest.approx(5.0, rel=0.05)
    out = np.load(tmp_path / "out.npy")
    v = read_ply(tmp_path / "pts" / "frame_000000.ply")
    assert v.dtype.names == ("x", "y", "z") and len(v) == np.isfinite(out[0]).sum()
    dx = np.asarray(pixel_rays(Sensor(optics=Optics.of_hr((128, 256), 1, fov_deg=60.0)))[0])
    valid = np.isfinite(out[0])
    np.testing.assert_allclose(v["x"] / v["z"], dx[np.nonzero(valid)[1]], rtol=1e-4, atol=1e-6)
    # the video and the point clouds are never replaced without --force (checked before any work)
    (tmp_path / "out.npy").unlink()
    before = (tmp_path / "v.gif").read_bytes()
    assert upscale(*args) == 2
    assert "--force" in capsys.readouterr().err
    assert (tmp_path / "v.gif").read_bytes() == before and not (tmp_path / "out.npy").exists()
    assert upscale(*args, "--force") == 0


def test_one_point_cloud_file_from_lr_intrinsics_planar_depth_and_opengl_axes(tmp_path, model_path, gated, capsys):
    """--lr-intrinsics of the 32 x 64 sensor, on the 128 x 256 output (x4): fx 4 * 70, fy 4 * 60, cx 4 * (30.5 +
    0.5) - 0.5, cy 4 * (15.5 + 0.5) - 0.5, by the pinhole's X = (u - cx) z / fx, Y = (v - cy) z / fy by hand."""
    assert upscale(gated, tmp_path / "out.npy", "--model", model_path, "--points", tmp_path / "seq.ply",
                   "--lr-intrinsics", "70,60,30.5,15.5", "--points-depth", "planar", "--points-axes", "opengl",
                   "--points-colour", "none") == 0
    assert json.loads(capsys.readouterr().out)["points"] == str(tmp_path / "seq.ply")
    out = np.load(tmp_path / "out.npy")
    v = read_ply(tmp_path / "seq.ply")
    assert v.dtype.names == ("x", "y", "z", "frame")
    np.testing.assert_array_equal(np.bincount(v["frame"], minlength=T), np.isfinite(out).sum(axis=(1, 2)))
    t, rows, cols = np.nonzero(np.isfinite(out))  # the file's order: frame by frame, row-major pixels
    z = out[t, rows, cols].astype(np.float64)
    want = np.stack([(cols - 123.5) * z / 280.0, -(rows - 63.5) * z / 240.0, -z], -1)
    np.testing.assert_allclose(np.stack([v["x"], v["y"], v["z"]], -1), want, rtol=1e-5, atol=1e-5)


def test_default_fps_is_the_recordings(tmp_path, model_path, gated, capsys):
    assert upscale(gated, tmp_path / "o.npy", "--model", model_path, "--video", tmp_path / "v.mp4") == 0
    meta = next(imageio_ffmpeg.read_frames(str(tmp_path / "v.mp4")))
    assert meta["fps"] == pytest.approx(10.0, rel=0.01)


@pytest.mark.parametrize("args,message", [
    (["--fps", "5"], "--fps applies to --video"),
    (["--reference", "gt.npy"], "--reference applies to --video"),
    (["--video", "v.avi"], r"\.mp4 or \.gif"),
    (["--points", "pts", "--fov", "200"], "field of view"),
    (["--points", "pts", "--fov", "30,180"], "field of view"),
    (["--points", "pts", "--fov", "30", "--intrinsics", "400,400,127.5,63.5"],
     "camera is given one way, by --fov, --intrinsics or --lr-intrinsics: got --fov and --intrinsics"),
    (["--points", "p.ply", "--intrinsics", "400,400,1,1", "--lr-intrinsics", "100,100,1,1"], "got --intrinsics and"),
    (["--points", "pts", "--intrinsics=-400,400,127.5,63.5"], r"focal lengths fx, fy must be > 0 pixels, got fx=-400"),
    (["--points", "pts", "--lr-intrinsics", "100,0,31.5,15.5"], r"lr_intrinsics \(--lr-intrinsics\): the focal"),
    (["--fov", "40"], "--fov applies to --points only"),
    (["--intrinsics", "400,400,127.5,63.5"], "--intrinsics applies to --points only"),
    (["--points-axes", "opengl"], "--points-axes applies to --points only"),
    (["--points-depth", "planar"], "--points-depth applies to --points only"),
    (["--video", "v.mp4", "--reference", "missing.npy"], "no such file"),
])
def test_bad_look_options_are_clear_errors(tmp_path, model_path, gated, capsys, args, message):
    args = [str(tmp_path / a) if a.endswith((".npy", ".avi", ".mp4", ".ply")) or a == "pts" else a for a in args]
    assert upscale(gated, tmp_path / "o.npy", "--model", model_path, *args) == 2
    err = capsys.readouterr().err
    assert __import__("re").search(message, err), err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize("flag,value,message", [
    ("--intrinsics", "400,400,127.5", "four numbers fx,fy,cx,cy"),
    ("--lr-intrinsics", "100,100,a,1", "four numbers fx,fy,cx,cy"),
    ("--fov", "30,20,10", "horizontal or horizontal,vertical"),
])
def test_camera_flags_that_do_not_parse_are_one_line(tmp_path, capsys, flag, value, message):
    with pytest.raises(SystemExit) as e:
        upscale(tmp_path / "in.npy", tmp_path / "o.npy", "--points", tmp_path / "pts", flag, value)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err


def test_the_colour_scale_is_the_recordings_depth_range_or_the_one_given(tmp_path, model_path):
    """A scene at 2-5 m: the pictures' scale spans its returns (whole metres), not the 0-35 m gate, unless --vmin /
    --vmax say; a bad colour map or an empty scale is refused before the work."""
    from jaxsr.app import Reading, Writing, prepare_upscale, upscale
    from jaxsr.app.writing import _colour_range

    near = np.random.default_rng(0).uniform(2.2, 4.8, (3, 32, 64)).astype(np.float32)
    job = prepare_upscale(near, model=model_path, read=Reading(units="m"))
    assert job.depth_range() == (2.0, 5.0) and job.d_range == (0.0, 35.0)
    assert _colour_range(job, Writing(preview="p.png")) == (2.0, 5.0)
    assert _colour_range(job, Writing(preview="p.png", vmax=10.0)) == (2.0, 10.0)
    upscale(near, tmp_path / "o.npy", model=model_path, read=Reading(units="m"),
            write=Writing(preview=tmp_path / "p.png", cmap="viridis"))
    assert io.read_image(tmp_path / "p.png").shape[0] > 128  # the panels and the colour bar
    with pytest.raises(ValueError, match="a matplotlib colour map"):
        Writing(cmap="nope")
    with pytest.raises(ValueError, match="vmin .* must be below vmax"):
        Writing(vmin=5.0, vmax=2.0)
