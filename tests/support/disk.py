"""A full disk, simulated: the tests of what survives one patch the project's one atomic writer."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from bimgame.util import files


def disk_fills_up(monkeypatch: pytest.MonkeyPatch, name: str, after: int = 0) -> None:
    """Atomic writes of a file called ``name`` fail with ENOSPC after the first ``after`` of them."""
    real = files.atomic_write_bytes
    count = {"writes": 0}

    def write(path, data):
        if Path(path).name == name:
            count["writes"] += 1
            if count["writes"] > after:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(path, data)
    monkeypatch.setattr(files, "atomic_write_bytes", write)
