"""One run directory's lifecycle (bimgame.learn.run_dir): the lock that keeps a second process out and
does not outlive a killed holder, the checks before anything is created, config.json with its kind,
the declared files, and the discard of a new run that failed before it kept anything."""

from __future__ import annotations

import contextlib
import json
import math
import os
import pickle
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from support.files import snapshot

from bimgame.learn.checkpoints import save_checkpoint
from bimgame.learn.run_dir import LAYOUTS, RunDirectory
from bimgame.learn.run_lock import LOCK, RunDirectoryInUse, RunLock
from bimgame.learn.runs import (
    CHECKPOINT,
    KIND_A3C,
    KIND_DAGGER,
    KIND_POLICY,
    directory_entries,
    prepare_new_run,
    write_run_json,
)
from bimgame.util.archives import pack_directory

#: A process that holds a run directory until its stdin closes: ``python -c HOLDER DIR KIND RESUME``.
#: With "child", it first starts a child process (multiprocessing's spawn, as A3C starts its workers)
#: that sleeps on, and prints the child's pid too.
HOLDER = textwrap.dedent("""
    import multiprocessing, sys, time
    from bimgame.learn.run_dir import RunDirectory

    def sleep():
        time.sleep(120)

    if __name__ == "__main__":
        path, kind, resume = sys.argv[1], sys.argv[2], sys.argv[3] == "resume"
        with RunDirectory(path, kind, resume=resume):
            child = None
            if "child" in sys.argv[4:]:
                child = multiprocessing.get_context("spawn").Process(target=sleep, daemon=False)
                child.start()
            print("ready", child.pid if child else "", flush=True)
            sys.stdin.read()
""")


def _hold(path: Path, kind: str, *, resume: bool = False, child: bool = False) -> tuple[subprocess.Popen, str]:
    """A process holding ``path`` (see :data:`HOLDER`), once it holds it; and what it printed."""
    process = subprocess.Popen([sys.executable, "-c", HOLDER, str(path), kind, "resume" if resume else "new",
                                *(["child"] if child else [])], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                               text=True)
    line = process.stdout.readline()
    assert line.startswith("ready"), f"the holder did not start (exit code {process.poll()})"
    return process, line


def _dagger_run(path: Path) -> Path:
    """A directory that ``RunDirectory(..., KIND_DAGGER, resume=True)`` accepts (its config and checkpoint)."""
    path.mkdir()
    write_run_json(path / "config.json", {"kind": KIND_DAGGER})
    save_checkpoint(path / CHECKPOINT, model={}, step=0)
    return path


# ------------------------------------------------------------------------------------ the lock
def test_a_second_process_is_refused_naming_the_holders_pid_and_the_directory(tmp_path):
    run_dir = _dagger_run(tmp_path / "run")
    before = snapshot(run_dir)
    holder, _ = _hold(run_dir, KIND_DAGGER, resume=True)
    try:
        assert (run_dir / LOCK).is_file()
        assert directory_entries(run_dir) == ["checkpoint.pt", "config.json"]  # the lock is nobody's content
        with pytest.raises(RunDirectoryInUse) as refused:
            with RunDirectory(run_dir, KIND_DAGGER, resume=True):
                pass
        assert refused.value.pid == holder.pid
        assert f"{run_dir} is in use by process {holder.pid} on " in str(refused.value)
        # A new run into it is refused as busy too, not only as "holds a run".
        with pytest.raises(RunDirectoryInUse, match=f"in use by process {holder.pid}"):
            with RunDirectory(run_dir, KIND_DAGGER):
                pass
        assert isinstance(refused.value, OSError)  # the command line reports it as an error (exit 2)
        # A worker process's refusal reaches its parent whole (process pools pickle exceptions).
        copied = pickle.loads(pickle.dumps(refused.value))
        assert (type(copied), str(copied), copied.pid, copied.directory) == (
            RunDirectoryInUse, str(refused.value), holder.pid, run_dir)
    finally:
        holder.stdin.close()
        holder.wait(timeout=60)
    assert snapshot(run_dir) == before  # the holder removed its lock; the refusals changed nothing
    with RunDirectory(run_dir, KIND_DAGGER, resume=True):
        pass


def test_a_lock_left_by_a_killed_process_does_not_block_even_while_its_children_live(tmp_path):
    run_dir = tmp_path / "run"
    holder, line = _hold(run_dir, KIND_POLICY, child=True)
    child = int(line.split()[1])
    try:
        os.kill(holder.pid, signal.SIGKILL)
        holder.wait(timeout=60)
        os.kill(child, 0)  # the holder's child still runs
        assert (run_dir / LOCK).read_text().split()[0] == str(holder.pid)  # left behind, naming a dead process
        with RunDirectory(run_dir, KIND_POLICY) as run:  # an empty directory with a stale lock: a new run
            run.write_config({})
            run.keep()
        assert not (run_dir / LOCK).exists()
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(child, signal.SIGKILL)


def test_a_stale_lock_file_is_not_content_and_is_neither_shipped_nor_kept(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / LOCK).write_text(f"{2**22 + 12345} elsewhere\n")  # a pid no process has
    assert prepare_new_run(run_dir, what="A3C", flag="--run-dir", kind=KIND_A3C) is False  # empty
    with RunDirectory(run_dir, KIND_A3C) as run:
        assert (run_dir / LOCK).read_text().split()[0] == str(os.getpid())
        run.write_config({"a3c": {}})
        assert b".lock" not in pack_directory(run_dir)  # the Ray backend ships run directories as archives
        run.keep()
    assert sorted(p.name for p in run_dir.iterdir()) == ["config.json"]


def test_the_lock_is_taken_once_per_directory_within_a_process_too(tmp_path):
    first = RunLock.acquire(tmp_path)
    try:
        with pytest.raises(RunDirectoryInUse, match=f"process {os.getpid()}"):
            RunLock.acquire(tmp_path)
    finally:
        first.release()
        first.release()  # twice is harmless
    RunLock.acquire(tmp_path).release()
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------- the lifecycle
def test_config_records_the_kind_and_a_new_run_that_failed_early_leaves_nothing(tmp_path):
    run_dir = tmp_path / "deep" / "run"
    with pytest.raises(RuntimeError, match="early"):
        with RunDirectory(run_dir, KIND_A3C) as run:
            run.write_config({"a3c": {"seed": 1}})
            assert json.loads((run_dir / "config.json").read_text()) == {"kind": "a3c", "a3c": {"seed": 1}}
            save_checkpoint(run / CHECKPOINT, model={}, step=0)
            raise RuntimeError("early")
    assert not run_dir.exists() and (tmp_path / "deep").is_dir()  # only what the run created is removed

    with pytest.raises(ValueError, match="the run's kind is 'a3c'"):
        with RunDirectory(run_dir, KIND_A3C) as run:
            run.write_config({"kind": "other"})
    assert not run_dir.exists()


def test_a_run_that_kept_something_or_was_interrupted_keeps_its_files(tmp_path):
    kept = tmp_path / "kept"
    with pytest.raises(RuntimeError):
        with RunDirectory(kept, KIND_A3C) as run:
            run.write_config({})
            run.keep()
            raise RuntimeError("later")
    assert sorted(p.name for p in kept.iterdir()) == ["config.json"]

    interrupted = tmp_path / "interrupted"  # resumable: Ctrl-C leaves a run --resume continues
    with pytest.raises(KeyboardInterrupt):
        with RunDirectory(interrupted, KIND_A3C) as run:
            run.write_config({})
            raise KeyboardInterrupt
    assert sorted(p.name for p in interrupted.iterdir()) == ["config.json"]

    pretraining = tmp_path / "pretraining"  # cannot resume: whatever stops it early removes it
    with pytest.raises(KeyboardInterrupt):
        with RunDirectory(pretraining, KIND_POLICY) as run:
            run.write_config({})
            raise KeyboardInterrupt
    assert not pretraining.exists()


def test_the_discard_removes_declared_files_only_and_undeclared_ones_are_refused(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    with pytest.raises(RuntimeError):
        with RunDirectory(run_dir, KIND_DAGGER) as run:
            (run / "data").mkdir()
            (run / "data/iteration_000.npz").write_bytes(b"x")
            (run_dir / "someone-elses.txt").write_text("x")  # appeared meanwhile: not the run's
            with pytest.raises(ValueError, match=r"'notes\.txt' is not a file of a DAgger run; declared: config\.json"):
                run / "notes.txt"
            with pytest.raises(ValueError, match=r"logs \['other'\] are not declared"):
                run.metric_log({"other": ["x"]})
            raise RuntimeError
    assert sorted(p.name for p in run_dir.iterdir()) == ["someone-elses.txt"]


def test_resuming_checks_before_the_lock_and_changes_nothing_when_refused(tmp_path):
    missing = tmp_path / "missing"
    with pytest.raises(ValueError, match="does not exist"):
        with RunDirectory(missing, KIND_DAGGER, resume=True):
            pass
    assert not missing.exists()
    run_dir = _dagger_run(tmp_path / "run")
    (run_dir / CHECKPOINT).unlink()
    before = snapshot(run_dir)
    with pytest.raises(ValueError, match=r"has no checkpoint\.pt"):
        with RunDirectory(run_dir, KIND_DAGGER, resume=True):
            pass
    with pytest.raises(ValueError, match="holds a dagger-policy run, not an A3C run"):
        with RunDirectory(run_dir, KIND_A3C, resume=True):
            pass
    assert snapshot(run_dir) == before and not (run_dir / LOCK).exists()


def test_every_learner_writes_only_what_its_layout_declares():
    from bimgame.learn import pretrain
    from bimgame.learn.a3c import parent as a3c_parent

    assert set(a3c_parent.TABLES) == set(LAYOUTS[KIND_A3C].tables)
    assert set(LAYOUTS[KIND_POLICY].tables) == {"pretrain"} and pretrain._TABLE
    with pytest.raises(ValueError, match="unknown run kind 'x'; allowed: a3c, dagger-policy"):
        RunDirectory("anywhere", "x")


# ------------------------------------------------------------------------------ JSON files
def test_run_json_files_are_strict_json_with_null_for_non_finite_numbers(tmp_path):
    path = write_run_json(tmp_path / "summary.json", {
        "nan": math.nan, "inf": math.inf, "minus_inf": -math.inf, "numpy": np.float32("nan"),
        "finite": np.float64(0.25), "single": np.float32(0.5), "count": 3, "flag": True,
        "nested": {"values": [1.0, math.nan, (math.inf, 2)]}, "none": None})

    def no_constants(name: str) -> None:
        raise AssertionError(f"{name} is not JSON")

    stored = json.loads(path.read_text(), parse_constant=no_constants)
    assert stored == {"nan": None, "inf": None, "minus_inf": None, "numpy": None, "finite": 0.25, "single": 0.5,
                      "count": 3, "flag": True, "nested": {"values": [1.0, None, [None, 2]]}, "none": None}
    assert path.read_text() == json.dumps(stored, indent=2, sort_keys=True) + "\n"
