"""File formats: depth frames (EXR, PFM, TIFF, 16-bit PNG), NPY/NPZ sequences, AirSim recordings, histogram
sequences, and plain images. OpenImageIO underneath for the image formats. Colour-mapped pictures of depth
(previews, comparison strips) are drawn in `jaxsr.io.previews`.

Conventions:
- a depth frame is (H, W) float32 radial metres; no return is +inf (NaN is read as no return too);
- EXR and TIFF store float32 exactly (inf included); PFM likewise (written and read here, bottom-to-top as the
  format and AirSim demand: OpenImageIO 3.2 returns PFM rows in file order, i.e. upside down);
- 16-bit PNG stores millimetres as uint16: 0 = no return, 1..65535 = 0.001..65.535 m; depths beyond 65.535 m
  saturate at 65535 and depths below 1 mm are stored as 1 (round trip within 0.5 mm);
- writes are atomic (a temporary file in the same folder, then `os.replace`) and never replace an existing file
  unless `overwrite=True` (FileExistsError otherwise).
"""

from __future__ import annotations

import csv
import errno
import json
import re
import shutil
from pathlib import Path

import numpy as np

from ..checks import npz_array_bytes, require_memory
from .files import atomic_path

__all__ = [
    "DEPTH_FORMATS",
    "read_airsim",
    "read_depth",
    "read_histograms",
    "read_image",
    "read_npz_arrays",
    "read_sequence",
    "write_depth",
    "write_histograms",
    "write_image",
    "write_sequence",
]

DEPTH_FORMATS = (".exr", ".pfm", ".tif", ".tiff", ".png", ".npy")
PNG_MAX_M = 65.535
# JSON metadata stored in a file (an .npz's `metadata` and `config`, a checkpoint's `__metadata__`): at most this many
# bytes as stored (a NumPy string, 4 bytes per character) and this many levels of nesting. Ours hold a few kB (a
# training run's checkpoint about 100 kB) and nest 5 levels; more is a damaged or hostile file, refused (a ValueError)
# before it costs minutes of parsing or a RecursionError.
JSON_METADATA_MAX_BYTES = 16 * 2**20
JSON_METADATA_MAX_DEPTH = 64


# ---------------------------------------------------------------------------------------------------------
# Atomic writes


def _atomic(path, overwrite):
    """Atomic write to `path` (see `jaxsr.io.files.atomic_path`)."""
    return atomic_path(path, overwrite=overwrite)


def _require_file(path):
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    return path


# ---------------------------------------------------------------------------------------------------------
# OpenImageIO


def _oiio():
    import OpenImageIO as oiio

    return oiio


def _read_oiio(path, pixel_type=None):
    """Read an image with OpenImageIO as (H, W, C) pixels in `pixel_type` ("float", or None for the stored
    type, e.g. uint16 for 16-bit PNG millimetres); returns (pixels, stored type name)."""
    path = _require_file(path)
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ValueError(f"cannot read {path} as an image: {oiio.geterror()}")
    try:
        spec = inp.spec()
        pixels = inp.read_image(pixel_type or spec.format)
        err = inp.geterror()
    finally:
        inp.close()
    if pixels is None or err:
        raise ValueError(f"cannot read {path}: the file is truncated or corrupt ({err or oiio.geterror()})")
    pixels = np.asarray(pixels)
    return pixels.reshape(pixels.shape[0], pixels.shape[1], -1), str(spec.format)


def read_image(path):
    """Read any image OpenImageIO can open as float32 (H, W, C), integer formats scaled to [0, 1].

    Args: path. Returns an array of shape (H, W, C) float32.
    """
    return _read_oiio(path, "float")[0].astype(np.float32)


def _read_raw(path):
    """Read an image in its stored pixel type: ((H, W, C) pixels, type name)."""
    return _read_oiio(path)


_WRITE_FAILED = re.compile(r"write error|could only write|no space|cannot write|failed to write", re.IGNORECASE)


def _write_oiio(tmp, pixels, pixel_type, attributes=()):
    oiio = _oiio()
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, pixel_type)
    for name, value in attributes:
        spec.attribute(name, value)
    out = oiio.ImageOutput.create(str(tmp))
    if out is None:
        raise ValueError(f"OpenImageIO cannot write {tmp.suffix} files: {oiio.geterror()}")
    try:
        if not out.open(str(tmp), spec):
            raise ValueError(f"cannot open {tmp} for writing: {out.geterror()}")
        if not out.write_image(np.ascontiguousarray(pixels)):
            raise ValueError(f"cannot write {tmp}: {out.geterror()}")
    finally:
        closed = out.close()
    # some writers (PNG among them) report a failed write only in their error text, returning True: a full disk
    # left empty files behind an exit status of 0
    error = out.geterror()
    if not closed or _WRITE_FAILED.search(error):  # its other messages are warnings (TIFF's Exif directory)
        full = shutil.disk_usage(Path(tmp).parent).free < pixels.nbytes
        raise OSError(errno.ENOSPC if full else errno.EIO, f"{error.splitlines()[0] if error else 'close failed'}",
                      str(tmp))


def write_image(path, pixels, *, overwrite=False):
    """Write pixels as an image, format from the suffix (PNG, EXR, TIFF, ... as OpenImageIO writes them), in
    their own type: uint8 -> 8 bits, uint16 -> 16 bits, float32 -> float. Atomic; no existing file is replaced
    unless `overwrite`.

    Args: path, pixels (H, W) or (H, W, C) uint8, uint16 or float32. Returns None.
    """
    pixels = np.asarray(pixels)
    types = {np.dtype(np.uint8): "uint8", np.dtype(np.uint16): "uint16", np.dtype(np.float32): "float"}
    if pixels.dtype not in types:
        raise ValueError(f"writing {path}: expected uint8, uint16 or float32 pixels, got {pixels.dtype}")
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    if pixels.ndim != 3:
        raise ValueError(f"writing {path}: expected an image of shape (H, W) or (H, W, C), got {pixels.shape}")
    with _atomic(path, overwrite) as tmp:
        _write_oiio(tmp, pixels, types[pixels.dtype])


# ---------------------------------------------------------------------------------------------------------
# PFM (Portable Float Map), bottom-to-top rows, negative scale = little-endian


def _read_pfm(path):
    path = _require_file(path)
    data = path.read_bytes()
    m = re.match(rb"(P[fF])\s+(\d+)\s+(\d+)\s+([-+0-9.eE]+)\s", data)
    if m is None:
        raise ValueError(f"{path} is not a PFM file (expected a 'Pf' or 'PF' header, got {data[:8]!r})")
    kind, w, h, scale, pos = m.group(1), int(m.group(2)), int(m.group(3)), float(m.group(4)), m.end()
    c = 1 if kind == b"Pf" else 3
    need = w * h * c * 4
    if len(data) - pos < need:
        raise ValueError(f"{path} is truncated: {len(data) - pos} bytes of pixels, expected {need} ({w}x{h}x{c})")
    dtype = "<f4" if scale < 0 else ">f4"
    pixels = np.frombuffer(data, dtype, w * h * c, pos).reshape(h, w, c)
    return np.flipud(pixels).astype(np.float32)


def _write_pfm(tmp, pixels):
    h, w, c = pixels.shape
    header = f"{'Pf' if c == 1 else 'PF'}\n{w} {h}\n-1.0\n".encode()
    with open(tmp, "wb") as f:
        f.write(header)
        f.write(np.flipud(pixels).astype("<f4").tobytes())


# ---------------------------------------------------------------------------------------------------------
# Depth frames


def _check_depth(depth, path):
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"writing {path}: expected a depth frame of shape (H, W), got {depth.shape}")
    if np.any(depth < 0):
        raise ValueError(f"writing {path}: depth must be non-negative metres (no return = inf)")
    return depth.astype(np.float32)


def _suffix(path):
    suffix = Path(path).suffix.lower()
    if suffix not in DEPTH_FORMATS:
        raise ValueError(f"{path}: unknown depth format {suffix!r}; expected one of {DEPTH_FORMATS}")
    return suffix


def write_depth(path, depth, *, overwrite=False):
    """Write a depth frame (H, W) in radial metres (inf = no return), format from the suffix: .exr, .pfm, .tif /
    .tiff (float32, exact), .png (uint16 millimetres, 0 = no return, saturating at 65.535 m), .npy.

    Args: path (str or Path), depth (H, W). Returns None; raises FileExistsError, ValueError.
    """
    suffix = _suffix(path)
    depth = _check_depth(depth, path)
    with _atomic(path, overwrite) as tmp:
        if suffix == ".npy":
            with open(tmp, "wb") as f:
                np.save(f, depth)
        elif suffix == ".pfm":
            _write_pfm(tmp, depth[..., None])
        elif suffix == ".png":
            mm = np.where(np.isfinite(depth), np.clip(np.rint(depth * 1000.0), 1, 65535), 0).astype(np.uint16)
            _write_oiio(tmp, mm[..., None], "uint16")
        else:
            attrs = [("compression", "zip")] if suffix == ".exr" else [("compression", "zip")]
            _write_oiio(tmp, depth[..., None], "float", attrs)


NPY_SIGNATURE = b"\x93NUMPY"


def load_npy(path, *, mmap_mode=None):
    """An .npy file's array (memory-mapped with `mmap_mode`), never unpickled. A file that is not one (random
    bytes, text, an image renamed; numpy would take it for a pickle and suggest loading it unsafely) or is
    damaged is a ValueError saying so."""
    with open(path, "rb") as f:
        if f.read(len(NPY_SIGNATURE)) != NPY_SIGNATURE:
            raise ValueError(f"cannot read {path}: not an NPY file (it does not begin with the NPY signature; an "
                             ".npy is what numpy.save writes)")
        f.seek(0)
        try:  # the header alone (a pickle is never loaded): an array of Python objects is said as such
            read = {(1, 0): np.lib.format.read_array_header_1_0,
                    (2, 0): np.lib.format.read_array_header_2_0}.get(np.lib.format.read_magic(f))
            dtype = None if read is None else read(f)[2]
        except (ValueError, EOFError, OSError, SyntaxError):
            dtype = None  # a damaged header: np.load says what is wrong below
    if dtype is not None and dtype.hasobject:
        raise ValueError(f"cannot read {path}: it holds Python objects ({dtype}), not numbers; an .npy of numbers is "
                         "what numpy.save writes of a numeric array (objects would need unpickling, which is unsafe)")
    try:
        return np.load(path, mmap_mode=mmap_mode, allow_pickle=False)
    except (ValueError, EOFError, OSError) as e:
        raise ValueError(f"cannot read {path}: a truncated or damaged NPY file ({e})") from e


def read_depth(path):
    """Read a depth frame written by `write_depth` (or AirSim's PFM, or any 1-channel float image): (H, W)
    float32 metres, inf = no return (NaN and, for 16-bit PNG, 0 are read as no return).

    Returns an array of shape (H, W) float32.
    """
    suffix = _suffix(path)
    if suffix == ".npy":
        path = _require_file(path)
        depth = load_npy(path)
        depth = depth[..., None] if depth.ndim == 2 else depth
    elif suffix == ".pfm":
        depth = _read_pfm(path)
    elif suffix == ".png":
        raw, fmt = _read_raw(path)
        if fmt != "uint16":
            raise ValueError(f"{path}: expected a 16-bit PNG of millimetres, got pixel type {fmt}")
        if raw.shape[-1] != 1:
            raise ValueError(f"{path}: expected 1 channel (depth in millimetres), got {raw.shape[-1]}")
        mm = raw[..., 0].astype(np.float32)
        return np.where(mm > 0, mm / 1000.0, np.inf).astype(np.float32)
    else:
        depth = read_image(path)
    if depth.ndim != 3 or depth.shape[-1] != 1:
        raise ValueError(f"{path}: expected a 1-channel depth image, got shape {depth.shape} "
                         f"({depth.shape[-1] if depth.ndim == 3 else '?'} channels)")
    depth = depth[..., 0].astype(np.float32)
    return np.where(np.isnan(depth), np.inf, depth)


# ---------------------------------------------------------------------------------------------------------
# Sequences (NPY: one array; NPZ: named arrays plus JSON metadata)


def write_sequence(path, depth, *, intensity=None, overwrite=False, arrays=None, **metadata):
    """Write a depth sequence (T, H, W) as .npy, or depth (+ intensity, + `arrays`) and JSON-able metadata (fps,
    snr, ...) as .npz.

    Args: path, depth (T, H, W), intensity (T, H, W) or None, arrays: {name: (T, H, W)} more arrays of the .npz
    (such as "confidence"), stored as float32. Returns None.
    """
    arrays = dict(arrays or {})
    depth = np.asarray(depth, np.float32)
    if depth.ndim != 3:
        raise ValueError(f"writing {path}: expected a sequence of shape (T, H, W), got {depth.shape}")
    suffix = Path(path).suffix.lower()
    with _atomic(path, overwrite) as tmp:
        if suffix == ".npy":
            if intensity is not None or metadata or arrays:
                raise ValueError(f"{path}: .npy holds the depth only; use .npz for intensity, arrays and metadata")
            with open(tmp, "wb") as f:
                np.save(f, depth)
        elif suffix == ".npz":
            extra = arrays
            for name, value in extra.items():
                if name in ("depth", "metadata", "intensity") or np.shape(value) != depth.shape:
                    raise ValueError(f"writing {path}: array {name!r} {np.shape(value)} beside depth {depth.shape}: "
                                     "expected another name and the depth's shape")
            arrays = dict(depth=depth, metadata=np.array(json.dumps(metadata)))
            arrays.update({name: np.asarray(v, np.float32) for name, v in extra.items()})
            if intensity is not None:
                intensity = np.asarray(intensity, np.float32)
                if intensity.shape != depth.shape:
                    raise ValueError(f"writing {path}: intensity {intensity.shape} != depth {depth.shape}")
                arrays["intensity"] = intensity
            with open(tmp, "wb") as f:
                np.savez_compressed(f, **arrays)
        else:
            raise ValueError(f"{path}: sequences are .npy or .npz, got {suffix!r}")


class DamagedFile(ValueError):
    """A file whose own description of its contents is false (a header that lies): refused before it is read."""


def read_entry(npz, name: str, where: str):
    """The array `name` of an opened .npz (`np.load`'s NpzFile), after its .npy header is checked against the
    entry's size in the archive: a header that claims more bytes than the entry holds (10^12 elements in a few
    bytes) is a ValueError naming `where`, not an allocation of terabytes. Compressed entries count their
    uncompressed size, which the archive records."""
    entry = f"{name}.npy" if f"{name}.npy" in npz.zip.namelist() else name
    stored = npz.zip.getinfo(entry).file_size
    with npz.zip.open(entry) as f:
        version = np.lib.format.read_magic(f)
        read = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}.get(version)
        if read is not None:
            shape, _, dtype = read(f)
            claimed = float(np.prod(shape, dtype=np.float64)) * dtype.itemsize
            if claimed > stored:
                raise DamagedFile(f"{where}: its array {name!r} claims {claimed:.3g} bytes ({shape} of {dtype}) in an "
                                 f"entry of {stored} bytes: a damaged or hostile file")
    return npz[name]


def _json_metadata(entry, where: str):
    """Parse JSON metadata stored in a file: `entry` is the stored value (a 0-d NumPy string, or str). Refuses
    (ValueError naming `where`) more than `JSON_METADATA_MAX_BYTES`, invalid JSON, and nesting deeper than
    `JSON_METADATA_MAX_DEPTH` levels. Returns the parsed value (any JSON type)."""
    size = entry.nbytes if isinstance(entry, np.ndarray) else 4 * len(str(entry))
    if size > JSON_METADATA_MAX_BYTES:
        raise ValueError(f"{where}: {size / 2**20:.0f} MiB of JSON metadata, more than the "
                         f"{JSON_METADATA_MAX_BYTES // 2**20} MiB it may hold: a damaged or foreign file")
    try:
        value = json.loads(str(entry))
        deep = _nested_deeper(value, JSON_METADATA_MAX_DEPTH)
    except RecursionError:  # nested deeper than the interpreter's recursion limit
        deep = True
    except ValueError as e:
        raise ValueError(f"{where}: unreadable JSON metadata (truncated or corrupt?): {e}") from e
    if deep:
        raise ValueError(f"{where}: JSON metadata nested more than {JSON_METADATA_MAX_DEPTH} levels deep: a damaged "
                         "or foreign file")
    return value


def _nested_deeper(value, limit: int) -> bool:
    """Whether lists and objects nest more than `limit` levels deep in the JSON value (no recursion)."""
    stack = [(value, 1)]
    while stack:
        v, depth = stack.pop()
        if isinstance(v, (dict, list)):
            if depth > limit:
                return True
            stack.extend((child, depth + 1) for child in (v.values() if isinstance(v, dict) else v))
    return False


def read_npz_arrays(path, required=(), *, names=None, max_memory=None):
    """The arrays of an .npz file, read eagerly (no pickles): every one, or only those in `names` (the others are
    never decompressed); the arrays named in `required` must be there. Their size is read from their headers first
    and refused beyond `max_memory` (bytes or a size such as "16GB"; default `jaxsr.checks.memory_budget`, a share
    of this machine's RAM): a small file that inflates to gigabytes is refused before it is read.

    Args: path (.npz), required (names), names (names, or None for all), max_memory. Returns a dict {name: array};
    raises FileNotFoundError, or ValueError for a truncated or foreign file, a missing array, a header that lies
    or arrays beyond the memory budget.
    """
    path = _require_file(path)
    try:
        z = np.load(path, allow_pickle=False)
    except Exception as e:  # zipfile.BadZipFile, EOFError, ValueError on truncated files
        raise ValueError(f"cannot read {path}: truncated or not an NPZ file ({e})") from e
    if not isinstance(z, np.lib.npyio.NpzFile):  # an .npy array
        raise ValueError(f"cannot read {path}: not an NPZ file (it holds one .npy array)")
    with z:
        found = list(z.files)
        wanted = [k for k in found if names is None or k in names]
        require_memory(npz_array_bytes(path, wanted), f"{path}: its arrays {', '.join(wanted)}", max_memory)
        try:
            out = {k: read_entry(z, k, str(path)) for k in wanted}
        except (DamagedFile, MemoryError):
            raise
        except Exception as e:  # zipfile.BadZipFile, EOFError, ValueError on truncated files
            raise ValueError(f"cannot read {path}: truncated or not an NPZ file ({e})") from e
    missing = [k for k in required if k not in found]
    if missing:
        raise ValueError(f"{path}: missing arrays {missing}; found {sorted(found)}")
    return out


def read_sequence(path, *, max_memory=None):
    """Read a sequence written by `write_sequence`: a dict with 'depth' (T, H, W), 'intensity' if stored, and
    'metadata' (a dict).

    Args: path (.npy or .npz), max_memory (as `read_npz_arrays`: an array beyond it, by its header, is refused
    before it is read). Returns a dict of arrays, depth of shape (T, H, W).
    """
    if Path(path).suffix.lower() == ".npy":
        path = _require_file(path)
        depth = load_npy(path, mmap_mode="r")  # its header's shape, nothing read yet
        if depth.ndim != 3:
            raise ValueError(f"{path}: expected a (T, H, W) sequence, got {depth.shape}")
        require_memory(depth.nbytes, f"{path}: its array", max_memory)
        return dict(depth=np.array(depth), metadata={})
    z = read_npz_arrays(path, ["depth"], max_memory=max_memory)
    z["metadata"] = _json_metadata(z["metadata"], f"{path}: metadata") if "metadata" in z else {}
    return z


def write_histograms(path, counts, *, depth=None, sensor=None, overwrite=False, **metadata):
    """Write photon histograms (T, h, w, K) (non-negative integers; stored uint16 when they fit, else int32),
    optionally the ground-truth HR depth (T, H, W) and the sensor (`jaxsr.Sensor.to_dict`) and metadata (JSON), as
    .npz.

    Args: path (.npz), counts (T, h, w, K), depth (T, H, W) or None. Returns None.
    """
    counts = np.asarray(counts)
    if counts.ndim < 3:
        raise ValueError(f"writing {path}: expected histograms (..., h, w, bins), got {counts.shape}")
    if np.any(counts < 0) or not np.all(np.isfinite(counts)) or np.any(np.asarray(counts) % 1):
        raise ValueError(f"writing {path}: histogram counts must be non-negative integers")
    dtype = np.uint16 if counts.max(initial=0) <= np.iinfo(np.uint16).max else np.int32
    config = {}
    if sensor is not None:
        config = sensor.to_dict()  # the jaxsr.Sensor, read back by jaxsr.Sensor.from_dict
    arrays = dict(counts=counts.astype(dtype), config=np.array(json.dumps(config)),
                  metadata=np.array(json.dumps(metadata)))
    if depth is not None:
        arrays["depth"] = np.asarray(depth, np.float32)
    if Path(path).suffix.lower() != ".npz":
        raise ValueError(f"{path}: histograms are stored as .npz")
    with _atomic(path, overwrite) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)


def read_histograms(path, *, max_memory=None):
    """Read `write_histograms` output: dict(counts=, depth= (if stored), config= dict, metadata= dict).

    Args: path (.npz), max_memory (as `read_npz_arrays`: a file inflating beyond it is refused before it is
    read). Returns a dict; counts of shape (T, h, w, K).
    """
    z = read_npz_arrays(path, ["counts"], max_memory=max_memory)
    z["config"] = _json_metadata(z["config"], f"{path}: config") if "config" in z else {}
    z["metadata"] = _json_metadata(z["metadata"], f"{path}: metadata") if "metadata" in z else {}
    return z


# ---------------------------------------------------------------------------------------------------------
# AirSim recordings

# AirSim ImageType numbers as they appear in image file names img_<vehicle>_<camera>_<type>_<timestamp>.<ext>
_AIRSIM_SCENE, _AIRSIM_DEPTH_PLANAR, _AIRSIM_DEPTH_PERSPECTIVE = 0, 1, 2


def _airsim_type(name):
    parts = Path(name).stem.split("_")
    try:
        return int(parts[-2])
    except (IndexError, ValueError):
        return None


def _grayscale(rgb):
    """ITU-R BT.601 luma of RGB(A) in [0, 1]; a 1-channel image is returned as is. (H, W, C) -> (H, W)."""
    if rgb.shape[-1] == 1:
        return rgb[..., 0]
    if rgb.shape[-1] < 3:
        raise ValueError(f"expected an RGB(A) or grayscale image, got {rgb.shape[-1]} channels")
    return 0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]


def read_airsim(folder, *, sensor=None):
    """Read an AirSim recording folder: `airsim_rec.txt` (tab-separated, an `ImageFile` column listing each row's
    images separated by ';') and the images in `folder/images/` (or `folder/`).

    Depth comes from the DepthPlanar (image type 1, converted to radial with `jaxsr.sensor.forward.planar_to_radial`) or
    DepthPerspective (type 2, already radial) PFM; intensity is the grayscale of the Scene image (type 0), or
    ones if there is none. Returns dict(depth (T, H, W) radial m, intensity (T, H, W) in [0, 1], timestamps (T,)
    seconds from the first frame, fps (median), files).
    """
    folder = Path(folder)
    rec = folder / "airsim_rec.txt"
    if not rec.is_file():
        raise FileNotFoundError(f"{folder} is not an AirSim recording: no airsim_rec.txt")
    with open(rec, newline="") as f:
        reader = csv.DictReader(f, delimiter="\t")
        rows = list(reader)
        header = reader.fieldnames or []
    if "ImageFile" not in header:
        raise ValueError(f"{rec}: expected a tab-separated header with an ImageFile column")
    if not rows:
        raise ValueError(f"{rec}: no frames (a header and no rows)")
    image_dir = folder / "images" if (folder / "images").is_dir() else folder
    depth, intensity, stamps, files = [], [], [], []
    for i, row in enumerate(rows):
        names = [n.strip() for n in (row["ImageFile"] or "").split(";") if n.strip()]
        by_type = {_airsim_type(n): n for n in names}
        if _AIRSIM_DEPTH_PLANAR in by_type:
            d = read_depth(image_dir / by_type[_AIRSIM_DEPTH_PLANAR])
            from ..sensor.forward import planar_to_radial

            d = np.asarray(planar_to_radial(d, sensor) if sensor is not None else planar_to_radial(d))
        elif _AIRSIM_DEPTH_PERSPECTIVE in by_type:
            d = read_depth(image_dir / by_type[_AIRSIM_DEPTH_PERSPECTIVE])
        else:
            raise ValueError(f"{rec} row {i + 1}: no DepthPlanar (type 1) or DepthPerspective (type 2) image "
                             f"among {names}")
        if _AIRSIM_SCENE in by_type:
            g = _grayscale(read_image(image_dir / by_type[_AIRSIM_SCENE]))
            if g.shape != d.shape:
                raise ValueError(f"{by_type[_AIRSIM_SCENE]}: scene image {g.shape} does not match depth {d.shape}")
        else:
            g = np.ones_like(d)
        depth.append(d.astype(np.float32))
        intensity.append(np.clip(g, 0, 1).astype(np.float32))
        stamps.append(float(row.get("TimeStamp") or i))
        files.append(names)
    stamps = np.asarray(stamps)
    # AirSim time stamps are milliseconds.
    t = (stamps - stamps[0]) / 1000.0
    fps = float(1.0 / np.median(np.diff(t))) if len(t) > 1 and np.median(np.diff(t)) > 0 else float("nan")
    return dict(depth=np.stack(depth), intensity=np.stack(intensity), timestamps=t, fps=fps, files=files)
