"""Atomic file writes: a temporary file in the destination folder, then `os.replace`, so a crash or an
exception never leaves a half-written file, and an existing file is only replaced when asked. Folders of
outputs are written the same way (`atomic_folder`): into a hidden temporary sibling, moved into place at the end.
A write that the disk refuses (full, over quota, read-only, an I/O error) raises `WriteError`, which names the
output rather than its hidden temporary file, after the temporary file or folder is removed.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile
from pathlib import Path


# OSErrors that are a user's mistake (an existing or missing path, no permission), raised with their own message:
# the rest, raised inside an atomic write, are the disk's (ENOSPC, EDQUOT, EROFS, EIO, ...) and become WriteError.
_PATH_ERRORS = (FileExistsError, FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError)


class WriteError(OSError):
    """An output could not be written (a full disk, a quota, a read-only or failing device). `path` is the
    output as the caller named it (never the hidden temporary file), `reason` the system's words for errno
    (e.g. "no space left on device"); str() is one line: "REASON while writing PATH; nothing was written (the
    partial file was removed)". partial: "file" or "folder", what was removed (None: nothing had been created)."""

    def __init__(self, errno_: int, path, reason: str, partial: str | None = "file"):
        self.path, self.reason, self.partial = Path(path), reason, partial
        removed = "" if partial is None else f" (the partial {partial} was removed)"
        super().__init__(errno_, f"{reason} while writing {path}; nothing was written{removed}")

    def __str__(self) -> str:  # no "[Errno 28]" prefix: the message is for people
        return self.strerror


def _write_error(error: BaseException, path: Path, tmp, partial: str) -> BaseException:
    """The exception an atomic write of `path` (through its temporary `tmp`, None before it exists) raises for
    `error`: a disk error becomes a `WriteError` naming `path`, and one an inner atomic write raised for a file
    inside `tmp` (or for `tmp` itself) names the file's final place; anything else is raised unchanged."""
    if isinstance(error, WriteError):
        inner = error.path
        if tmp is None or not (inner == tmp or tmp in inner.parents):
            return error  # another output's (written beside this one, not into it)
        where = path if inner == tmp else path / inner.relative_to(tmp)
        return WriteError(error.errno, where, error.reason, partial)
    if not isinstance(error, OSError) or error.errno is None or isinstance(error, _PATH_ERRORS):
        return error
    reason = os.strerror(error.errno)
    return WriteError(error.errno, path, reason[:1].lower() + reason[1:], None if tmp is None else partial)


def reserve_space(path) -> None:
    """Allocate the disk blocks of the whole file `path` now (`os.posix_fallocate` over its current size): a
    memory-mapped file (`numpy.lib.format.open_memmap`) is created sparse, and a page written to it on a full disk
    kills the process with SIGBUS; reserved first, a full disk is an OSError (ENOSPC) before any work. A file
    system or platform that cannot allocate ahead is left as it is."""
    if not hasattr(os, "posix_fallocate"):  # pragma: no cover - not POSIX
        return
    size = os.path.getsize(path)
    if size == 0:
        return
    fd = os.open(path, os.O_RDWR)
    try:
        os.posix_fallocate(fd, 0, size)
    except OSError as e:
        if e.errno not in (errno.EOPNOTSUPP, errno.ENOTSUP, errno.EINVAL, errno.ENOSYS):
            raise
    finally:
        os.close(fd)


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
    mkstemp's private 0600. Any exception, KeyboardInterrupt included, removes the temporary file; an OSError
    of the disk (full, over quota, read-only, failing) is raised as a `WriteError` naming `path`.
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
    except BaseException as e:
        if tmp is not None:
            with contextlib.suppress(FileNotFoundError):
                os.remove(tmp)
        error = _write_error(e, path, None if tmp is None else Path(tmp), "file")
        if error is e:
            raise
        raise error from e


def _claimed_meanwhile(path: Path) -> FileExistsError:
    return FileExistsError(f"{path} was created by another writer while this one ran; not replaced (pass "
                           "overwrite=True, or --force, to replace it)")


def _claim(tmp: Path, path: Path) -> None:
    """Move the finished file `tmp` to `path`, which must not exist: a hard link fails if another writer created
    `path` meanwhile (checking first and then renaming would silently replace its file)."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise _claimed_meanwhile(path) from None
    except OSError as e:  # a file system without hard links: the check and the rename, a moment apart
        if e.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK):
            raise
        if path.exists():
            raise _claimed_meanwhile(path) from None
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
    files by then (another writer's, created while this one ran). Raises FileExistsError if `path` is a file,
    and a `WriteError` naming `path` (or the file inside it) for an OSError of the disk (full, over quota, ...).
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
    except BaseException as e:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        error = _write_error(e, path, tmp, "folder")
        if error is e:
            raise
        raise error from e


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
