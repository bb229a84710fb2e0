"""Parallel expert episodes and the episode progress bar (worker-count independence and the Ray
backend are checked end to end in test_evaluation.py and test_datasets.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bimgame.expert.pool import episode_progress, expert_episodes
from bimgame.expert.mpc import MPCConfig, episode_seed, run_expert_episode

CONFIG = MPCConfig(n_samples=4, horizon=6)


def test_episodes_in_this_process_are_the_seeded_expert_episodes():
    outcomes = list(expert_episodes("STG1", [2, 0], 7, CONFIG, max_steps=10))
    assert [index for index, _, _ in outcomes] == [2, 0]
    for index, episode, seconds in outcomes:
        reference = run_expert_episode("STG1", episode_seed(7, index), CONFIG, max_steps=10)
        assert np.array_equal(episode["sim_states"], reference["sim_states"]) and seconds > 0


def test_bad_workers_and_backend_are_refused():
    with pytest.raises(ValueError, match="workers must be an integer >= 1, got 0"):
        next(expert_episodes("STG1", [0], 0, CONFIG, workers=0))
    with pytest.raises(ValueError, match="unknown backend 'dask'; allowed: local, ray"):
        next(expert_episodes("STG1", [0], 0, CONFIG, backend="dask"))


def test_progress_counts_resumed_and_new_episodes():
    with episode_progress(False, "x", 4, done=2, successes=1) as update:
        update(True)
        update(False)
    with episode_progress(True, "x", 2, transient=True) as update:  # the rich bar runs too
        update(True)


# ------------------------------------------------------------------------------ a killed parent
def _stat(pid: int) -> tuple[str, int, int] | None:
    """(state, parent pid, start time) of a process from /proc, or None if it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text.rsplit(")", 1)[1].split()  # after "pid (comm)": state, ppid, ..., starttime (22nd field)
    return fields[0], int(fields[1]), int(fields[19])


def _descendants(pid: int) -> dict[int, int]:
    """Every process below ``pid`` → its start time (which tells a reused pid apart)."""
    stats = {int(name): _stat(int(name)) for name in os.listdir("/proc") if name.isdigit()}
    found, frontier = {}, [pid]
    while frontier:
        parent = frontier.pop()
        for child, stat in stats.items():
            if stat is not None and stat[1] == parent and child not in found:
                found[child] = stat[2]
                frontier.append(child)
    return found


def _running(pid: int, start: int) -> bool:
    stat = _stat(pid)
    return stat is not None and stat[2] == start and stat[0] not in "ZX"  # a zombie has exited


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds the worker processes in /proc")
def test_workers_exit_when_generate_is_killed(tmp_path):
    """kill -9 of `bimgame generate` with 2 workers: no worker outlives it (they used to wait forever
    on the pool's pipes)."""
    out = tmp_path / "run"
    process = subprocess.Popen(
        [sys.executable, "-m", "bimgame.cli.main", "generate", "--task", "STG1", "--episodes", "1000",
         "--workers", "2", "-K", "4", "-H", "8", "--max-steps", "40", "--no-progress", "--out", str(out)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    children: dict[int, int] = {}
    try:
        deadline = time.monotonic() + 60
        while not list((out / "episodes").glob("episode_*.npz")):  # the workers are running episodes
            assert process.poll() is None, "generate exited early"
            assert time.monotonic() < deadline, "no episodes were written"
            time.sleep(0.05)
        children = _descendants(process.pid)
        assert len(children) >= 2
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait()
    try:
        deadline = time.monotonic() + 15
        while any(_running(pid, start) for pid, start in children.items()) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = [pid for pid, start in children.items() if _running(pid, start)]
        assert not left, f"processes {left} of the killed generate still run"
    finally:
        for pid, start in children.items():  # clean up after a failure: only the ones we started
            if _running(pid, start):
                os.kill(pid, signal.SIGKILL)


ORPHAN = """
import subprocess, sys, time
child = subprocess.Popen([sys.executable, "-c", "import os, sys, time; sys.path[:] = %r; "
                          "from bimgame.expert.pool import exit_when_parent_dies; "
                          "exit_when_parent_dies(os.getppid(), poll_seconds=0.05); print('watching', flush=True); "
                          "time.sleep(60)"], stdout=sys.stdout)
time.sleep(60)
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds the processes in /proc")
def test_a_helper_process_exits_when_its_parent_is_killed():
    """The same for a process that is not a multiprocessing child (the Minari build process)."""
    parent = subprocess.Popen([sys.executable, "-c", ORPHAN % (sys.path,)], stdout=subprocess.PIPE, text=True)
    children: dict[int, int] = {}
    try:
        assert parent.stdout.readline() == "watching\n"
        children = _descendants(parent.pid)
        assert len(children) == 1
    finally:
        parent.kill()
        parent.wait()
        parent.stdout.close()
    try:
        deadline = time.monotonic() + 5
        while any(_running(pid, start) for pid, start in children.items()) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not any(_running(pid, start) for pid, start in children.items())
    finally:
        for pid, start in children.items():
            if _running(pid, start):
                os.kill(pid, signal.SIGKILL)

