"""The lock that keeps a second process out of a run directory that one is writing.

Two processes writing one run directory (two ``bimgame train --resume`` of the same run, say) would
interleave their checkpoints and log rows, and neither would notice. So whoever writes a run holds
:data:`LOCK` in it; a second process is refused at once with :class:`RunDirectoryInUse`, which names
the directory and the holder (pid and host, read from the lock file).

**Why ``fcntl.flock`` and not a pid file created with ``O_CREAT | O_EXCL``.** A pid file is a lock
only while its content is believed: after a kill (``SIGKILL``, the OOM killer, a power cut) it stays
behind, and the next process must decide from ``os.kill(pid, 0)`` whether its writer lives. That test
is wrong when the pid was reused by an unrelated process (the run stays blocked), cannot be made for a
pid on another host (a run directory on a shared filesystem), and breaking the stale file is a race
of its own (two processes may both decide it is stale, and both remove and recreate it). ``flock``
leaves the decision to the kernel: the lock belongs to the open file and is released when the
holder's last descriptor closes, however it dies, so a stale lock cannot exist and the file's
content is only what the refusal message quotes. The descriptor is not inherited by processes
started with ``spawn`` or ``exec`` (as A3C's workers are), so they neither hold nor need the lock:
their parent holds it for them, and a worker that outlives a killed parent does not block a rerun.
On a filesystem without ``flock`` (some network mounts) acquiring fails with the ``OSError`` it met.

The lock file is removed when the lock is released; one left by a killed process is taken over. Its
name is the project's lock-file name (:data:`bimgame.util.archives.SKIPPED_NAMES`), so archives of a
run directory (the Ray backend ships them) never carry it, and the checks that refuse a directory
with other content do not count it (:func:`bimgame.learn.runs.directory_entries`).
"""

from __future__ import annotations

import contextlib
import errno
import os
import socket
from pathlib import Path

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: run directories are not locked
    fcntl = None  # type: ignore[assignment]

__all__ = ["LOCK", "RunLock", "RunDirectoryInUse"]

#: The lock file in a run directory while a process writes the run.
LOCK = ".lock"


class RunDirectoryInUse(BlockingIOError):
    """Another process holds the run directory's lock. ``pid`` and ``host`` are the holder's as its
    lock file records them (None if it has not written them yet)."""

    def __init__(self, directory: Path, pid: int | None, host: str | None):
        self.directory, self.pid, self.host = directory, pid, host
        holder = "another process" if pid is None else f"process {pid}" + (f" on {host}" if host else "")
        super().__init__(f"{directory} is in use by {holder} (it holds {directory / LOCK}); wait for it to finish "
                         f"or stop it, then run the command again. Nothing was changed.")


class RunLock:
    """An exclusive ``flock`` on ``DIRECTORY/.lock`` (see the module notes); :meth:`acquire` takes it,
    :meth:`release` removes the file and lets it go."""

    def __init__(self, path: Path, descriptor: int | None):
        self.path = path
        self._descriptor = descriptor

    @classmethod
    def acquire(cls, directory: str | Path) -> RunLock:
        """Lock ``directory`` (which must exist) for this process, or raise :class:`RunDirectoryInUse`
        naming the holder. The file records this process's pid and host for whoever is refused."""
        path = Path(directory) / LOCK
        if fcntl is None:  # pragma: no cover
            return cls(path, None)
        while True:
            descriptor = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            try:
                fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as error:
                holder = _holder(descriptor)
                os.close(descriptor)
                if error.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise RunDirectoryInUse(Path(directory), *holder) from None
                raise
            if _same_file(descriptor, path):
                break
            # The holder released it (and removed the file) between our open and our flock: the
            # lock we got is on a file no longer there. Lock the one at the path instead.
            os.close(descriptor)
        lock = cls(path, descriptor)
        lock._record()
        return lock

    @staticmethod
    def refuse_if_held(directory: str | Path) -> None:
        """Raise :class:`RunDirectoryInUse` if another process holds ``directory``'s lock, creating
        nothing: how a command that would be refused for what the directory holds (another run's
        files) says first that the directory is busy."""
        path = Path(directory) / LOCK
        if fcntl is None:  # pragma: no cover
            return
        try:
            descriptor = os.open(path, os.O_RDWR | os.O_CLOEXEC)
        except OSError:
            return  # no lock file (or none this process may open): nobody holds it
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as error:
            if error.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise RunDirectoryInUse(Path(directory), *_holder(descriptor)) from None
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
        """Remove the lock file, then let the lock go (in this order, so that a process that opens
        the path afterwards locks a new file). Safe to call twice."""
        if self._descriptor is None:
            return
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
