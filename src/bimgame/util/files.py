"""File safety: atomic writes (write to a temporary file in the same directory, then rename, so a
crash never leaves a half-written file under the final name), JSON files written that way and read
back tolerantly, an exclusive directory lock, and the one way a failed write is reported.

Write errors: :func:`atomic_write_bytes` raises the ``OSError`` it met, naming the file it was
writing. A caller that reports the failure to the user raises :class:`FileWriteError` ("cannot
write PATH: REASON. ADVICE"; :meth:`FileWriteError.from_error`), or, for a full disk or quota,
:class:`DiskFullError` ("no space left on device while writing PATH; ADVICE";
:func:`reporting_full_disk`, :func:`disk_full_errno`). Both are ``OSError`` with ``path``,
``reason``, ``advice`` and ``errno``; :meth:`FileWriteError.with_advice` adds what the caller knows
about going on.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import re
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from bimgame.util.locks import FileLock, LockHeld

__all__ = [
    "atomic_write_bytes",
    "exclusive_lock",
    "write_json",
    "read_json",
    "complete_lines",
    "file_sha256",
    "FileWriteError",
    "DiskFullError",
    "disk_full_errno",
    "reporting_full_disk",
]


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (creating parent directories); returns the path. An
    ``OSError`` (e.g. a full disk) names ``path``; the file keeps its old content, if any."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as error:
        raise _naming(error, path) from error
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)  # mkstemp creates 0600; give the file normal permissions
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException as error:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(error, OSError):
            raise _naming(error, path) from error
        raise
    return path


def _naming(error: OSError, path: Path) -> OSError:
    """``error`` naming ``path`` (the file being written, not a temporary): "[Errno 28] No space
    left on device: 'runs/a/checkpoint.pt'". Errors without an errno are passed on as they are."""
    if error.errno is None:
        return error
    return OSError(error.errno, error.strerror or os.strerror(error.errno), str(path))  # the errno's subclass


@contextlib.contextmanager
def exclusive_lock(lock_path: str | Path, busy_message: str) -> Iterator[None]:
    """Hold an exclusive lock on ``lock_path`` (created if missing, and left in place) for the block;
    another process holding it raises ``BlockingIOError(busy_message)`` at once. The OS releases the
    lock even if the process is killed, so a crash never leaves a stale lock behind
    (:class:`~bimgame.util.locks.FileLock`)."""
    try:
        lock = FileLock.acquire(lock_path)
    except LockHeld:
        raise BlockingIOError(busy_message) from None
    try:
        yield
    finally:
        lock.release()


def write_json(path: str | Path, values: dict[str, Any]) -> Path:
    """``values`` as indented JSON with sorted keys, written atomically; returns the path."""
    return atomic_write_bytes(path, (json.dumps(values, indent=2, sort_keys=True) + "\n").encode())


def read_json(path: str | Path) -> dict[str, Any] | None:
    """The JSON object in ``path``, or None when the file is missing, unreadable, not JSON or not an
    object: for files whose absence means "not done yet" (summaries, states, plans). Where a missing
    or broken file is an error, say so with the caller's own message instead."""
    try:
        value = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    return value if isinstance(value, dict) else None


def complete_lines(path: str | Path) -> list[str]:
    """The lines of the log ``path`` (with their line ends) without a last line cut off mid-write:
    a log appended line by line, read while it is written or after a kill, ends in a line that was
    never complete. Raises ``OSError`` or ``UnicodeDecodeError`` for a file that cannot be read."""
    with Path(path).open(encoding="utf-8", newline="") as handle:
        lines = handle.read().splitlines(keepends=True)
    if lines and not lines[-1].endswith(("\n", "\r")):
        lines.pop()
    return lines


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes (hex), read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


# ------------------------------------------------------------------------------ write errors
_FULL_DISK_ERRNOS = (errno.ENOSPC, errno.EDQUOT)
#: How C libraries report a full disk in an error's text only (HDF5: "errno = 28, error message = …").
_FULL_DISK_TEXT = {code: re.compile(rf"errno = {code}\b|{re.escape(os.strerror(code))}") for code in _FULL_DISK_ERRNOS}


class FileWriteError(OSError):
    """A file could not be written (e.g. the disk is full): "cannot write PATH: REASON. ADVICE". The
    message names the file and, with ``advice``, how to go on. ``path`` is the file, ``reason`` why
    (an ``OSError``'s text), ``errno`` the error number if known."""

    def __init__(self, path: str | os.PathLike, reason: str, advice: str = "", code: int | None = None) -> None:
        super().__init__(self._message(path, reason, advice))
        self.path, self.reason, self.advice = Path(path), reason, advice
        self.errno = code

    @staticmethod
    def _message(path: str | os.PathLike, reason: str, advice: str) -> str:
        return f"cannot write {os.fspath(path)}: {reason}" + (f". {advice}" if advice else "")

    @classmethod
    def from_error(cls, path: str | os.PathLike, error: OSError) -> FileWriteError:
        """``error`` (met while writing ``path``) as a :class:`FileWriteError`; one already is is kept."""
        if isinstance(error, FileWriteError):
            return error
        return cls(path, error.strerror or str(error) or type(error).__name__, code=error.errno)

    def with_advice(self, advice: str) -> FileWriteError:
        """The same error with ``advice`` (what the caller knows about going on) instead of its own."""
        return FileWriteError(self.path, self.reason, advice, self.errno)

    def __reduce__(self):  # pickles (to and from worker processes) with its own arguments
        return FileWriteError, (self.path, self.reason, self.advice, self.errno)


class DiskFullError(FileWriteError):
    """A write found the disk full (or the quota used up): "no space left on device while writing
    PATH; ADVICE". ``errno`` is ``ENOSPC`` (or ``EDQUOT``), ``path`` the file being written."""

    def __init__(self, path: str | os.PathLike, advice: str = "", code: int = errno.ENOSPC) -> None:
        reason = os.strerror(code)
        OSError.__init__(
            self,
            f"{reason[:1].lower()}{reason[1:]} while writing {os.fspath(path)}" + (f"; {advice}" if advice else ""),
        )
        self.path, self.reason, self.advice = Path(path), reason, advice
        self.errno = code

    def with_advice(self, advice: str) -> DiskFullError:
        return DiskFullError(self.path, advice, self.errno if self.errno is not None else errno.ENOSPC)

    def __reduce__(self):
        return DiskFullError, (self.path, self.advice, self.errno)


def disk_full_errno(error: BaseException | str) -> int | None:
    """``errno.ENOSPC`` or ``errno.EDQUOT`` if ``error`` — an exception, anything it was raised from
    or during, or a process's error output — says the disk (or the quota) is full; else None.
    Recognises ``OSError`` and the errors of C libraries that carry the errno only in their text
    (h5py's ``RuntimeError: … errno = 28, error message = 'No space left on device'``)."""
    if isinstance(error, str):
        return next((code for code, pattern in _FULL_DISK_TEXT.items() if pattern.search(error)), None)
    seen: set[int] = set()
    current: BaseException | None = error
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, OSError) and current.errno in _FULL_DISK_ERRNOS:
            return current.errno
        code = disk_full_errno(str(current))
        if code is not None:
            return code
        current = current.__cause__ or current.__context__
    return None


@contextlib.contextmanager
def reporting_full_disk(
    path: str | os.PathLike | None,
    advice: str | Callable[[], str] = "",
    *,
    default_path: str | os.PathLike | None = None,
) -> Iterator[None]:
    """Within the block, an error that says the disk is full becomes :class:`DiskFullError` naming
    ``path`` (None: the file the error names, else ``default_path``) with ``advice`` (a callable is
    asked when the error happens, e.g. to count what was saved). A :class:`DiskFullError` raised
    inside gets the advice if it has none; other errors pass unchanged."""
    try:
        yield
    except (OSError, RuntimeError) as error:
        code = disk_full_errno(error)
        if code is None or (isinstance(error, DiskFullError) and (error.advice or not advice)):
            raise
        where = path or getattr(error, "path", None) or getattr(error, "filename", None) or default_path
        if where is None:  # no file to name: the error says the disk is full itself
            raise
        raise DiskFullError(where, advice() if callable(advice) else advice, code) from error
