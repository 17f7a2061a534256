"""Atomic file writes: write to a temporary name in the same folder, fsync, then ``os.replace``.

A target that exists and is not a regular file (a symlink, FIFO, device node, socket or folder) is
refused with :class:`UnsafeTargetError` before anything is written: replacing it would silently turn
``--json /dev/stdout`` or a symlinked output into a new regular file.
"""

from __future__ import annotations

import errno
import os
import re
import stat
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from os import PathLike
from pathlib import Path
from typing import IO


class UnsafeTargetError(OSError):
    """An output path that exists and is not a regular file; the message names it and what it is."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


def _kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISLNK, "a symbolic link"),
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISCHR, "a device node"),
        (stat.S_ISBLK, "a device node"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISDIR, "a folder"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def check_target(path: str | PathLike) -> Path:
    """``path`` as a Path; UnsafeTargetError unless it is absent or a regular file (symlinks are not followed)."""
    path = Path(path)
    try:
        mode = os.lstat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):  # absent: making its folder will report what is wrong
        return path
    if not stat.S_ISREG(mode):
        raise UnsafeTargetError(
            f"{path}: is {_kind(mode)}; refusing to replace it with a regular file (give a regular file path)"
        )
    return path


def check_writable(path: str | PathLike) -> Path:
    """Check before any work that ``path`` can be written atomically: a safe target (:func:`check_target`) in a
    folder where a temporary file can be created, or, when the folder does not exist yet, whose nearest existing
    ancestor is a writable folder (nothing is created). OSError names ``path``."""
    path = check_target(path)
    folder = path.parent
    try:
        if folder.is_dir():
            fd, tmp = create_temp_file(path)
            try:  # a real byte, flushed to the disk: a full disk fails here, not after the work
                os.write(fd, b"\0")
                os.fsync(fd)
            finally:
                os.close(fd)
                os.unlink(tmp)
            return path
        ancestor = folder
        while not ancestor.exists() and ancestor != ancestor.parent:
            ancestor = ancestor.parent
        if not ancestor.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, f"{ancestor} is not a folder")
        if not os.access(ancestor, os.W_OK | os.X_OK):
            raise PermissionError(errno.EACCES, f"{ancestor} is not writable")
    except OSError as e:
        raise OSError(f"{path}: cannot write ({e.strerror or e})") from None
    return path


def _fsync_dir(folder: Path) -> None:
    """Make a rename in ``folder`` durable (best effort: some file systems refuse to open folders)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


_TEMP_NAME = re.compile(r"^\.(.+)\.(\d+)\.[0-9a-f]{8}\.tmp")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def stale_temporaries(folder: str | PathLike, recursive: bool = False) -> list[Path]:
    """Temporary files (:func:`temp_sibling` names, ``.NAME.PID.XXXXXXXX.tmp*``) under ``folder`` whose writing
    process no longer runs: a ``kill -9`` or a power cut mid-write left them. Sorted."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    found = []
    for p in folder.rglob(".*.tmp*") if recursive else folder.glob(".*.tmp*"):
        m = _TEMP_NAME.match(p.name)
        if m and p.is_file() and int(m.group(2)) != os.getpid() and not _pid_alive(int(m.group(2))):
            found.append(p)
    return sorted(found)


def temp_sibling(path: Path, suffix: str = "") -> Path:
    """A fresh hidden name beside ``path`` (process id + random part) for a temporary file or folder."""
    return path.parent / f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp{suffix}"


def create_temp_file(path: Path, suffix: str = "") -> tuple[int, Path]:
    """Create a new temporary file beside ``path``: (open descriptor, its path). O_EXCL with mode 0o666,
    so it gets the permissions a plain ``open`` would (the umask's), unlike mkstemp's 0600."""
    tmp = temp_sibling(path, suffix)
    return os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o666), tmp


def _name_the_file(e: BaseException, path: Path) -> None:
    """A write that failed for want of space (or a file-size limit) says which file: raise an OSError naming
    ``path`` in its place; other errors are left as they are."""
    if isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT):
        raise OSError(
            e.errno, f"{path}: cannot write ({e.strerror or e}); the previous file, if any, is unchanged"
        ) from None


@contextmanager
def atomic_write(path: str | PathLike, mode: str = "wb") -> Iterator[IO]:
    """Open a temporary file beside ``path``; on success it replaces ``path``, on error it is removed.

    A reader never sees a half-written file, and an existing ``path`` survives a failed write.
    """
    path = check_target(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = create_temp_file(path)
    try:
        with os.fdopen(fd, mode) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        _put_in_place(tmp, path)
    except BaseException as e:
        _discard(tmp, path, e)
        raise


def _put_in_place(tmp: str | Path, path: Path) -> None:
    """Replace ``path`` by the finished temporary file ``tmp`` (checked again first) and fsync the folder."""
    check_target(path)
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def _discard(tmp: str | Path, path: Path, error: BaseException) -> None:
    """After a failed write: remove the temporary file and name ``path`` in ``error``."""
    if os.path.exists(tmp):
        os.unlink(tmp)
    _name_the_file(error, path)


@contextmanager
def atomic_path(path: str | PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` for writers that take a file name (torch.save, PIL).

    On success the temporary file is fsynced and replaces ``path``; on error it is removed.
    """
    path = check_target(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = create_temp_file(path, path.suffix)
    os.close(fd)
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        _put_in_place(tmp, path)
    except BaseException as e:
        _discard(tmp, path, e)
        raise


def keep_original(path: str | PathLike) -> Path | None:
    """Before ``path`` is replaced on purpose (``scene check --write DIR/transforms.json``): copy it to the first free
    name of ``PATH.orig``, ``PATH.orig-2``, ... beside it (never over an earlier copy) and return that name; None when
    ``path`` does not exist."""
    import shutil

    path = check_target(path)
    if not path.exists():
        return None
    for n in range(1, 10_000):
        keep = path.with_name(path.name + (".orig" if n == 1 else f".orig-{n}"))
        if not keep.exists() and not keep.is_symlink():
            with atomic_path(keep) as tmp:
                shutil.copyfile(path, tmp)
            return keep
    raise OSError(f"{path}: 9,999 earlier copies beside it; remove some before writing it again")
