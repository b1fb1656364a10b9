"""PLY point clouds (`jaxsr.io.write_point_cloud(s)`): parsed back by a small independent reader of the PLY
grammar, one vertex per valid pixel on the camera's rays (the sensor model's by default, or intrinsics), radial or
planar depth preserved, OpenCV or OpenGL axes, one file a frame or one file for a sequence with a frame index."""

import numpy as np
import pytest

from jaxsr import io
from jaxsr.config import Optics, Sensor
from jaxsr.sensor import Intrinsics
from jaxsr.sensor.forward import pixel_rays

PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "<i2", "ushort": "<u2", "int": "<i4", "uint": "<u4",
             "float": "<f4", "double": "<f8", "int8": "i1", "uint8": "u1", "int16": "<i2", "uint16": "<u2",
             "int32": "<i4", "uint32": "<u4", "float32": "<f4", "float64": "<f8"}


def read_ply(path):
    """(header lines, structured vertex array) of a binary little-endian PLY, read as the PLY grammar says: magic,
    format, comment / obj_info lines, elements with their scalar properties, end_header, then the records; a
    trailing or missing byte is an error, as in Open3D's and trimesh's readers."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").split("\n")[:-1]
    assert header[0] == "ply" and header[1] == "format binary_little_endian 1.0", header[:2]
    elements = []
    for line in header[2:-1]:
        words = line.split()
        if words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "element":
            assert len(words) == 3 and words[2].isdigit(), line
            elements.append((words[1], int(words[2]), []))
        else:
            assert words[0] == "property" and len(words) == 3 and words[1] in PLY_TYPES and elements, line
            elements[-1][2].append((words[2], PLY_TYPES[words[1]]))
    assert header[-1] == "end_header"
    assert [e[0] for e in elements] == ["vertex"]
    _, n, fields = elements[0]
    dtype = np.dtype(fields)
    assert len(data) - end == n * dtype.itemsize, "the records do not match the header's count"
    return header, np.frombuffer(data[end:], dtype=dtype)


def xyz(v):
    return np.stack([v["x"], v["y"], v["z"]], -1).astype(np.float64)


def depth(h=16, w=32, start=0.0):
    rng = np.random.default_rng(1)
    d = (start + rng.uniform(1.0, 30.0, (h, w))).astype(np.float32)
    d[0] = np.inf
    d[1, :5] = np.nan
    return d


@pytest.mark.parametrize("fov", [30.0, 60.0])
def test_one_vertex_per_valid_pixel_on_the_sensor_rays(tmp_path, fov):
    d = depth(start=776.0)  # a gated recording: the true range, gate start included
    valid = np.isfinite(d)
    n = io.write_point_cloud(tmp_path / "p.ply", d, fov_deg=fov)
    header, v = read_ply(tmp_path / "p.ply")
    assert n == len(v) == valid.sum()
    p = xyz(v)
    np.testing.assert_allclose(np.linalg.norm(p, axis=1), d[valid], rtol=1e-6)  # radial metres
    dx, dy, _ = (np.asarray(a) for a in pixel_rays(Sensor(optics=Optics.of_hr(d.shape, 1, fov_deg=fov))))
    rows, cols = np.nonzero(valid)
    # OpenCV axes: the sensor model's rays with y down (pixel_rays' y is up)
    np.testing.assert_allclose(p[:, 0] / p[:, 2], dx[cols], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(p[:, 1] / p[:, 2], -dy[rows], rtol=1e-5, atol=1e-6)
    assert np.all(p[:, 2] > 0) and np.all(p[rows < d.shape[0] // 2, 1] < 0)  # the top rows above: y < 0
    assert any("opencv axes (x right, y down, z forward)" in line for line in header)


def test_intrinsics_planar_depth_and_opengl_axes(tmp_path):
    """Points against the pinhole by hand: u, v the column and row, X = (u - cx) z / fx, Y = (v - cy) z / fy."""
    d = depth(8, 12)
    cam = Intrinsics(fx=9.0, fy=7.0, cx=4.0, cy=5.5)
    io.write_point_cloud(tmp_path / "p.ply", d, intrinsics=cam, depth_kind="planar", axes="opengl")
    header, v = read_ply(tmp_path / "p.ply")
    rows, cols = np.nonzero(np.isfinite(d))
    z = d[rows, cols].astype(np.float64)
    want = np.stack([(cols - 4.0) * z / 9.0, -(rows - 5.5) * z / 7.0, -z], -1)  # OpenGL: y up, z backward
    np.testing.assert_allclose(xyz(v), want, rtol=1e-6, atol=1e-6)
    assert "comment camera fx 9 fy 7 cx 4 cy 5.5 (pixels, centres at integers)" in header
    with pytest.raises(ValueError, match="not both"):
        io.write_point_cloud(tmp_path / "q.ply", d, intrinsics=cam, fov_deg=30.0)
    with pytest.raises(ValueError, match="focal lengths fx, fy must be > 0"):
        io.write_point_cloud(tmp_path / "q.ply", d, intrinsics=(0.0, 7.0, 4.0, 5.5))
    assert not (tmp_path / "q.ply").exists()


def test_colours_and_default_fov(tmp_path):
    d = depth()
    io.write_point_cloud(tmp_path / "c.ply", d, colour="depth")
    header, v = read_ply(tmp_path / "c.ply")
    assert {"property uchar red", "property uchar green", "property uchar blue"} <= set(header)
    assert io.DEFAULT_FOV_DEG == Sensor().fov_deg == 30.0
    gray = np.linspace(0, 1, d.size).reshape(d.shape)
    io.write_point_cloud(tmp_path / "g.ply", d, colour=gray)
    _, g = read_ply(tmp_path / "g.ply")
    np.testing.assert_array_equal(g["red"], np.round(gray[np.isfinite(d)] * 255).astype(np.uint8))


def test_folder_of_point_clouds(tmp_path):
    seq = np.stack([depth(), depth() + 1])
    assert io.write_point_clouds(tmp_path / "pts", seq) == 2
    files = sorted((tmp_path / "pts").iterdir())
    assert [f.name for f in files] == ["frame_000000.ply", "frame_000001.ply"]
    for f, d in zip(files, seq):
        _, v = read_ply(f)
        np.testing.assert_allclose(np.linalg.norm(xyz(v), axis=1), d[np.isfinite(d)], rtol=1e-6)
    with pytest.raises(FileExistsError):
        io.write_point_clouds(tmp_path / "pts", seq)
    with pytest.raises(FileExistsError):
        io.write_point_cloud(files[0], seq[0])
    with pytest.raises(ValueError, match="field of view"):
        io.write_point_clouds(tmp_path / "bad", seq, fov_deg=180)
    assert not (tmp_path / "bad").exists()


def test_one_file_for_a_sequence_holds_each_points_frame(tmp_path):
    seq = np.stack([depth(), depth() + 1, depth() + 2])
    seq[1, 3:6] = np.inf  # frames of different counts
    assert io.write_point_clouds(tmp_path / "seq.ply", seq, colour="depth") == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq.ply"]  # no temporary left beside it
    header, v = read_ply(tmp_path / "seq.ply")
    assert header[-2:] == ["property uint frame", "end_header"]
    counts = np.isfinite(seq).sum(axis=(1, 2))
    np.testing.assert_array_equal(np.bincount(v["frame"]), counts)
    for t, d in enumerate(seq):  # the same points as that frame's own file, in pixel order
        io.write_point_cloud(tmp_path / f"f{t}.ply", d, colour="depth")
        _, own = read_ply(tmp_path / f"f{t}.ply")
        mine = v[v["frame"] == t]
        np.testing.assert_array_equal(xyz(mine), xyz(own))
        np.testing.assert_array_equal(mine["red"], own["red"])
    with pytest.raises(FileExistsError):
        io.write_point_clouds(tmp_path / "seq.ply", seq)
    assert io.write_point_clouds(tmp_path / "seq.ply", seq[:1], overwrite=True) == 1
    assert set(read_ply(tmp_path / "seq.ply")[1]["frame"]) == {0}


def test_one_file_refuses_a_frame_of_another_camera_and_leaves_nothing(tmp_path):
    with pytest.raises(ValueError, match=r"frame 1 is \(8, 16\), the sequence's first \(16, 32\)"):
        io.write_point_clouds(tmp_path / "seq.ply", [depth(), depth(8, 16)])
    with pytest.raises(ValueError, match="frame 1 has colours where the first frame has none"):
        with io.PointCloudWriter(tmp_path / "seq.ply") as out:
            out.write(depth())
            out.write(depth(), colour=np.zeros((16, 32)))
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "a_folder.ply").mkdir()
    with pytest.raises(IsADirectoryError, match="a .ply name writes one file"):
        io.write_point_clouds(tmp_path / "a_folder.ply", [depth()])
