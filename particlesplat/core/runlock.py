"""A run folder is owned by one process: ``RUN/.lock`` (JSON: pid, host, start time), created exclusively.

``train`` takes the lock before it reads or deletes anything in the folder and gives it back when it ends. A
second ``train`` (``--resume``, ``--overwrite`` or a fresh run) on a locked folder ends in one line naming the
owner. A lock left by a process that no longer runs on this host (a ``kill -9``, a power cut) is stale: it is
taken over with a message. A lock of another host is never taken over (that host may still be training on a
shared file system): the message says which host and which file to remove once that run is known to be over.
"""

from __future__ import annotations

import errno
import json
import os
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from particlesplat.core.errors import UserError, one_line
from particlesplat.core.jsonfile import read_json

LOCK_NAME = ".lock"


class RunLockedError(UserError):
    """The run folder is owned by another process; the message names it."""


@dataclass(frozen=True)
class LockOwner:
    """Who holds a run folder: process id, host name, start time (seconds since the epoch, UTC)."""

    pid: int
    host: str
    started: float

    def describe(self) -> str:
        when = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(self.started))
        return f"process {self.pid} on {self.host}, started {when}"


def _alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def _read_owner(path: Path) -> LockOwner | None:
    """The owner a lock file records; None when it is unreadable or torn (a crash while writing it)."""
    try:
        data: Any = read_json(path, 4096)  # a lock file is ~80 bytes
        return LockOwner(int(data["pid"]), str(data["host"])[:255], float(data["started"]))
    except (OSError, ValueError, KeyError, TypeError):
        return None


class RunLock:
    """The exclusive lock of one run folder; :meth:`acquire` it, :meth:`release` it (also as a context manager)."""

    def __init__(self, folder: str | os.PathLike):
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self.owner: LockOwner | None = None  # set while held

    def acquire(self) -> RunLock:
        """Take the lock (creating the folder). RunLockedError naming the owner when another process holds it; a
        stale lock of a dead process on this host is taken over with a message on stderr."""
        self.folder.mkdir(parents=True, exist_ok=True)
        me = LockOwner(os.getpid(), socket.gethostname(), time.time())
        for _ in range(3):
            try:
                fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileExistsError:
                self._take_over_stale()  # raises unless the lock is stale (then removed): try again
                continue
            except OSError as e:
                raise OSError(e.errno, f"{self.path}: cannot create the run lock ({e.strerror or e})") from None
            try:
                with os.fdopen(fd, "w") as f:
                    json.dump({"pid": me.pid, "host": me.host, "started": me.started}, f)
                    f.flush()
                    os.fsync(f.fileno())
            except OSError as e:
                self.path.unlink(missing_ok=True)
                raise OSError(e.errno, f"{self.path}: cannot write the run lock ({e.strerror or e})") from None
            self.owner = me
            return self
        raise RunLockedError(f"{self.path}: could not take the run lock (another process keeps taking it)")

    def _take_over_stale(self) -> None:
        """Remove the existing lock when its owner is gone; RunLockedError when it is alive (or elsewhere)."""
        owner = _read_owner(self.path)
        host = socket.gethostname()
        if owner is None:
            # torn or unreadable: a writer that died between create and write, or one writing right now
            try:
                age = time.time() - self.path.stat().st_mtime
            except FileNotFoundError:
                return
            if age < 10:
                raise RunLockedError(
                    f"{self.folder}: another process is starting a run in this folder ({self.path} was just created)"
                )
            print(f"warning: {self.path}: unreadable run lock, {age:.0f} s old; taking it over", file=sys.stderr)
        elif owner.host != host:
            raise RunLockedError(
                f"{self.folder}: in use by {owner.describe()} ({self.path}); if that run is over, remove the lock file"
            )
        elif owner.pid == os.getpid() or _alive(owner.pid):
            raise RunLockedError(
                f"{self.folder}: in use by {owner.describe()}; wait for it to end or stop it "
                f"(a second process would mix its files with that one's)"
            )
        else:
            print(
                f"warning: {self.folder}: taking over the stale lock of {owner.describe()}, which no longer runs",
                file=sys.stderr,
            )
        try:
            os.unlink(self.path)
        except FileNotFoundError:
            pass
        except OSError as e:
            raise OSError(errno.EACCES, f"{self.path}: cannot remove the stale run lock ({one_line(e)})") from None

    def release(self) -> None:
        """Give the lock back (only when this process still holds it)."""
        if self.owner is None:
            return
        current = _read_owner(self.path)
        if current == self.owner:
            self.path.unlink(missing_ok=True)
        self.owner = None

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def live_owner(folder: str | os.PathLike) -> LockOwner | None:
    """The process that holds ``folder``'s run lock, when one does: a live process on this host other than this one,
    or any process on another host (which cannot be checked). None for no lock, a torn one or a stale one."""
    owner = _read_owner(Path(folder) / LOCK_NAME)
    if owner is None or owner.pid == os.getpid() and owner.host == socket.gethostname():
        return None
    if owner.host != socket.gethostname() or _alive(owner.pid):
        return owner
    return None
