"""Point clouds of depth frames, to look at in 3-D: binary little-endian PLY files that Open3D, trimesh, MeshLab,
CloudCompare and Blender read, one file a frame (a folder) or one file for a whole sequence (a `frame`
property holds each point's frame index).

The camera is a pinhole (`jaxsr.sensor.camera`): intrinsics fx, fy, cx, cy in the frame's pixels, OpenCV's
pixel convention (pixel centres at integer coordinates), or fields of view (default the sensor model's 30
degrees across the width, square pixels, centred: `Intrinsics.from_fov`). Depth is radial range in metres (the
sensor's; the gate's start included) or planar z; points are in metres on OpenCV axes (x right, y down, z
forward) or OpenGL axes (x right, y up, z backward). The maths is `jaxsr.sensor.back_project`, a pure
function of arrays; this module writes its points. No-return pixels (inf, NaN, negative) give no point.

Files are written atomically (`jaxsr.io.files`) and never replace an existing file unless `overwrite=True`; a
folder of point clouds is written into a hidden temporary sibling and appears when every frame is written, and
one file for a sequence is assembled from a temporary file when its last frame is written.
"""

from __future__ import annotations

import contextlib
import functools
import shutil
import tempfile
from pathlib import Path

import numpy as np

from ..config import Sensor
from ..sensor.camera import AXES, DEPTH_KINDS, Intrinsics, as_intrinsics, back_project
from .files import atomic_folder, atomic_path, check_new_file, check_output_folder, refuse_link
from .previews import _colourise

__all__ = ["DEFAULT_FOV_DEG", "points_camera", "depth_points", "write_ply", "write_point_cloud",
           "write_point_clouds", "PointCloudWriter", "check_points", "check_points_folder"]

DEFAULT_FOV_DEG = float(Sensor().fov_deg)  # the sensor model's horizontal field of view, 30 degrees
_PLY_TYPES = {("f", 4): "float", ("u", 1): "uchar", ("u", 4): "uint"}  # (NumPy kind, bytes): PLY's name


def points_camera(shape, *, fov_deg=None, intrinsics=None) -> Intrinsics:
    """The camera of (H, W) frames: `intrinsics` (fx, fy, cx, cy in pixels, checked) or fields of view `fov_deg`
    (horizontal degrees, or (horizontal, vertical); None: `DEFAULT_FOV_DEG`), never both. Returns `Intrinsics`."""
    if intrinsics is not None and fov_deg is not None:
        raise ValueError("give the camera as fields of view (fov_deg) or as intrinsics, not both")
    if intrinsics is not None:
        return as_intrinsics(intrinsics)
    return Intrinsics.from_fov(shape, DEFAULT_FOV_DEG if fov_deg is None else fov_deg)


@functools.lru_cache(maxsize=1)
def _back_project_jit():
    import jax

    return jax.jit(back_project, static_argnames=("depth_kind", "axes"))


def _check_conventions(depth_kind, axes):
    if depth_kind not in DEPTH_KINDS:
        raise ValueError(f"depth_kind: expected one of {', '.join(DEPTH_KINDS)}, got {depth_kind!r}")
    if axes not in AXES:
        raise ValueError(f"axes: expected one of {', '.join(AXES)}, got {axes!r}")


def depth_points(depth, *, fov_deg=None, intrinsics=None, depth_kind: str = "radial", axes: str = "opencv"):
    """The 3-D points of a depth frame: (points (N, 3) float32 x, y, z in metres, valid (H, W) bool).

    depth: (H, W) metres, radial range or planar z (`depth_kind`); inf, NaN or negative is no return and gives
    no point. The camera: `points_camera` (intrinsics, or fields of view; default the sensor model's); axes
    "opencv" or "opengl" (the module's description). Points are in row-major pixel order (`depth[valid]`'s).
    """
    depth = np.asarray(depth, np.float32)
    if depth.ndim != 2:
        raise ValueError(f"expected a depth frame (H, W), got {depth.shape}")
    _check_conventions(depth_kind, axes)
    camera = points_camera(depth.shape, fov_deg=fov_deg, intrinsics=intrinsics)
    valid = np.isfinite(depth) & (depth >= 0)
    points = np.asarray(_back_project_jit()(depth, camera, depth_kind=depth_kind, axes=axes))
    return points[valid], valid


def _vertices(points, colours, frames, what):
    """The structured vertex records: float x, y, z (, uchar red, green, blue) (, uint frame)."""
    points = np.asarray(points, np.float32)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{what}: expected points (N, 3), got {points.shape}")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colours is not None:
        colours = np.asarray(colours)
        if colours.shape != points.shape:
            raise ValueError(f"{what}: colours {colours.shape} != points {points.shape}")
        if colours.dtype != np.uint8:
            colours = (np.clip(colours.astype(np.float64), 0, 1) * 255 + 0.5).astype(np.uint8)
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    if frames is not None:
        frames = np.broadcast_to(np.asarray(frames), (len(points),))
        if not np.issubdtype(frames.dtype, np.integer) or (frames.size and not 0 <= frames.min() <= frames.max()
                                                           < 2**32):
            raise ValueError(f"{what}: expected frame indices (N,) of integers in [0, 2^32), got {frames.dtype}")
        fields += [("frame", "<u4")]
    vertices = np.empty(len(points), dtype=fields)
    for i, name in enumerate("xyz"):
        vertices[name] = points[:, i]
    if colours is not None:
        for i, name in enumerate(("red", "green", "blue")):
            vertices[name] = colours[:, i]
    if frames is not None:
        vertices["frame"] = frames
    return vertices


def _header(dtype, count, comments) -> bytes:
    lines = ["ply", "format binary_little_endian 1.0", *(f"comment {c}" for c in comments),
             f"element vertex {count}",
             *(f"property {_PLY_TYPES[dtype[n].kind, dtype[n].itemsize]} {n}" for n in dtype.names),
             "end_header"]
    return ("\n".join(lines) + "\n").encode("ascii")


def _comments(camera: Intrinsics | None, depth_kind: str, axes: str) -> tuple[str, ...]:
    frame = {"opencv": "x right, y down, z forward", "opengl": "x right, y up, z backward"}[axes]
    out = [f"written by jaxsr: metres, {axes} axes ({frame}), from {depth_kind} depth"]
    if camera is not None:
        out.append("camera fx {:.6g} fy {:.6g} cx {:.6g} cy {:.6g} (pixels, centres at integers)".format(*camera))
    return tuple(out)


def write_ply(path, points, *, colours=None, frames=None, comments=(), overwrite: bool = False) -> None:
    """Write points (N, 3) (and colours (N, 3) uint8 RGB, or floats in [0, 1]; frames (N,) frame indices) as a
    binary little-endian PLY: vertex properties float x, y, z (, uchar red, green, blue) (, uint frame), with
    `comments` (lines of ASCII text) in the header. Atomic; refuses an existing file unless `overwrite`.
    Returns None."""
    vertices = _vertices(points, colours, frames, f"writing {path}")
    comments = tuple(comments)
    if any(not c.isascii() or "\n" in c or "\r" in c for c in comments):
        raise ValueError(f"writing {path}: a PLY comment is one line of ASCII text, got {comments!r}")
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
        f.write(_header(vertices.dtype, len(vertices), comments))
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


def write_point_cloud(path, depth, *, fov_deg=None, intrinsics=None, depth_kind: str = "radial",
                      axes: str = "opencv", colour=None, d_min: float = 0.0, d_max: float = 35.0,
                      cmap: str = "turbo", overwrite: bool = False) -> int:
    """Write one depth frame (H, W) in metres as a PLY point cloud (`depth_points`, `write_ply`).

    The camera (fov_deg or intrinsics), depth_kind and axes: as `depth_points`. colour: None (points only),
    "depth" (the colour map `cmap` from d_min to d_max metres, the sensor's true range), or an (H, W) array in
    [0, 1] (an intensity or confidence, as gray) or (H, W, 3) RGB. Returns the number of points (valid pixels).
    """
    depth = np.asarray(depth, np.float32)
    points, valid = depth_points(depth, fov_deg=fov_deg, intrinsics=intrinsics, depth_kind=depth_kind, axes=axes)
    camera = points_camera(depth.shape, fov_deg=fov_deg, intrinsics=intrinsics)
    write_ply(path, points, colours=_colours(depth, valid, colour, d_min, d_max, cmap),
              comments=_comments(camera, depth_kind, axes), overwrite=overwrite)
    return int(len(points))


def _is_file(spec) -> bool:
    return Path(spec).suffix.lower() == ".ply"


def check_points_folder(spec, *, force: bool, output=None) -> Path:
    """A folder for point clouds: refuses a file, a non-empty folder unless `force`, a symbolic link, a place
    this process cannot write into, and the OUTPUT path. Writes nothing. Returns the path."""
    path = Path(spec)
    if _is_file(path):
        raise ValueError(f"{path}: a folder of point clouds (one .ply per frame) was expected, not one file")
    if output is not None and path.resolve() == Path(output).resolve():
        raise ValueError(f"{path}: the point clouds' folder and OUTPUT are the same")
    refuse_link(path, "the point clouds' folder")
    if path.exists() and not path.is_dir():
        raise FileExistsError(f"{path} is a file; point clouds are written into a folder")
    if path.is_dir() and any(path.iterdir()) and not force:
        raise FileExistsError(f"{path} exists and is not an empty folder; pass --force to write into it")
    check_output_folder(path)
    return path


def check_points(spec, *, force: bool, output=None) -> Path:
    """Where point clouds go: a .ply file (the whole sequence in one file) or a folder (one .ply per frame,
    `check_points_folder`). Refuses an existing file unless `force`, a symbolic link, a place this process cannot
    write into, and the OUTPUT path. Writes nothing. Returns the path."""
    if not _is_file(spec):
        return check_points_folder(spec, force=force, output=output)
    path = Path(spec)
    if output is not None and path.resolve() == Path(output).resolve():
        raise ValueError(f"{path}: the point clouds' file and OUTPUT are the same")
    refuse_link(path, "the point clouds' file")
    if path.is_dir():
        raise IsADirectoryError(f"{path} is a folder; a .ply name writes one file for the whole sequence")
    check_new_file(path, force=force, what="the point clouds' file")
    return path


class PointCloudWriter:
    """Write the point clouds of a depth sequence frame by frame (a context manager; nothing appears unless the
    block ends without an exception). path: a folder (frame_000000.ply ..., one file a frame) or a .ply file (the
    whole sequence, each point with its frame index in a uint `frame` property). The camera, depth_kind, axes
    and colours: as `write_point_cloud`; overwrite: replace the file or write into a non-empty folder (replacing
    files of the same name). `write(depth, colour=None)` writes the next frame and returns its number of points;
    `frames_written` and `points_written` count them."""

    def __init__(self, path, *, fov_deg=None, intrinsics=None, depth_kind: str = "radial", axes: str = "opencv",
                 colour=None, d_min: float = 0.0, d_max: float = 35.0, cmap: str = "turbo",
                 overwrite: bool = False):
        self.path = check_points(path, force=overwrite)
        self.one_file = _is_file(self.path)
        _check_conventions(depth_kind, axes)
        points_camera((4, 4), fov_deg=fov_deg, intrinsics=intrinsics)  # checks the camera now
        self.fov_deg, self.intrinsics, self.depth_kind, self.axes = fov_deg, intrinsics, depth_kind, axes
        self.colour, self.d_min, self.d_max, self.cmap, self.overwrite = colour, d_min, d_max, cmap, overwrite
        self.frames_written, self.points_written = 0, 0
        self._stack = self._tmp = self._body = self._dtype = self._shape = None

    def __enter__(self):
        self._stack = contextlib.ExitStack()
        if self.one_file:
            self._body = self._stack.enter_context(_one_ply(self.path, self.overwrite, self._file_header))
        else:
            self._tmp = self._stack.enter_context(atomic_folder(self.path, replaces=("frame_*.ply",)))
        return self

    def __exit__(self, exc_type, exc, tb):
        stack, self._stack = self._stack, None
        return stack.__exit__(exc_type, exc, tb)

    def write(self, depth, colour=None) -> int:
        if self._stack is None:
            raise RuntimeError("PointCloudWriter.write outside its `with` block")
        colour = self.colour if colour is None else colour
        options = dict(fov_deg=self.fov_deg, intrinsics=self.intrinsics, depth_kind=self.depth_kind, axes=self.axes)
        if not self.one_file:
            n = write_point_cloud(self._tmp / f"frame_{self.frames_written:06d}.ply", depth, colour=colour,
                                  d_min=self.d_min, d_max=self.d_max, cmap=self.cmap, **options)
        else:
            depth = np.asarray(depth, np.float32)
            if self._shape is not None and depth.shape != self._shape:
                raise ValueError(f"{self.path}: frame {self.frames_written} is {depth.shape}, the sequence's first "
                                 f"{self._shape}: one file holds frames of one camera")
            points, valid = depth_points(depth, **options)
            vertices = _vertices(points, _colours(depth, valid, colour, self.d_min, self.d_max, self.cmap),
                                 self.frames_written, f"writing {self.path}")
            if self._dtype is not None and vertices.dtype != self._dtype:
                raise ValueError(f"{self.path}: frame {self.frames_written} has colours where the first frame has "
                                 "none, or none where it has: one file holds one kind of point")
            self._shape, self._dtype = depth.shape, vertices.dtype
            self._body.write(vertices.tobytes())
            n = len(vertices)
        self.frames_written += 1
        self.points_written += n
        return n

    def _file_header(self) -> bytes:
        dtype = self._dtype
        if dtype is None:  # no frame: an empty cloud of the points it would have held
            colours = None if self.colour is None else np.zeros((0, 3), np.uint8)
            dtype = _vertices(np.zeros((0, 3)), colours, np.zeros(0, np.uint32), "").dtype
        camera = None if self._shape is None else points_camera(self._shape, fov_deg=self.fov_deg,
                                                                intrinsics=self.intrinsics)
        comments = _comments(camera, self.depth_kind, self.axes) + (
            "frame: the index of the frame (0, 1, ...) of each point",)
        return _header(dtype, self.points_written, comments)


@contextlib.contextmanager
def _one_ply(path: Path, overwrite: bool, header):
    """Yield a temporary file for the vertex records; when the block succeeds, write `header()` and them into
    `path` atomically (the header states the count of vertices, known only at the end)."""
    with atomic_path(path, overwrite=overwrite) as tmp, tempfile.TemporaryFile(dir=path.parent) as body:
        yield body
        body.seek(0)
        with open(tmp, "wb") as f:
            f.write(header())
            shutil.copyfileobj(body, f, 1 << 20)


def write_point_clouds(path, frames, *, fov_deg=None, intrinsics=None, depth_kind: str = "radial",
                       axes: str = "opencv", colour=None, d_min: float = 0.0, d_max: float = 35.0,
                       cmap: str = "turbo", overwrite: bool = False) -> int:
    """Write a depth sequence as PLY point clouds, streamed: into a folder, frame_000000.ply ... (one file a
    frame), or, where `path` ends in .ply, one file whose points carry their frame index (`PointCloudWriter`).

    frames: (T, H, W) metres, or an iterable of (H, W) frames. The camera (fov_deg or intrinsics), depth_kind and
    axes: as `depth_points`. colour: as `write_point_cloud`, or an iterable of per-frame (H, W) / (H, W, 3)
    arrays. Refuses an existing file or a non-empty folder unless `overwrite`. Returns the number of frames
    written.
    """
    per_frame = colour is not None and not isinstance(colour, str)
    colours = iter(colour) if per_frame else None
    with PointCloudWriter(path, fov_deg=fov_deg, intrinsics=intrinsics, depth_kind=depth_kind, axes=axes,
                          colour=None if per_frame else colour, d_min=d_min, d_max=d_max, cmap=cmap,
                          overwrite=overwrite) as out:
        for depth in frames:
            out.write(depth, None if colours is None else next(colours))
    return out.frames_written
