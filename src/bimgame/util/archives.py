"""A directory as bytes and back: :func:`pack_directory` and :func:`unpack_directory`, how a piece
of a reproduction travels between the driver and a cluster node that shares no filesystem with it
(see :mod:`bimgame.experiments.cluster`).

The format is an uncompressed tar archive (Python's :mod:`tarfile`; the weights that make up most
of a piece do not compress). Unpacking is safe and atomic: members are extracted with tarfile's
``data`` filter (no absolute paths, no links out of the directory, no device files) into a new
directory next to the destination, which then takes the destination's name by a rename — a reader
never sees a half-written directory, and an existing destination is only removed once the new one
is in place.
"""

from __future__ import annotations

import io
import os
import shutil
import tarfile
import tempfile
from pathlib import Path

__all__ = ["SKIPPED_NAMES", "pack_directory", "unpack_directory"]

#: Files never packed: lock files, which only mean something to the process holding them.
SKIPPED_NAMES = frozenset({".lock", ".reproduce.lock"})


def pack_directory(path: str | Path) -> bytes:
    """The files under ``path`` (recursively, names relative to it) as a tar archive in memory."""
    path = Path(path)
    if not path.is_dir():
        raise NotADirectoryError(f"cannot pack {path}: not a directory")
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as archive:
        for member in sorted(path.rglob("*")):
            if member.name in SKIPPED_NAMES or member.is_symlink():
                continue
            archive.add(member, arcname=member.relative_to(path).as_posix(), recursive=False)
    return buffer.getvalue()


def unpack_directory(data: bytes, destination: str | Path) -> Path:
    """Extract an archive of :func:`pack_directory` so that ``destination`` holds exactly its files,
    atomically (see the module notes); returns ``destination``. A damaged archive raises
    ``tarfile.TarError`` and leaves ``destination`` as it was."""
    destination = Path(destination)
    if destination.exists() and not destination.is_dir():
        raise NotADirectoryError(f"cannot unpack into {destination}: it exists and is not a directory")
    destination.parent.mkdir(parents=True, exist_ok=True)
    incoming = Path(tempfile.mkdtemp(prefix=f".{destination.name}.incoming-", dir=destination.parent))
    try:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r:") as archive:
            archive.extractall(incoming, filter="data")
        replaced = None
        if destination.exists():
            replaced = Path(tempfile.mkdtemp(prefix=f".{destination.name}.replaced-", dir=destination.parent))
            os.replace(destination, replaced / destination.name)
        try:
            os.replace(incoming, destination)
        except BaseException:
            if replaced is not None:  # put the old directory back
                os.replace(replaced / destination.name, destination)
                replaced.rmdir()
            raise
        if replaced is not None:
            shutil.rmtree(replaced, ignore_errors=True)
    except BaseException:
        shutil.rmtree(incoming, ignore_errors=True)
        raise
    return destination
