"""Parallel expert episodes and the episode progress bar (worker-count independence and the Ray
backend are checked end to end in test_evaluation.py and test_datasets.py)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from support import procfs

from bimgame.expert.mpc import MPCConfig, run_expert_episode
from bimgame.expert.pool import episode_progress, expert_episodes
from bimgame.util.seeding import episode_seed

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
        deadline = time.monotonic() + 180  # generous: the machine may be loaded
        while not list((out / "episodes").glob("episode_*.npz")):  # the workers are running episodes
            assert process.poll() is None, "generate exited early"
            assert time.monotonic() < deadline, "no episodes were written"
            time.sleep(0.05)
        children = procfs.descendants(process.pid)
        assert len(children) >= 2
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait()
    try:
        left = procfs.still_running_after(children, 60)
        assert not left, f"processes {left} of the killed generate still run"
    finally:
        procfs.kill_left(children)
