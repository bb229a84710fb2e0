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
