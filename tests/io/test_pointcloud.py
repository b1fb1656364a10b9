"""PLY point clouds (`jaxsr.io.write_point_cloud(s)`): parsed back by hand, one vertex per valid pixel, the
sensor model's camera (`pixel_rays`), radial range preserved, binary little endian."""

import numpy as np
import pytest

from jaxsr import io
from jaxsr.config import SensorConfig
from jaxsr.sensor.forward import pixel_rays


def read_ply(path):
    """(header lines, structured vertex array) of a binary little-endian PLY holding only vertices."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    assert header[0] == "ply" and header[1] == "format binary_little_endian 1.0"
    n = int(next(line.split()[2] for line in header if line.startswith("element vertex")))
    types = {"float": "<f4", "uchar": "u1"}
    fields = [(line.split()[2], types[line.split()[1]]) for line in header if line.startswith("property")]
    vertices = np.frombuffer(data[end:], dtype=fields)
    assert len(vertices) == n
    return header, vertices


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
    _, v = read_ply(tmp_path / "p.ply")
    assert n == len(v) == valid.sum()
    xyz = np.stack([v["x"], v["y"], v["z"]], -1).astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(xyz, axis=1), d[valid], rtol=1e-6)  # radial metres
    dx, dy, _ = (np.asarray(a) for a in pixel_rays(SensorConfig(hr_shape=d.shape, scale=1, fov_deg=fov)))
    rows, cols = np.nonzero(valid)
    np.testing.assert_allclose(xyz[:, 0] / xyz[:, 2], dx[cols], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(xyz[:, 1] / xyz[:, 2], dy[rows], rtol=1e-5, atol=1e-6)
    # the horizontal field of view spans the frame's width: the edge pixels' centres half a pixel inside it
    f = (d.shape[1] / 2) / np.tan(np.radians(fov) / 2)
    assert dx[0] == pytest.approx(-(d.shape[1] / 2 - 0.5) / f, rel=1e-6)
    assert np.all(xyz[:, 2] > 0)


def test_colours_and_default_fov(tmp_path):
    d = depth()
    io.write_point_cloud(tmp_path / "c.ply", d, colour="depth")
    header, v = read_ply(tmp_path / "c.ply")
    assert {"property uchar red", "property uchar green", "property uchar blue"} <= set(header)
    assert io.DEFAULT_FOV_DEG == SensorConfig().fov_deg == 30.0
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
        np.testing.assert_allclose(np.linalg.norm(np.stack([v["x"], v["y"], v["z"]], -1), axis=1),
                                   d[np.isfinite(d)], rtol=1e-6)
    with pytest.raises(FileExistsError):
        io.write_point_clouds(tmp_path / "pts", seq)
    with pytest.raises(FileExistsError):
        io.write_point_cloud(files[0], seq[0])
    with pytest.raises(ValueError, match="field of view"):
        io.write_point_clouds(tmp_path / "bad", seq, fov_deg=180)
    assert not (tmp_path / "bad").exists()
