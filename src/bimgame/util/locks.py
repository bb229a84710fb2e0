"""The one exclusive file lock every writer of a directory takes: run directories, dataset
directories, human recordings and reproductions.

**Why ``fcntl.flock`` and not a pid file created with ``O_CREAT | O_EXCL``.** A pid file is a lock
only while its content is believed: after a kill (``SIGKILL``, the OOM killer, a power cut) it stays
behind, and the next process must decide from ``os.kill(pid, 0)`` whether its writer lives. That test
is wrong when the pid was reused by an unrelated process, cannot be made for a pid on another host
(a directory on a shared filesystem), and breaking the stale file is a race of its own. ``flock``
leaves the decision to the kernel: the lock belongs to the open file and is released when the
holder's last descriptor closes, however it dies, so a stale lock cannot exist. The holder writes
its pid and host into the file only so that whoever is refused can be told who holds it. The
descriptor is opened close-on-exec, so processes started with ``spawn`` or ``exec`` neither hold nor
need the lock. On a filesystem without ``flock`` (some network mounts) acquiring fails with the
``OSError`` it met; off POSIX nothing is locked.
"""

from __future__ import annotations

import contextlib
import errno
import os
import socket
from pathlib import Path
from typing import Any

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: nothing is locked
    fcntl = None  # type: ignore[assignment]

__all__ = ["FileLock", "LockHeld"]

#: The errors ``flock(LOCK_NB)`` raises when another descriptor holds the lock.
_BUSY = (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES)


class LockHeld(BlockingIOError):
    """Another process holds the lock at ``path``; ``pid`` and ``host`` are the holder's as its lock
    file records them (None if it has not written them)."""

    def __init__(self, path: Path, pid: int | None, host: str | None):
        self.path, self.pid, self.host = path, pid, host
        super().__init__(f"{path} is held by {self.holder}")

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled with its own arguments: a worker process's refusal reaches its parent intact."""
        return type(self), (self.path, self.pid, self.host)

    @property
    def holder(self) -> str:
        """The holder in words: "process PID on HOST", or "another process"."""
        return (
            "another process" if self.pid is None else f"process {self.pid}" + (f" on {self.host}" if self.host else "")
        )


class FileLock:
    """An exclusive ``flock`` on the file at ``path`` (see the module notes). :meth:`acquire` takes it
    or raises :class:`LockHeld`; :meth:`release` lets it go and, with ``remove=True``, removes the file
    first (so that a process that opens the path afterwards locks a new file)."""

    def __init__(self, path: Path, descriptor: int | None, *, remove: bool):
        self.path, self.remove = path, remove
        self._descriptor = descriptor

    @classmethod
    def acquire(cls, path: str | Path, *, remove: bool = False) -> FileLock:
        """Lock ``path`` (created if missing, in a directory that must exist) for this process, and
        record this process's pid and host in it."""
        path = Path(path)
        if fcntl is None:  # pragma: no cover
            return cls(path, None, remove=remove)
        while True:
            descriptor = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            try:
                fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as error:
                holder = _holder(descriptor)
                os.close(descriptor)
                if error.errno in _BUSY:
                    raise LockHeld(path, *holder) from None
                raise
            if _same_file(descriptor, path):
                break
            # The holder released it (and removed the file) between our open and our flock: the lock
            # we got is on a file no longer there. Lock the one at the path instead.
            os.close(descriptor)
        lock = cls(path, descriptor, remove=remove)
        lock._record()
        return lock

    @staticmethod
    def refuse_if_held(path: str | Path) -> None:
        """Raise :class:`LockHeld` if another process holds the lock at ``path``, creating nothing."""
        path = Path(path)
        if fcntl is None:  # pragma: no cover
            return
        try:
            descriptor = os.open(path, os.O_RDWR | os.O_CLOEXEC)
        except OSError:
            return  # no lock file (or none this process may open): nobody holds it
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as error:
            if error.errno in _BUSY:
                raise LockHeld(path, *_holder(descriptor)) from None
            raise
        finally:
            os.close(descriptor)

    def _record(self) -> None:
        assert self._descriptor is not None
        try:
            os.ftruncate(self._descriptor, 0)
            os.pwrite(self._descriptor, f"{os.getpid()} {socket.gethostname()}\n".encode(), 0)
        except OSError:
            pass  # the lock holds without its note; a refused process then names "another process"

    def release(self) -> None:
        """Let the lock go (removing its file first with ``remove``). Safe to call twice."""
        if self._descriptor is None:
            return
        if self.remove:
            with contextlib.suppress(OSError):
                if _same_file(self._descriptor, self.path):
                    self.path.unlink()
        os.close(self._descriptor)  # closing releases the flock
        self._descriptor = None


def _same_file(descriptor: int, path: Path) -> bool:
    """Whether ``path`` still names the file open as ``descriptor``."""
    try:
        here, there = os.fstat(descriptor), os.stat(path)
    except OSError:
        return False
    return (here.st_dev, here.st_ino) == (there.st_dev, there.st_ino)


def _holder(descriptor: int) -> tuple[int | None, str | None]:
    """(pid, host) as the holder of the lock file open as ``descriptor`` wrote them."""
    try:
        words = os.pread(descriptor, 256, 0).decode(errors="replace").split()
    except OSError:
        return None, None
    pid = int(words[0]) if words and words[0].isdigit() else None
    return pid, (words[1] if pid is not None and len(words) > 1 else None)
