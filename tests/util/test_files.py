"""Atomic writes leave either the old file or the new one, never a partial file."""

from __future__ import annotations

import os

import pytest

from bimgame.util.files import atomic_write_bytes


def test_atomic_write_creates_parents_and_normal_permissions(tmp_path):
    path = atomic_write_bytes(tmp_path / "a" / "b.bin", b"hello")
    assert path.read_bytes() == b"hello"
    assert oct(os.stat(path).st_mode & 0o777) != oct(0o600)
    assert [p.name for p in path.parent.iterdir()] == ["b.bin"]


def test_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path, monkeypatch):
    path = atomic_write_bytes(tmp_path / "x.bin", b"old")

    def broken_replace(src, dst):
        raise OSError("disk full")
    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError, match="disk full"):
        atomic_write_bytes(path, b"new")
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["x.bin"]


def test_a_full_disk_names_the_file_being_written(tmp_path, monkeypatch):
    """Errors used to read "[Errno 28] No space left on device", naming no file (nor the temporary)."""
    import errno

    path = atomic_write_bytes(tmp_path / "run" / "checkpoint.pt", b"old")

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OSError, match=r"No space left on device: '.*run/checkpoint.pt'") as failed:
        atomic_write_bytes(path, b"new")
    assert failed.value.errno == errno.ENOSPC and failed.value.filename == str(path)
    assert path.read_bytes() == b"old" and [p.name for p in path.parent.iterdir()] == ["checkpoint.pt"]
    monkeypatch.undo()
    (tmp_path / "file").write_text("x")
    with pytest.raises(OSError, match="file/out.json"):
        atomic_write_bytes(tmp_path / "file" / "out.json", b"{}")
