"""Where `jaxsr upscale` writes, checked before any work: the OUTPUT (an array file or a folder of frames) and
what `Writing` adds beside it (a preview, a video, point clouds), and the reference the video shows. Nothing is
written here; `check_outputs` returns the checked paths as `Outputs`, which `jaxsr.app.write_upscaled` takes.
"""

from __future__ import annotations

import dataclasses
import glob
import os
from pathlib import Path

import numpy as np

from ..io.files import check_new_file, check_output_folder, refuse_link
from ..io.pointcloud import check_points
from ..io.video import check_video
from .recordings import ARRAY_FORMATS, FRAME_FORMATS, Recording, open_recording
from .specs import Writing

__all__ = ["Outputs", "check_outputs", "check_output", "check_preview"]


@dataclasses.dataclass(frozen=True)
class Outputs:
    """Checked destinations (`check_outputs`): output (None: the result is kept in memory), preview, video and
    points (None where not asked for), and the `Writing` they came from."""

    output: Path | None
    preview: Path | None
    video: Path | None
    points: Path | None
    writing: Writing

    @property
    def folder(self) -> bool:
        """True when OUTPUT is a folder of frame files."""
        return self.output is not None and self.output.suffix.lower() not in ARRAY_FORMATS

    @property
    def in_memory(self) -> bool:
        """True when the whole result is held in memory: kept (no OUTPUT) or written as one .npz."""
        return self.output is None or self.output.suffix.lower() == ".npz"


def check_outputs(output, writing: Writing = Writing(), *, input=None) -> Outputs:
    """Check OUTPUT and every path of `writing` once, before anything is read or run: each is refused where it
    exists (unless `writing.overwrite`), cannot be written, is a symbolic link or is another of them, and, even
    with overwrite, where it is the input (`input`: a path, a folder or glob pattern of frames) or the reference,
    or the folder of their frames; a reference given as a path must exist and read as depth (its frames are
    checked against the output's once the model is known). Writes nothing. Returns `Outputs`. Raises
    FileExistsError, IsADirectoryError, NotADirectoryError, FileNotFoundError, `jaxsr.io.NotWritableError` or
    ValueError."""
    if not isinstance(writing, Writing):
        raise TypeError(f"writing: expected a jaxsr.app.Writing, got {type(writing).__name__}")
    force = writing.overwrite
    reads = {"the input": _read_paths(input), "the reference": _read_paths(writing.reference)}  # listed once
    out = None if output is None else check_output(output, force=force)
    _refuse_inside_folder_output(out, writing)
    preview = None if writing.preview is None else check_preview(writing.preview, force=force, output=out)
    video = None if writing.video is None else check_video(writing.video, force=force, output=out)
    points = None if writing.points is None else check_points(writing.points, force=force, output=out)
    for what, path in (("OUTPUT", out), ("the preview", preview), ("the video", video),
                       ("the point clouds", points)):
        for whose, (files, folders) in reads.items():
            _refuse_writing_over(path, what, files, folders, whose)
    if writing.reference is not None and not isinstance(writing.reference, (np.ndarray, Recording)):
        open_recording(writing.reference, kind="depth")  # exists and reads
    if writing.frame_format is not None and (out is None or out.suffix.lower() in ARRAY_FORMATS):
        raise ValueError(f"frame_format (--frame-format) applies to a folder OUTPUT (one file per frame), not "
                         f"{'an output kept in memory' if out is None else out}")
    return Outputs(out, preview, video, points, writing)


def _refuse_inside_folder_output(out: Path | None, writing: Writing) -> None:
    """Refuse a preview, video or point clouds (a folder or a .ply) inside a folder OUTPUT: the folder is written as
    a whole and holds this run's frames alone (a new or empty folder is claimed by one rename, which what is written
    into it first would make fail after the work; with --force an earlier run's frame_* files are removed)."""
    if out is None or out.suffix.lower() in ARRAY_FORMATS:
        return
    folder = out.resolve()
    for what, spec in (("the preview", writing.preview), ("the video", writing.video),
                       ("the point clouds", writing.points)):
        if spec is not None and folder in Path(spec).resolve().parents:
            raise ValueError(f"{spec}: {what} lies inside the folder OUTPUT {out}, which holds the frames alone; "
                             "write it beside that folder")


def _read_paths(source) -> tuple[set[Path], set[Path]]:
    """(files, folders of frames) a recording given as `source` reads: a file, a folder's files and the folder,
    a glob pattern's matches and their folders; nothing for arrays and other objects."""
    if not isinstance(source, (str, os.PathLike)):
        return set(), set()
    spec = str(source)
    files = {Path(f) for f in glob.glob(spec)} if any(c in spec for c in "*?[") else {Path(spec)}
    folders = {f for f in files if f.is_dir()}
    for folder in folders:
        files |= set(folder.iterdir())
    folders |= {f.parent for f in files if f.suffix.lower() in FRAME_FORMATS}
    return {f.resolve() for f in files if f.exists()}, {f.resolve() for f in folders if f.exists()}


def _refuse_writing_over(path: Path | None, what: str, files: set, folders: set, whose: str) -> None:
    """Refuse `path` (a file or folder about to be written) where it is one of the `files` a recording reads, or one
    of its `folders` of frames (`_read_paths`): nothing read is ever written over, --force or not."""
    if path is None:
        return
    target = path.resolve()
    if target in files or target in folders:
        raise ValueError(f"{path}: {what} is {whose} itself{' (or its folder of frames)' if target in folders else ''}"
                         f"; choose another path (nothing is written over what is read)")


def check_output(spec, *, force: bool) -> Path:
    """OUTPUT: .npy / .npz (one array, in an existing folder) or a folder (one frame file per frame; missing
    parent folders are created when the frames are all written). Refuses to replace an existing file or write
    into a non-empty folder unless `force`, and in any case a file where a folder is meant, a symbolic link
    (the output is moved into place by a rename, which would replace the link, not write where it points) and a
    folder this process cannot write into (`jaxsr.io.files.check_output_folder`). Writes nothing."""
    out = Path(spec)
    refuse_link(out, "OUTPUT")
    if out.suffix.lower() in ARRAY_FORMATS:
        check_new_file(out, force=force, what=f"OUTPUT {out.suffix}")
    elif out.suffix:
        raise ValueError(f"{out}: OUTPUT is an .npy or .npz file, or a folder for frames (see --frame-format)")
    elif out.exists() and not out.is_dir():
        raise FileExistsError(f"{out} is a file; OUTPUT without a suffix is a folder for frames")
    elif out.is_dir() and any(out.iterdir()) and not force:
        raise FileExistsError(f"{out} exists and is not an empty folder; pass --force to write into it")
    else:
        _check_ancestors(out)
        check_output_folder(out)
    return out


def _check_ancestors(path: Path) -> None:
    """Refuse a folder path whose nearest existing ancestor is a file (it could never be created)."""
    p = path.parent
    while not p.exists():
        p = p.parent
    if not p.is_dir():
        raise NotADirectoryError(f"cannot create the folder {path}: {p} is a file")


def check_preview(spec, *, force: bool, output=None) -> Path:
    """A preview path (.png): refuses an existing file unless `force`, a missing folder, a symbolic link and the
    OUTPUT path itself. Writes nothing."""
    path = Path(spec)
    if path.suffix.lower() != ".png":
        raise ValueError(f"{path}: the preview is a .png file")
    if output is not None and path.resolve() == Path(output).resolve():
        raise ValueError(f"{path}: the preview and OUTPUT are the same file")
    refuse_link(path, "the preview")  # a dangling one passed for a new file, then failed after the work
    check_new_file(path, force=force, what="the preview")
    return path


