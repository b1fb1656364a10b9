"""The held-out scenes: public third-party depth (and the colour image beside it) that jaxsr's scene generator did
not make and training never sees, read from the fetched repositories and written as jaxsr's HR frames (128 x 256
radial metres + intensity in [0, 1]) into a data folder outside the repository (`prepare`), and read back
(`load_scenes`).

Each set (`SETS`) names its repository, the commit its files are read at, their paths, licence and units. A
source folder is either a bare git mirror of the repository (read at the commit with `git show`) or a checkout
holding the same paths. What is done to every set:
- depth to metres by the source's own rule (`Source.depth`), missing pixels (0: no measurement, a Kinect's holes)
  filled from the nearest measured pixel: they are no lack of a return, a real lidar would see a surface there;
- planar z-buffers to radial range with the source camera's intrinsics (`to_radial`); range is what a dToF pixel
  measures;
- the central rows cropped to 2:1 and resampled to 256 x 128: depth by the nearest source pixel (averaging would
  invent depths between a foreground edge and its background), intensity (the grey level of the colour image,
  ITU-R 601) by the mean over each HR pixel's footprint;
- static sets repeated over `static_frames` frames (a still camera; the photons of each frame drawn apart when
  scored); videos kept as their frames.
"""

from __future__ import annotations

import dataclasses
import io
import json
import subprocess
from pathlib import Path
from types import SimpleNamespace
from typing import Callable

import numpy as np
from PIL import Image

from jaxsr.config import DEFAULT_MEAN_SIGNAL, Sensor
from jaxsr.io.files import atomic_path, write_text_atomic

DEFAULT_DATA = Path.home() / ".cache" / "jaxsr" / "heldout"
STATIC_FRAMES = 30  # frames of a static set: as many as the video's, so every scene scores the same frames
STATIC_FPS = 30.0
# Open3D's PrimeSenseDefault (fx, fy, cx, cy at 640 x 480), the intrinsics its RGBD tutorials give these Kinect-class
# frames; each sensor's own differ by about 1 % (TUM fr1: 517.3, 516.5, 318.6, 255.3)
KINECT = (525.0, 525.0, 319.5, 239.5)
OPEN3D = "isl-org/Open3D"
OPEN3D_COMMIT = "3f9bdc102091bf884be56335d374b68c6951681c"  # the last with examples/test_data/RGBD
OPEN3D_RGBD = "examples/test_data/RGBD/other_formats"
STDNET = "yanzq95/STDNet"
STDNET_COMMIT = "c55f06c31f953b4c9208fea31582acd9f11b7664"
DYDTOF = "dataset/DyDToF/DyDToF_HR_RGB/school/school_shot8"


FIRST = ((3.0, 14.0), (1.3, 0.3, 0.1))  # the regimes the issue measured the gap in, run first


def regimes(photons, snrs, paper: bool = True, first: bool = True) -> list:
    """[(photons, snr)]: the issue's regimes (`FIRST`: 3 and 14 photons at SNR 1.3, 0.3 and 0.1) first (unless
    not `first`), then the rest of the grid `photons` x `snrs`, then the paper's (snr None)."""
    first = [(p, s) for p in FIRST[0] for s in FIRST[1]] if first else []
    grid = [(float(p), float(s)) for p in photons for s in snrs]
    return first + [r for r in grid if r not in first] + ([(DEFAULT_MEAN_SIGNAL, None)] if paper else [])


def _png16(data: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(data)), dtype=np.float64)


def nyu_metres(data: bytes) -> np.ndarray:
    """NYU Depth V2 raw Kinect disparity (a 16-bit PGM whose bytes are little-endian, as Open3D's
    CreateFromNYUFormat swaps them) -> metres, 351.3 / (1092.5 - d); 2047 and above: no measurement (0)."""
    raw = np.asarray(Image.open(io.BytesIO(data)), dtype=np.int64)
    raw = ((raw & 0xFF) << 8) | (raw >> 8)  # PIL reads PGM big-endian
    depth = 351.3 / (1092.5 - raw.astype(np.float64))
    return np.where((raw < 2047) & (depth > 0), depth, 0.0)


def tum_metres(data: bytes) -> np.ndarray:
    """TUM RGB-D depth PNG: 5000 units per metre; 0 no measurement."""
    return _png16(data) / 5000.0


def sun_metres(data: bytes) -> np.ndarray:
    """SUN RGB-D / SUN3D depth PNG: the 16 bits rotated right by 3 (`depthRead.m`), millimetres; 0 no measurement."""
    raw = np.asarray(Image.open(io.BytesIO(data)), dtype=np.uint16)
    return ((raw >> 3) | (raw << 13)).astype(np.float64) / 1000.0


def npy_metres(data: bytes) -> np.ndarray:
    """A float .npy of metres (DyDToF's rendered depth)."""
    return np.load(io.BytesIO(data)).astype(np.float64)


@dataclasses.dataclass(frozen=True)
class Source:
    """One held-out set: where its files are, what they hold and how depth becomes metres."""

    repo: str
    commit: str
    depth: tuple[str, ...]  # one path per frame
    color: tuple[str, ...]
    to_metres: Callable[[bytes], np.ndarray]
    kind: str  # "static" or "video"
    licence: str
    holds: str
    units: str
    intrinsics: tuple[float, float, float, float] | None  # (fx, fy, cx, cy) of a planar z-buffer; None: range
    fps: float = STATIC_FPS


def _frames(folder: str, stem: str, ext: str, n: int) -> tuple[str, ...]:
    return tuple(f"{folder}/{stem}.{i:04d}.{ext}" for i in range(n))


SETS = {
    "nyu-office": Source(
        OPEN3D, OPEN3D_COMMIT, (f"{OPEN3D_RGBD}/NYU_depth.pgm",), (f"{OPEN3D_RGBD}/NYU_color.ppm",), nyu_metres,
        "static", "Open3D: MIT; the frame is from NYU Depth V2 (Silberman et al., ECCV 2012)",
        "one Kinect frame of an indoor room (NYU Depth V2) and its colour image, as Open3D's RGBD tutorial uses",
        "raw Kinect disparity d, metres = 351.3 / (1092.5 - d), 2047 = none", KINECT),
    "tum-desk": Source(
        OPEN3D, OPEN3D_COMMIT, (f"{OPEN3D_RGBD}/TUM_depth.png",), (f"{OPEN3D_RGBD}/TUM_color.png",), tum_metres,
        "static", "Open3D: MIT; the frame is from the TUM RGB-D benchmark (Sturm et al., IROS 2012, CC BY 4.0)",
        "one Kinect frame of an office desk (TUM RGB-D) and its colour image",
        "uint16, 5000 per metre, 0 = none", KINECT),
    "sun-room": Source(
        OPEN3D, OPEN3D_COMMIT, (f"{OPEN3D_RGBD}/SUN_depth.png",), (f"{OPEN3D_RGBD}/SUN_color.jpg",), sun_metres,
        "static", "Open3D: MIT; the frame is from SUN RGB-D / SUN3D (Song et al., CVPR 2015)",
        "one depth frame of an indoor room (SUN RGB-D) and its colour image",
        "uint16 rotated right by 3 bits, millimetres, 0 = none", KINECT),
    "dydtof-school": Source(
        STDNET, STDNET_COMMIT, _frames(f"{DYDTOF}/depth", "school_shot8", "npy", 30),
        _frames(f"{DYDTOF}/color", "school_shot8", "jpeg", 30), npy_metres, "video",
        "STDNet: Apache-2.0; DyDToF (Sun et al., CVPR 2023, facebookresearch/DVSR): CC BY-NC 4.0",
        "30 frames of a rendered indoor video with moving objects and camera (DyDToF school_shot8, 528 x 960), "
        "the subset STDNet's repository carries; the dToF dataset of 'Consistent Direct Time-of-Flight Video "
        "Depth Super-Resolution'", "float32 metres, range (used as DVSR's dToF simulator uses it)", None, 30.0),
}


@dataclasses.dataclass(frozen=True)
class Recording:
    """A real single-photon recording with photons enough for an all-photon reference, copied verbatim into the data
    folder's real/ for experiments/studies/real_photons.py (its SOURCES name the same files)."""

    repo: str
    commit: str
    path: str
    licence: str
    holds: str
    units: str


REAL = {
    "face.mat": Recording(
        "photon-efficient-imaging/pseudo-array", "e086df6beb34b91455207240a1e84c103bbe226e", "data_face.mat",
        "no licence file; the data of Shin et al., 'Photon-efficient computational 3-D and reflectivity imaging with "
        "single-photon detectors', IEEE TCI 2015",
        "a raster-scanned mannequin face: `Ts` (340, 340) cell of photon arrival times per pixel, 8.3 per pixel",
        "arrival times in the system's time bins (uint16, width not given)"),
}


def read_blob(root, path: str, commit: str) -> bytes:
    """The bytes of `path` in a source folder: a checkout's file, else `git show commit:path` of a (bare) git
    repository. FileNotFoundError (saying which) where neither holds it."""
    root = Path(root)
    if (root / path).is_file():
        return (root / path).read_bytes()
    try:
        return subprocess.run(["git", "-C", str(root), "show", f"{commit}:{path}"], check=True,
                              capture_output=True).stdout
    except (subprocess.CalledProcessError, FileNotFoundError):
        raise FileNotFoundError(f"{root}: expected a checkout or git mirror holding {path} at {commit[:12]} "
                                "(fetch the repository named in _heldout_data.SETS)") from None


def fill_missing(depth: np.ndarray) -> np.ndarray:
    """Pixels without a measurement (0 or not finite) given the depth of the nearest measured pixel."""
    from scipy import ndimage

    missing = ~(np.isfinite(depth) & (depth > 0))
    if missing.all():
        raise ValueError("fill_missing: expected at least one measured pixel, got none")
    if not missing.any():
        return depth
    _, (rows, cols) = ndimage.distance_transform_edt(missing, return_indices=True)
    return depth[rows, cols]


def to_radial(z: np.ndarray, intrinsics) -> np.ndarray:
    """(h, w) planar depth z (metres, the z-buffer) -> radial range along each pixel's ray: z |(u-cx)/fx,
    (v-cy)/fy, 1| at pixel centres (u = col + 0.5 in the convention of `jaxsr.sensor.forward.planar_to_radial`;
    the intrinsics given here use OpenCV's, col = u, so no half-pixel shift)."""
    fx, fy, cx, cy = intrinsics
    h, w = z.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    return z * np.sqrt(1.0 + ((u - cx) / fx) ** 2 + ((v - cy) / fy) ** 2)


def crop_rows(image: np.ndarray, aspect: float) -> np.ndarray:
    """The central rows of (h, w, ...) that make width / height = aspect (all rows where there are too few)."""
    h, w = image.shape[:2]
    rows = min(h, int(round(w / aspect)))
    top = (h - rows) // 2
    return image[top:top + rows]


def resample_depth(depth: np.ndarray, shape) -> np.ndarray:
    """(h, w) -> shape by the source pixel nearest each target pixel's centre."""
    h, w = depth.shape
    rows = np.minimum(((np.arange(shape[0]) + 0.5) * h / shape[0]).astype(int), h - 1)
    cols = np.minimum(((np.arange(shape[1]) + 0.5) * w / shape[1]).astype(int), w - 1)
    return depth[np.ix_(rows, cols)]


def intensity_of(rgb: np.ndarray, shape) -> np.ndarray:
    """(h, w, 3) uint8 colour -> (H, W) grey level in [0, 1] (ITU-R 601 luma), the mean over each target pixel's
    footprint (PIL's box filter)."""
    grey = Image.fromarray(np.asarray(rgb, np.uint8)).convert("L")
    return np.asarray(grey.resize((shape[1], shape[0]), Image.Resampling.BOX), np.float32) / 255.0


def hr_frame(depth_m: np.ndarray, rgb: np.ndarray, intrinsics, shape) -> tuple[np.ndarray, np.ndarray]:
    """One source frame -> (radial depth in metres, intensity), each `shape` (H, W) float32."""
    if depth_m.shape != rgb.shape[:2]:
        raise ValueError(f"hr_frame: depth {depth_m.shape} and colour {rgb.shape[:2]} must be the same size")
    depth = fill_missing(depth_m)
    if intrinsics is not None:
        depth = to_radial(depth, intrinsics)
    aspect = shape[1] / shape[0]
    return (resample_depth(crop_rows(depth, aspect), shape).astype(np.float32),
            intensity_of(crop_rows(rgb, aspect), shape))


def read_source(name: str, root, *, shape=Sensor().hr_shape, static_frames: int = STATIC_FRAMES) -> dict:
    """The set `name` of `SETS` read from its source folder: {"depth", "intensity"} (T, H, W) float32."""
    src = SETS[name]
    frames = []
    for dpath, cpath in zip(src.depth, src.color):
        depth = src.to_metres(read_blob(root, dpath, src.commit))
        rgb = np.asarray(Image.open(io.BytesIO(read_blob(root, cpath, src.commit))).convert("RGB"))
        frames.append(hr_frame(depth, rgb, src.intrinsics, shape))
    depth, intensity = (np.stack(x) for x in zip(*frames))
    if src.kind == "static":
        depth, intensity = (np.repeat(x[:1], static_frames, axis=0) for x in (depth, intensity))
    return {"depth": depth, "intensity": intensity}


def write_scene(folder, name: str, scene: dict, src: Source) -> Path:
    """`name`.npz in folder (atomically): depth (T, H, W) radial metres, intensity (T, H, W) in [0, 1], fps, kind."""
    buf = io.BytesIO()
    np.savez_compressed(buf, depth=scene["depth"], intensity=scene["intensity"], fps=np.float32(src.fps),
                        kind=np.str_(src.kind))
    path = Path(folder) / f"{name}.npz"
    with atomic_path(path, overwrite=True, make_parents=True) as tmp:
        Path(tmp).write_bytes(buf.getvalue())
    return path


def describe(name: str, scene: dict, src: Source, gate: float) -> dict:
    """A set's record in the data folder's manifest.json."""
    d = scene["depth"]
    return {"repo": src.repo, "commit": src.commit, "paths": [src.depth[0], src.color[0]] + (
        [f"... {len(src.depth)} frames"] if len(src.depth) > 1 else []), "licence": src.licence,
        "holds": src.holds, "units": src.units, "kind": src.kind, "frames": int(len(d)), "fps": src.fps,
        "radial_from_planar": src.intrinsics is not None,
        "range_m": [round(float(np.percentile(d, 1)), 2), round(float(np.percentile(d, 99)), 2)],
        "beyond_gate_pct": round(100.0 * float((d > gate).mean()), 2)}


def prepare(sources: dict, data, *, names=None, static_frames: int = STATIC_FRAMES, log=print) -> dict:
    """Write each set of `names` (default: all) whose repository has a folder in `sources` ({"owner/name": folder})
    into `data`, and copy each recording of `REAL` (named by its file) into data/real/, with manifest.json;
    returns the manifest. Sets whose repository is not given are skipped with a
    line (the manifest keeps what an earlier run wrote of them)."""
    data = Path(data)
    data.mkdir(parents=True, exist_ok=True)
    manifest_path = data / "manifest.json"
    manifest = json.loads(manifest_path.read_text()) if manifest_path.exists() else {}
    gate = Sensor().d_max
    for name in names or list(SETS):
        if name in REAL:
            continue
        if name not in SETS:
            raise ValueError(f"prepare: unknown set {name!r}; expected one of {sorted(SETS) + sorted(REAL)}")
        src = SETS[name]
        if src.repo not in sources:
            log(f"skipping {name}: no folder given for {src.repo}")
            continue
        scene = read_source(name, sources[src.repo], static_frames=static_frames)
        write_scene(data, name, scene, src)
        manifest[name] = describe(name, scene, src, gate)
        log(f"{name}: {len(scene['depth'])} frames, {manifest[name]['range_m'][0]}-{manifest[name]['range_m'][1]} m")
    for file, rec in REAL.items():
        if rec.repo in sources and (names is None or file in names):
            with atomic_path(data / "real" / file, overwrite=True, make_parents=True) as tmp:
                Path(tmp).write_bytes(read_blob(sources[rec.repo], rec.path, rec.commit))
            manifest[f"real/{file}"] = dataclasses.asdict(rec)
            log(f"real/{file}: copied from {rec.repo}")
    write_text_atomic(manifest_path, json.dumps(manifest, indent=1) + "\n")
    return manifest


def load_scenes(data, names=None, *, snr: float = 1.3) -> dict:
    """{name: record with depth, intensity, fps, snr, kind} of the held-out scenes written in `data` (`prepare`), as
    the photon benchmark reads test sequences. snr: the frame SNR of the paper's regime for them (the test scenes
    have their own; these have none, so the paper's 1.3)."""
    data = Path(data)
    paths = sorted(data.glob("*.npz")) if names is None else [data / f"{n}.npz" for n in names]
    if not paths:
        raise FileNotFoundError(f"{data}: no held-out scenes (*.npz); write them with `heldout.py prepare`")
    out = {}
    for path in paths:
        with np.load(path) as f:
            out[path.stem] = SimpleNamespace(name=path.stem, depth=f["depth"], intensity=f["intensity"],
                                             fps=float(f["fps"]), snr=snr, kind=str(f["kind"]))
    return out
