"""Atomic writes leave either the old file or the new one, never a partial file."""

from __future__ import annotations

import os

import pytest

from bimgame.util.files import atomic_write_bytes, complete_lines


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


# ------------------------------------------------------------------------------ write errors
def test_a_write_error_names_the_file_the_reason_and_the_advice(tmp_path):
    import errno
    import pickle

    from bimgame.util.files import FileWriteError

    error = FileWriteError.from_error(tmp_path / "a.csv", OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)))
    assert isinstance(error, OSError) and error.errno == errno.ENOSPC and error.path == tmp_path / "a.csv"
    assert str(error) == f"cannot write {tmp_path / 'a.csv'}: No space left on device"
    advised = error.with_advice("Resume later")
    assert str(advised) == f"cannot write {tmp_path / 'a.csv'}: No space left on device. Resume later"
    assert error.with_advice("x").advice == "x" and FileWriteError.from_error("b", advised) is advised
    again = pickle.loads(pickle.dumps(advised))
    assert type(again) is FileWriteError and str(again) == str(advised) and again.errno == errno.ENOSPC


def test_a_full_disk_is_reported_in_one_line_naming_the_file(tmp_path):
    import errno
    import pickle

    from bimgame.util.files import DiskFullError, FileWriteError, disk_full_errno, reporting_full_disk

    target = tmp_path / "data.hdf5"
    with pytest.raises(DiskFullError) as failed:
        with reporting_full_disk(target, "rerun to resume"):
            raise RuntimeError("Can't write data (file write failed: errno = 28, error message = 'No space …')")
    error = failed.value
    assert str(error) == f"no space left on device while writing {target}; rerun to resume"
    assert isinstance(error, FileWriteError) and error.errno == errno.ENOSPC and error.path == target
    assert str(error.with_advice("later")) == f"no space left on device while writing {target}; later"
    assert str(pickle.loads(pickle.dumps(error))) == str(error)
    quota = DiskFullError(target, code=errno.EDQUOT)
    assert str(quota) == f"{os.strerror(errno.EDQUOT)[:1].lower()}{os.strerror(errno.EDQUOT)[1:]} while writing {target}"
    assert disk_full_errno(OSError(errno.EACCES, "Permission denied")) is None
    assert disk_full_errno("errno = 122") == errno.EDQUOT
    with pytest.raises(PermissionError):  # other errors pass unchanged
        with reporting_full_disk(target):
            raise PermissionError(errno.EACCES, "Permission denied")


def test_complete_lines_leave_out_a_last_line_cut_off_mid_write(tmp_path):
    log = tmp_path / "log.csv"
    log.write_bytes(b"step,return\r\n1,0.5\r\n2,0.")
    assert complete_lines(log) == ["step,return\r\n", "1,0.5\r\n"]
    log.write_bytes(b"step,return\n1,0.5\n")
    assert complete_lines(log) == ["step,return\n", "1,0.5\n"]
    log.write_bytes(b"")
    assert complete_lines(log) == []
    with pytest.raises(FileNotFoundError):
        complete_lines(tmp_path / "missing.csv")
