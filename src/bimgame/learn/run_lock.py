"""The lock that keeps a second process out of a run directory that one is writing.

Two processes writing one run directory (two ``bimgame train --resume`` of the same run, say) would
interleave their checkpoints and log rows, and neither would notice. So whoever writes a run holds
:data:`LOCK` in it (a :class:`~bimgame.util.locks.FileLock`, which the kernel releases however its
holder dies, so a stale lock cannot exist); a second process is refused at once with
:class:`RunDirectoryInUse`, which names the directory and the holder (pid and host). A3C's workers are
spawned, so they neither hold nor need the lock: their parent holds it for them, and a worker that
outlives a killed parent does not block a rerun. The lock file is removed when the lock is released;
one left by a killed process is taken over. Its name is the project's lock-file name
(:data:`bimgame.util.archives.SKIPPED_NAMES`), so archives of a run directory (the Ray backend ships
them) never carry it, and the checks that refuse a directory with other content do not count it
(:func:`bimgame.learn.runs.directory_entries`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bimgame.util.locks import FileLock, LockHeld

__all__ = ["LOCK", "RunLock", "RunDirectoryInUse"]

#: The lock file in a run directory while a process writes the run.
LOCK = ".lock"


class RunDirectoryInUse(BlockingIOError):
    """Another process holds the run directory's lock. ``pid`` and ``host`` are the holder's as its
    lock file records them (None if it has not written them yet)."""

    def __init__(self, directory: Path, pid: int | None, host: str | None):
        self.directory, self.pid, self.host = directory, pid, host
        holder = LockHeld(directory / LOCK, pid, host).holder
        super().__init__(
            f"{directory} is in use by {holder} (it holds {directory / LOCK}); wait for it to finish "
            f"or stop it, then run the command again. Nothing was changed."
        )

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled with its own arguments: a worker process's refusal reaches its parent intact."""
        return type(self), (self.directory, self.pid, self.host)


class RunLock:
    """The run directory's :class:`~bimgame.util.locks.FileLock` on ``DIRECTORY/.lock``, whose
    refusal names the run directory."""

    def __init__(self, lock: FileLock):
        self._lock = lock

    @classmethod
    def acquire(cls, directory: str | Path) -> RunLock:
        """Lock ``directory`` (which must exist) for this process, or raise :class:`RunDirectoryInUse`
        naming the holder."""
        try:
            return cls(FileLock.acquire(Path(directory) / LOCK, remove=True))
        except LockHeld as held:
            raise RunDirectoryInUse(Path(directory), held.pid, held.host) from None

    @staticmethod
    def refuse_if_held(directory: str | Path) -> None:
        """Raise :class:`RunDirectoryInUse` if another process holds ``directory``'s lock, creating
        nothing: how a command that would be refused for what the directory holds (another run's
        files) says first that the directory is busy."""
        try:
            FileLock.refuse_if_held(Path(directory) / LOCK)
        except LockHeld as held:
            raise RunDirectoryInUse(Path(directory), held.pid, held.host) from None

    def release(self) -> None:
        """Remove the lock file, then let the lock go. Safe to call twice."""
        self._lock.release()
