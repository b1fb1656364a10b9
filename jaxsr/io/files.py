"""Atomic file writes: a temporary file in the destination folder, then `os.replace`, so a crash or an
exception never leaves a half-written file, and an existing file is only replaced when asked. Folders of
outputs are written the same way (`atomic_folder`): into a hidden temporary sibling, moved into place at the end.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile
from pathlib import Path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path, *, overwrite: bool = False, make_parents: bool = False):
    """Yield a temporary path beside `path`; when the block succeeds, move it onto `path`.

    Raises FileExistsError if `path` exists and `overwrite` is False, at the start or (another writer's file)
    at the end, when it is never replaced; FileNotFoundError if its folder does not exist (unless
    `make_parents`). The file gets the usual permissions (0666 less the umask), not
    mkstemp's private 0600. Any exception, KeyboardInterrupt included, removes the temporary file.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True (or --force) to replace it")
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    elif not path.parent.is_dir():
        raise FileNotFoundError(f"folder {path.parent} does not exist (writing {path.name})")
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
        os.close(fd)
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        if overwrite:
            os.replace(tmp, path)
        else:
            _claim(Path(tmp), path)
    except BaseException:
        if tmp is not None:
            with contextlib.suppress(FileNotFoundError):
                os.remove(tmp)
        raise


def _claim(tmp: Path, path: Path) -> None:
    """Move the finished file `tmp` to `path`, which must not exist: a hard link fails if another writer created
    `path` meanwhile (checking first and then renaming would silently replace its file)."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise FileExistsError(f"{path} was created by another writer while this one ran; not replaced (pass "
                              "overwrite=True, or --force, to replace it)") from None
    except OSError as e:  # a file system without hard links: the check and the rename, a moment apart
        if e.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK):
            raise
        if path.exists():
            raise FileExistsError(f"{path} was created by another writer while this one ran; not replaced (pass "
                                  "overwrite=True, or --force, to replace it)") from None
        os.replace(tmp, path)
        return
    os.remove(tmp)


def write_text_atomic(path, text: str, *, overwrite: bool = True, make_parents: bool = True) -> None:
    """Write `text` to `path` atomically (replacing an existing file by default)."""
    with atomic_path(path, overwrite=overwrite, make_parents=make_parents) as tmp:
        tmp.write_text(text)


LOCK_FILE = ".lock"  # `folder_lock`'s file inside the locked folder, removed when the lock is released


@contextlib.contextmanager
def folder_lock(folder, *, what: str = "run"):
    """Hold an exclusive lock on the existing folder `folder` for the block: `flock` on `folder/.lock`
    (created, and removed on release), not waiting. Raises FileExistsError naming the folder at once when
    another process (or another lock in this one) holds it, so that two writers never share one folder. Without
    `fcntl` (Windows) the block runs unlocked.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    lock = Path(folder) / LOCK_FILE
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666 & ~_umask())
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise FileExistsError(f"{folder} is in use by another {what} (it holds the lock {lock}); wait for that "
                                  "one to end, or choose another folder") from None
        except BaseException:
            os.close(fd)
            raise
        try:
            same = os.stat(lock).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # the holder removed the file between our open and lock: lock the new one
    try:
        yield
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(lock)  # before the unlock, so a waiter that locks the old file sees it gone and retries
        os.close(fd)


def _nearest_existing(path: Path) -> Path:
    """`path` or its nearest ancestor that exists (the current folder for a relative path)."""
    path = Path(os.path.abspath(path))
    while not path.exists():
        path = path.parent
    return path


@contextlib.contextmanager
def atomic_folder(path, *, overwrite: bool = True):
    """Yield a new hidden temporary folder (`.NAME.XXXX.partial`) for the files of the folder `path`; when the
    block succeeds, the folder becomes `path` (or, if `path` is an existing folder, its files are moved into
    it, replacing files of the same name), creating missing parent folders only then. Any exception,
    KeyboardInterrupt included, removes the temporary folder, so a partial folder never looks complete.

    The caller decides beforehand whether `path` may be written into (`jaxsr.io.recordings.check_output`);
    overwrite=False claims a new folder: FileExistsError at the end, writing nothing into it, if `path` holds
    files by then (another writer's, created while this one ran). Raises FileExistsError if `path` is a file.
    """
    path = Path(path)
    if path.is_file():
        raise FileExistsError(f"{path} is a file, not a folder")
    # In the nearest existing ancestor, so the final rename stays on one file system.
    home = _nearest_existing(path.parent)
    tmp = None
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".partial", dir=home))
        yield tmp
        os.chmod(tmp, 0o777 & ~_umask())
        path.parent.mkdir(parents=True, exist_ok=True)
        if not overwrite:
            try:
                os.rename(tmp, path)  # onto nothing or an empty folder; fails on a folder with files, or a file
            except OSError as e:
                if e.errno not in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR):
                    raise
                raise FileExistsError(f"{path} was written by another writer while this one ran; not written into "
                                      "(pass overwrite, or --force, to write into it)") from None
            return
        if not path.exists() or not any(path.iterdir()):
            os.replace(tmp, path)  # an empty folder is replaced as a whole
            return
        for f in sorted(tmp.iterdir()):
            os.replace(f, path / f.name)
        tmp.rmdir()
    except BaseException:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        raise


@contextlib.contextmanager
def removing_new_folder(path):
    """Run the block; if it fails (any exception, KeyboardInterrupt included), remove the folder `path` and
    the parents the block created, if they are empty, so a failed command leaves no folder behind."""
    home = _nearest_existing(path)
    try:
        yield
    except BaseException:
        p = Path(os.path.abspath(path))
        while p != home and p.is_dir() and not any(p.iterdir()):
            p.rmdir()
            p = p.parent
        raise
