"""Directories as bytes: a round trip keeps every file, unpacking replaces a directory atomically
and refuses archives that would write outside it or onto a file."""

from __future__ import annotations

import io
import tarfile

import pytest

from bimgame.util.archives import pack_directory, unpack_directory


def _tree(root, files):
    for name, content in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(content)


def _files(root):
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in root.rglob("*") if p.is_file()}


def test_round_trip_keeps_every_file_but_locks(tmp_path):
    files = {"summary.json": b'{"a": 1}', "tb/events": b"\x00\x01" * 1000, "deep/er/w.pt": b"weights"}
    _tree(tmp_path / "src", {**files, ".lock": b""})
    unpack_directory(pack_directory(tmp_path / "src"), tmp_path / "dst")
    assert _files(tmp_path / "dst") == files


def test_unpacking_replaces_the_old_directory_and_leaves_nothing_beside_it(tmp_path):
    _tree(tmp_path / "src", {"new.csv": b"1"})
    _tree(tmp_path / "out" / "piece", {"old-partial.csv": b"0", "checkpoint.pt": b"old"})
    unpack_directory(pack_directory(tmp_path / "src"), tmp_path / "out" / "piece")
    assert _files(tmp_path / "out" / "piece") == {"new.csv": b"1"}
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["piece"]


def test_a_damaged_archive_leaves_the_destination_as_it_was(tmp_path):
    _tree(tmp_path / "piece", {"kept.csv": b"1"})
    with pytest.raises(tarfile.TarError):
        unpack_directory(b"not a tar archive" * 100, tmp_path / "piece")
    assert _files(tmp_path / "piece") == {"kept.csv": b"1"}
    assert [p.name for p in tmp_path.iterdir()] == ["piece"]


def test_members_outside_the_directory_are_refused(tmp_path):
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as archive:
        info = tarfile.TarInfo("../escaped.txt")
        info.size = 3
        archive.addfile(info, io.BytesIO(b"bad"))
    with pytest.raises(tarfile.TarError):
        unpack_directory(buffer.getvalue(), tmp_path / "out" / "piece")
    assert not (tmp_path / "out" / "escaped.txt").exists() and not (tmp_path / "out" / "piece").exists()


def test_a_file_in_the_way_is_not_replaced(tmp_path):
    _tree(tmp_path / "src", {"a": b"1"})
    (tmp_path / "piece").write_text("someone's notes")
    with pytest.raises(NotADirectoryError, match="exists and is not a directory"):
        unpack_directory(pack_directory(tmp_path / "src"), tmp_path / "piece")
    assert (tmp_path / "piece").read_text() == "someone's notes"
    with pytest.raises(NotADirectoryError, match="not a directory"):
        pack_directory(tmp_path / "piece")
