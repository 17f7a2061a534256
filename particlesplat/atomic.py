"""Atomic file writes: write to a temporary name in the same folder, then ``os.replace``."""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from os import PathLike
from pathlib import Path
from typing import IO


def temp_sibling(path: Path, suffix: str = "") -> Path:
    """A fresh hidden name beside ``path`` (process id + random part) for a temporary file or folder."""
    return path.parent / f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp{suffix}"


def create_temp_file(path: Path, suffix: str = "") -> tuple[int, Path]:
    """Create a new temporary file beside ``path``: (open descriptor, its path). O_EXCL with mode 0o666,
    so it gets the permissions a plain ``open`` would (the umask's), unlike mkstemp's 0600."""
    tmp = temp_sibling(path, suffix)
    return os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o666), tmp


@contextmanager
def atomic_write(path: str | PathLike, mode: str = "wb") -> Iterator[IO]:
    """Open a temporary file beside ``path``; on success it replaces ``path``, on error it is removed.

    A reader never sees a half-written file, and an existing ``path`` survives a failed write.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = create_temp_file(path)
    try:
        with os.fdopen(fd, mode) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


@contextmanager
def atomic_path(path: str | PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` for writers that take a file name (torch.save, PIL).

    On success the temporary file replaces ``path``; on error it is removed.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = create_temp_file(path, path.suffix)
    os.close(fd)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
