"""Point clouds of depth frames, to look at in 3-D: binary little-endian PLY files (one per frame) that Open3D,
MeshLab, CloudCompare and Blender read.

The camera is the sensor model's (`jaxsr.sensor.forward.pixel_rays`, docs/sensor-model.md): a pinhole camera
with square pixels whose horizontal field of view is `fov_deg` (default the sensor's 30 degrees) across the
frame's width W, focal length f = (W / 2) / tan(fov / 2) pixels, and rays through the pixel centres
(col + 0.5, row + 0.5). Depth is radial range r in metres (the true range from the sensor, the gate's start
included), so a pixel's point is r D / |D| with D = ((col + 0.5 - W / 2) / f, -(row + 0.5 - H / 2) / f, 1):
x right, y up, z forward (along the optical axis), in metres. No-return pixels (inf, NaN, negative) are left out.

Files are written atomically (`jaxsr.io.files`) and never replace an existing file unless `overwrite=True`; a
folder of point clouds is written into a hidden temporary sibling and appears when every frame is written.
"""

from __future__ import annotations

import contextlib
import functools
from pathlib import Path

import numpy as np

from ..config import SensorConfig
from .files import atomic_folder, atomic_path, check_output_folder, refuse_link
from .previews import _colourise

__all__ = ["DEFAULT_FOV_DEG", "depth_points", "write_ply", "write_point_cloud", "write_point_clouds",
           "PointCloudWriter", "check_points_folder"]

DEFAULT_FOV_DEG = float(SensorConfig().fov_deg)  # the sensor model's horizontal field of view, 30 degrees


@functools.lru_cache(maxsize=8)
def _unit_rays(shape, fov_deg):
    """(H, W, 3) float64 unit ray directions of the pixel centres (`jaxsr.sensor.forward.pixel_rays`), read-only
    (kept for the next frame of the same size)."""
    from ..sensor.forward import pixel_rays

    fov_deg = float(fov_deg)
    if not (0 < fov_deg < 180):
        raise ValueError(f"fov_deg: expected a horizontal field of view in (0, 180) degrees, got {fov_deg}")
    dx, dy, norm = (np.asarray(a, np.float64) for a in pixel_rays(SensorConfig(hr_shape=tuple(shape), scale=1,
                                                                                fov_deg=fov_deg)))
    h, w = shape
    d = np.stack([np.broadcast_to(dx[None, :], (h, w)), np.broadcast_to(dy[:, None], (h, w)), np.ones((h, w))], -1)
    rays = d / norm[..., None]
    rays.flags.writeable = False
    return rays


def depth_points(depth, *, fov_deg: float = DEFAULT_FOV_DEG):
    """The 3-D points of a depth frame: (points (N, 3) float32 x, y, z in metres, valid (H, W) bool).

    depth: (H, W) radial range in metres; inf, NaN or negative is no return and gives no point. Points are in
    row-major pixel order (`depth[valid]`'s order). The camera: see the module's description.
    """
    depth = np.asarray(depth, np.float64)
    if depth.ndim != 2:
        raise ValueError(f"expected a depth frame (H, W), got {depth.shape}")
    valid = np.isfinite(depth) & (depth >= 0)
    rays = _unit_rays(tuple(depth.shape), float(fov_deg))
    return (rays[valid] * depth[valid][:, None]).astype(np.float32), valid


def write_ply(path, points, *, colours=None, overwrite: bool = False) -> None:
    """Write points (N, 3) (and colours (N, 3) uint8 RGB, or floats in [0, 1]) as a binary little-endian PLY:
    vertex properties float x, y, z (and uchar red, green, blue). Atomic; refuses an existing file unless
    `overwrite`."""
    points = np.asarray(points, np.float32)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"writing {path}: expected points (N, 3), got {points.shape}")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colours is not None:
        colours = np.asarray(colours)
        if colours.shape != points.shape:
            raise ValueError(f"writing {path}: colours {colours.shape} != points {points.shape}")
        if colours.dtype != np.uint8:
            colours = (np.clip(colours.astype(np.float64), 0, 1) * 255 + 0.5).astype(np.uint8)
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    vertices = np.empty(len(points), dtype=fields)
    for i, name in enumerate("xyz"):
        vertices[name] = points[:, i]
    if colours is not None:
        for i, name in enumerate(("red", "green", "blue")):
            vertices[name] = colours[:, i]
    types = {"<f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0", "comment written by jaxsr: x right, y up, z forward, metres",
              f"element vertex {len(points)}", *(f"property {types[t]} {n}" for n, t in fields), "end_header"]
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(vertices.tobytes())


def _colours(depth, valid, colour, d_min, d_max, cmap):
    """(N, 3) colours of the valid pixels: None, "depth" (the colour map from d_min to d_max metres), or an
    (H, W) value in [0, 1] (intensity, confidence: gray) or (H, W, 3) RGB."""
    if colour is None:
        return None
    if isinstance(colour, str):
        if colour != "depth":
            raise ValueError(f"colour: None, 'depth' or an (H, W) / (H, W, 3) array, got {colour!r}")
        return _colourise(depth, d_min, d_max, cmap)[valid]
    colour = np.asarray(colour)
    if colour.shape[:2] != depth.shape or colour.ndim not in (2, 3) or (colour.ndim == 3 and colour.shape[2] != 3):
        raise ValueError(f"colour: expected (H, W) or (H, W, 3) like the depth {depth.shape}, got {colour.shape}")
    if colour.ndim == 2:
        colour = np.repeat(colour[..., None], 3, axis=-1)
    return colour[valid]


def write_point_cloud(path, depth, *, fov_deg: float = DEFAULT_FOV_DEG, colour=None, d_min: float = 0.0,
                      d_max: float = 35.0, cmap: str = "turbo", overwrite: bool = False) -> int:
    """Write one depth frame (H, W) of radial metres as a PLY point cloud (`depth_points`, `write_ply`).

    colour: None (points only), "depth" (the colour map `cmap` from d_min to d_max metres, the sensor's true
    range), or an (H, W) array in [0, 1] (an intensity or confidence, as gray) or (H, W, 3) RGB.
    Returns the number of points (the valid pixels).
    """
    depth = np.asarray(depth, np.float32)
    points, valid = depth_points(depth, fov_deg=fov_deg)
    write_ply(path, points, colours=_colours(depth, valid, colour, d_min, d_max, cmap), overwrite=overwrite)
    return int(len(points))


def check_points_folder(spec, *, force: bool, output=None) -> Path:
    """A folder for point clouds: refuses a file, a non-empty folder unless `force`, a symbolic link, a place
    this process cannot write into, and the OUTPUT path. Writes nothing. Returns the path."""
    path = Path(spec)
    if path.suffix.lower() == ".ply":
        raise ValueError(f"{path}: point clouds are written into a folder (one .ply per frame), not one file")
    if output is not None and path.resolve() == Path(output).resolve():
        raise ValueError(f"{path}: the point clouds' folder and OUTPUT are the same")
    refuse_link(path, "the point clouds' folder")
    if path.exists() and not path.is_dir():
        raise FileExistsError(f"{path} is a file; point clouds are written into a folder")
    if path.is_dir() and any(path.iterdir()) and not force:
        raise FileExistsError(f"{path} exists and is not an empty folder; pass --force to write into it")
    check_output_folder(path)
    return path


class PointCloudWriter:
    """Write a folder of point clouds frame by frame, frame_000000.ply ... (a context manager; the folder appears
    when the block ends without an exception). Options as `write_point_cloud`; overwrite: write into a non-empty
    folder (replacing files of the same name). `write(depth, colour=None)` writes the next frame and returns
    its number of points; `frames_written` counts the frames."""

    def __init__(self, folder, *, fov_deg: float = DEFAULT_FOV_DEG, colour=None, d_min: float = 0.0,
                 d_max: float = 35.0, cmap: str = "turbo", overwrite: bool = False):
        self.folder = check_points_folder(folder, force=overwrite)
        _unit_rays((4, 4), float(fov_deg))  # checks the field of view now
        self.fov_deg, self.colour, self.d_min, self.d_max, self.cmap = float(fov_deg), colour, d_min, d_max, cmap
        self.frames_written, self.points_written = 0, 0
        self._stack = None
        self._tmp = None

    def __enter__(self):
        self._stack = contextlib.ExitStack()
        self._tmp = self._stack.enter_context(atomic_folder(self.folder, replaces=("frame_*.ply",)))
        return self

    def __exit__(self, exc_type, exc, tb):
        return self._stack.__exit__(exc_type, exc, tb)

    def write(self, depth, colour=None) -> int:
        if self._tmp is None:
            raise RuntimeError("PointCloudWriter.write outside its `with` block")
        colour = self.colour if colour is None else colour
        n = write_point_cloud(self._tmp / f"frame_{self.frames_written:06d}.ply", depth, fov_deg=self.fov_deg,
                              colour=colour, d_min=self.d_min, d_max=self.d_max, cmap=self.cmap)
        self.frames_written += 1
        self.points_written += n
        return n


def write_point_clouds(folder, frames, *, fov_deg: float = DEFAULT_FOV_DEG, colour=None, d_min: float = 0.0,
                       d_max: float = 35.0, cmap: str = "turbo", overwrite: bool = False) -> int:
    """Write a depth sequence as a folder of PLY point clouds, frame_000000.ply ... (one per frame, streamed).

    frames: (T, H, W) radial metres, or an iterable of (H, W) frames. colour: as `write_point_cloud`, or an
    iterable of per-frame (H, W) / (H, W, 3) arrays. Refuses a non-empty folder unless `overwrite`.
    Returns the number of frames written.
    """
    per_frame = colour is not None and not isinstance(colour, str)
    colours = iter(colour) if per_frame else None
    with PointCloudWriter(folder, fov_deg=fov_deg, colour=None if per_frame else colour, d_min=d_min,
                          d_max=d_max, cmap=cmap, overwrite=overwrite) as out:
        for depth in frames:
            out.write(depth, None if colours is None else next(colours))
    return out.frames_written
