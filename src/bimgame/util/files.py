"""File safety: atomic writes (write to a temporary file in the same directory, then rename, so a
crash never leaves a half-written file under the final name), JSON files written that way and read
back tolerantly, and an exclusive directory lock."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: directories are not locked
    fcntl = None  # type: ignore[assignment]

__all__ = ["atomic_write_bytes", "exclusive_lock", "write_json", "read_json"]


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
    """Hold an exclusive lock on ``lock_path`` (created if missing) for the block; another process
    holding it raises ``BlockingIOError(busy_message)`` at once. The OS releases the lock even if
    the process is killed, so a crash never leaves a stale lock behind."""
    if fcntl is None:  # pragma: no cover
        yield
        return
    with open(lock_path, "a") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise BlockingIOError(busy_message) from None
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


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
