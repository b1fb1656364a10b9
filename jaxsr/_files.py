"""Atomic file writes: a temporary file in the destination folder, then `os.replace`, so a crash or an
exception never leaves a half-written file, and an existing file is only replaced when asked."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path, *, overwrite: bool = False, make_parents: bool = False):
    """Yield a temporary path beside `path`; when the block succeeds, move it onto `path`.

    Raises FileExistsError if `path` exists and `overwrite` is False, FileNotFoundError if its folder does
    not exist (unless `make_parents`). The file gets the usual permissions (0666 less the umask), not
    mkstemp's private 0600.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True (or --force) to replace it")
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    elif not path.parent.is_dir():
        raise FileNotFoundError(f"folder {path.parent} does not exist (writing {path.name})")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.remove(tmp)
        raise


def write_text_atomic(path, text: str, *, overwrite: bool = True, make_parents: bool = True) -> None:
    """Write `text` to `path` atomically (replacing an existing file by default)."""
    with atomic_path(path, overwrite=overwrite, make_parents=make_parents) as tmp:
        tmp.write_text(text)
