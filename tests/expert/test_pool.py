"""Parallel expert episodes and the episode progress bar (worker-count independence and the Ray
backend are checked end to end in test_evaluation.py and test_datasets.py)."""

from __future__ import annotations

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
