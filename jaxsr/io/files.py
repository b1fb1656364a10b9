"""Atomic file writes: a temporary file in the destination folder, then `os.replace`, so a crash or an
exception never leaves a half-written file, and an existing file is only replaced when asked. Folders of
outputs are written the same way (`atomic_folder`): into a hidden temporary sibling, moved into place at the end.
A write that the disk fails (full, over quota, an I/O error) raises `WriteError` (exit status 1 in the CLI),
and one into a place this process may not write to (no permission, a read-only file system: the user's choice
of path) `NotWritableError` (a PermissionError: exit status 2); both name the output rather than its hidden
temporary file, after the temporary file or folder is removed.

The temporaries are named after their output and their writer, `.NAME.WRITER-PID.XXXXXXXX.partial` (a file
keeps its suffix after that: `.out.WRITER-PID.XXXXXXXX.partial.npy`; WRITER a short hash of the full host name
and the pid namespace, `_writer_tag`), so that one a killed process left (SIGKILL, a power cut: nothing could
remove it) is recognised: the next atomic write of the same output by a process of the same host and pid
namespace removes those whose process no longer runs, with a warning that says so.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import re
import shutil
import socket
import tempfile
import warnings
from pathlib import Path


# OSErrors that are a user's mistake (an existing or missing path, no permission), raised with their own message;
# a place that cannot be written (EPERM, EACCES, EROFS: `_NOT_WRITABLE`) is the user's too, a NotWritableError
# (`_write_error`; exit 2 in the CLI). The rest, raised inside an atomic write, are the disk's faults (ENOSPC,
# EDQUOT, EIO, ...) and become WriteError (exit 1).
_PATH_ERRORS = (FileExistsError, FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError)


class WriteError(OSError):
    """An output could not be written: the disk failed the write (a full disk, a quota, an I/O error of a failing
    device; a read-only file system or a missing permission is a `NotWritableError` instead). `path` is the
    output as the caller named it (never the hidden temporary file), `reason` the system's words for errno
    (e.g. "no space left on device"); str() is one line: "REASON while writing PATH; nothing was written (the
    partial file was removed)". partial: "file" or "folder", what was removed (None: nothing had been created)."""

    def __init__(self, errno_: int, path, reason: str, partial: str | None = "file"):
        self.path, self.reason, self.partial = Path(path), reason, partial
        removed = "" if partial is None else f" (the partial {partial} was removed)"
        super().__init__(errno_, f"{reason} while writing {path}; nothing was written{removed}")

    def __str__(self) -> str:  # no "[Errno 28]" prefix: the message is for people
        return self.strerror


class NotWritableError(PermissionError):
    """An output in a folder this process may not write to: no permission, or a read-only file system (a path
    the user chose badly, as a missing folder is). `path` is the output as the caller named it; str() is one
    line: "cannot write PATH: REASON; choose a folder you can write to"."""

    def __init__(self, errno_: int, path, reason: str, partial: str | None = None):
        self.path, self.reason, self.partial = Path(path), reason, partial
        super().__init__(errno_, f"cannot write {path}: {reason}; choose a folder you can write to")

    def __str__(self) -> str:
        return self.strerror


# errno values of a place that cannot be written (EPERM, EACCES: permissions; EROFS: a read-only mount)
_NOT_WRITABLE = (errno.EPERM, errno.EACCES, errno.EROFS)


def _reason(number: int) -> str:
    reason = os.strerror(number)
    return reason[:1].lower() + reason[1:]


def _write_error(error: BaseException, path: Path, home: Path, tmp, partial: str) -> BaseException:
    """The exception an atomic write of `path` (through its temporary `tmp` in the folder `home`, None before it
    exists) raises for `error`: a place that cannot be written becomes a `NotWritableError` (exit status 2 in
    the CLI, as any PermissionError), naming `path` when the error names the write (`home`'s files or `tmp`'s;
    for EROFS also no file), else the file it names (EROFS: only writes meet it; a PermissionError naming another
    file, which may have been read, is raised unchanged); another disk error becomes a `WriteError` naming
    `path`; one an inner atomic write raised for a file inside `tmp` (or for `tmp` itself) names the file's final
    place; anything else is raised unchanged."""
    if isinstance(error, (WriteError, NotWritableError)):
        inner = error.path
        if tmp is None or not (inner == tmp or tmp in inner.parents):
            return error  # another output's (written beside this one, not into it)
        where = path if inner == tmp else path / inner.relative_to(tmp)
        return type(error)(error.errno, where, error.reason, partial)
    if not isinstance(error, OSError) or error.errno is None:
        return error
    if error.errno in _NOT_WRITABLE and _names_the_write(error, home, tmp):
        return NotWritableError(error.errno, path, _reason(error.errno))
    if error.errno == errno.EROFS:  # only a write meets a read-only file system: without a file name, this one's
        return NotWritableError(error.errno, path if error.filename is None else error.filename, _reason(error.errno))
    if isinstance(error, _PATH_ERRORS):
        return error
    return WriteError(error.errno, path, _reason(error.errno), None if tmp is None else partial)


def _names_the_write(error: OSError, home: Path, tmp) -> bool:
    """Whether `error` is about the write itself: a file in `home` (the temporary's folder) or in `tmp`, not
    another file the block happened to open."""
    if error.filename is None:
        return False
    where = Path(os.path.abspath(error.filename))
    return where.parent == Path(os.path.abspath(home)) or (tmp is not None and Path(os.path.abspath(tmp)) in
                                                           (where, *where.parents))


def check_writable(folder, output) -> None:
    """Refuse (`NotWritableError` naming `output`) an existing `folder` in which this process cannot create
    files: no write permission, or a read-only file system (which `os.access` reports for root too), before any
    work. Writes nothing."""
    folder = Path(folder)
    if os.access(folder, os.W_OK | os.X_OK):
        return
    try:
        read_only = bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except (OSError, AttributeError):  # no statvfs (not POSIX)
        read_only = False
    where = os.path.abspath(folder)  # "." says nothing
    reason = f"{where} is on a read-only file system" if read_only else f"{where} is not writable"
    raise NotWritableError(errno.EROFS if read_only else errno.EACCES, output, reason)


def check_output_folder(folder) -> None:
    """Refuse (`NotWritableError` naming `folder`) an output folder that `atomic_folder` could not write, before
    any work: the nearest existing folder above it must take the hidden temporary folder, and `folder`, where it
    exists, the files moved into it. Writes nothing."""
    folder = Path(folder)
    check_writable(_nearest_existing(folder.parent), folder)
    if folder.is_dir():
        check_writable(folder, folder)


def refuse_link(path, what: str) -> None:
    """Refuse (ValueError) a symbolic link as the output `path` (`what` names it: "OUTPUT", "the video"): an atomic
    write moves its output into place by a rename, which would replace the link rather than write where it points
    (a link to a folder failed after the work). Writes nothing."""
    path = Path(path)
    if path.is_symlink():
        raise ValueError(f"{path} is a symbolic link (to {os.readlink(path)}); {what} is moved into place by a "
                         "rename, which would replace the link: give the path it points to")


# ---------------------------------------------------------------------------------------------------------
# Temporaries of a writer that was killed

_PARTIAL = ".partial"


def _pid_namespace() -> str:
    """This process's pid namespace, the inode of /proc/self/ns/pid (Linux), or "" where the system shows none."""
    try:
        return str(os.stat("/proc/self/ns/pid").st_ino)
    except OSError:
        return ""


def _writer_tag() -> str:
    """Where this writer's pid means something, in its temporaries' names: 12 hex digits of a hash of the full
    host name and the pid namespace. A pid means nothing on another host sharing the folder, nor in another
    container on this one: with its own host name (which may share any start with this one's: Kubernetes pods)
    or with this host's name but its own pids (docker --network host)."""
    return hashlib.sha256(f"{socket.gethostname()}\0{_pid_namespace()}".encode(errors="replace")).hexdigest()[:12]


def _temporary_affixes(path: Path, *, folder: bool) -> tuple[str, str]:
    """(".NAME.", ".partial" + the suffix): what every temporary of the output `path` begins and ends with; a
    file keeps its suffix last (the writers choose the format by it)."""
    stem, suffix = (path.name, "") if folder else (path.stem, path.suffix)
    return f".{stem}.", f"{_PARTIAL}{suffix}"


def _temporary_name_parts(path: Path, *, folder: bool) -> tuple[str, str]:
    """(prefix, suffix) for mkstemp / mkdtemp: this writer (`_writer_tag`, the pid) between the output's name and
    the random part."""
    start, end = _temporary_affixes(path, folder=folder)
    return f"{start}{_writer_tag()}-{os.getpid()}.", end


def _writer_gone(tag: str, pid: int) -> bool:
    """Whether the process `pid` that named a temporary with `tag` (`_writer_tag`) is known to have ended: of this
    host and pid namespace (the same tag), no such process (a process of another user is alive too; another
    host's or namespace's cannot be told). A pid reused since by an unrelated process keeps the temporary: left,
    never a live writer's removed."""
    if tag != _writer_tag() or pid == os.getpid() or os.name != "posix":  # Windows' os.kill(pid, 0) would end it
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:  # PermissionError: alive, another user's
        return False
    return False


def remove_stale_temporaries(path, *, folder: bool = False) -> list[Path]:
    """Remove the temporaries of the output `path` (a file, or a folder with `folder`) that a writer of this host
    and pid namespace left when it was killed (its process no longer runs), with one warning line that says how
    many and which output; temporaries of live writers, of other hosts and namespaces (whose processes cannot be
    seen from here) and of other outputs are left alone. Returns the paths removed."""
    path = Path(path)
    home = path.parent if not folder else _nearest_existing(path.parent)
    if not home.is_dir() or _own_temporary(home):  # a folder of ours being filled: nothing in it is stale
        return []
    start, end = _temporary_affixes(path, folder=folder)
    pattern = re.compile(re.escape(start) + r"(?P<tag>[A-Za-z0-9-]+)-(?P<pid>\d+)\.[a-z0-9_]+" + re.escape(end))
    removed, pids = [], set()
    try:
        with os.scandir(home) as entries:
            stale = [(e.path, int(m["pid"])) for e in entries if (m := pattern.fullmatch(e.name))
                     and _writer_gone(m["tag"], int(m["pid"]))]
    except OSError:  # a folder that cannot be listed: the write itself says what is wrong
        return []
    for p, pid in stale:
        try:
            if os.path.isdir(p) and not os.path.islink(p):
                shutil.rmtree(p)
            else:
                os.remove(p)
        except OSError:  # gone meanwhile (another run cleaned it), or not ours to remove
            continue
        removed.append(Path(p))
        pids.add(pid)
    if removed:
        what = "temporary folder" if folder else "temporary file"
        warnings.warn(f"removed {len(removed)} {what}{'s' if len(removed) > 1 else ''} of {path} that a stopped "
                      f"writer left (process {', '.join(map(str, sorted(pids)))}, no longer running)", stacklevel=3)
    return removed


def _own_temporary(folder: Path) -> bool:
    """Whether `folder` is a temporary folder of this process (its outputs' files are written into it)."""
    writer = re.escape(f"{_writer_tag()}-{os.getpid()}.")
    return bool(re.fullmatch(r"\..+\." + writer + r"[a-z0-9_]+" + re.escape(_PARTIAL), folder.name))


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


def check_new_file(path: Path, *, force: bool, what: str) -> None:
    """A file about to be written (`what` names it for people): not a folder, not an existing file unless `force`,
    in an existing folder that this process can write into. Writes nothing."""
    if path.is_dir():
        raise IsADirectoryError(f"{path} is a folder; {what} is a file")
    if path.exists() and not force:
        raise FileExistsError(f"{path} exists; pass --force (overwrite=True) to overwrite it")
    if not path.parent.is_dir():
        raise FileNotFoundError(f"no such folder for {what}: {path.parent}")
    check_writable(path.parent, path)


@contextlib.contextmanager
def atomic_path(path, *, overwrite: bool = False, make_parents: bool = False):
    """Yield a temporary path beside `path`; when the block succeeds, move it onto `path`.

    Raises FileExistsError if `path` exists and `overwrite` is False, at the start or (another writer's file)
    at the end, when it is never replaced; FileNotFoundError if its folder does not exist (unless
    `make_parents`). The file gets the usual permissions (0666 less the umask), not
    mkstemp's private 0600. Any exception, KeyboardInterrupt included, removes the temporary file; an OSError
    of the disk (full, over quota, failing) is raised as a `WriteError` naming `path`, and one of a folder it may
    not write into (permissions, a read-only file system) as a `NotWritableError`. Temporaries of `path` that a
    killed writer left are removed first (`remove_stale_temporaries`).
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True (or --force) to replace it")
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    elif not path.parent.is_dir():
        raise FileNotFoundError(f"folder {path.parent} does not exist (writing {path.name})")
    remove_stale_temporaries(path)
    tmp = None
    try:
        prefix, suffix = _temporary_name_parts(path, folder=False)
        fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=path.parent)
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
        error = _write_error(e, path, path.parent, None if tmp is None else Path(tmp), "file")
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
def atomic_folder(path, *, overwrite: bool = True, replaces: tuple[str, ...] = ()):
    """Yield a new hidden temporary folder (`.NAME.WRITER-PID.XXXXXXXX.partial`) for the files of the folder `path`;
    when the block succeeds, the folder becomes `path` (or, if `path` is an existing folder, its files are moved
    into it, replacing files of the same name, and the files there that match a glob pattern of `replaces` but
    were not written now are removed: an earlier run's frames do not mix with this run's), creating missing parent
    folders only then. Any exception,
    KeyboardInterrupt included, removes the temporary folder, so a partial folder never looks complete.

    The caller decides beforehand whether `path` may be written into (`jaxsr.app.outputs.check_output`);
    overwrite=False claims a new folder: FileExistsError at the end, writing nothing into it, if `path` holds
    files by then (another writer's, created while this one ran). Raises FileExistsError if `path` is a file,
    and a `WriteError` or `NotWritableError` naming `path` (or the file inside it) for an OSError of the disk
    (full, over quota, ...) or of a folder it may not write into. Temporaries of `path` that a killed writer left
    are removed first (`remove_stale_temporaries`).
    """
    path = Path(path)
    if path.is_file():
        raise FileExistsError(f"{path} is a file, not a folder")
    # In the nearest existing ancestor, so the final rename stays on one file system.
    home = _nearest_existing(path.parent)
    remove_stale_temporaries(path, folder=True)
    tmp = None
    try:
        prefix, suffix = _temporary_name_parts(path, folder=True)
        tmp = Path(tempfile.mkdtemp(prefix=prefix, suffix=suffix, dir=home))
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
        written = {f.name for f in tmp.iterdir()}
        for name in sorted(written):
            os.replace(tmp / name, path / name)
        tmp.rmdir()
        for pattern in replaces:  # an earlier run's output of the same kind, left over
            for stale in path.glob(pattern):
                if stale.name not in written and stale.is_file() and not stale.is_symlink():
                    stale.unlink()
    except BaseException as e:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        error = _write_error(e, path, home, tmp, "folder")
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
