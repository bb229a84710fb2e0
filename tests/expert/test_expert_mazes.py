"""The MPC expert (default settings) on random held-out mazes (:func:`bimgame.sim.maze_sets.maze_number`).

benchmarks/bench_expert_mazes.py measures it on 100 test mazes per task; these tests keep the
cheap facts it relies on."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.expert.mpc import MPCConfig, run_expert_episode
from bimgame.sim.maze_sets import maze_number
from bimgame.sim.tasks import Task
from bimgame.util.seeding import episode_seed


@pytest.mark.parametrize("index", [0, 1, 2])
def test_expert_solves_stg1_on_random_test_mazes_within_the_time_limit(index):
    maze = maze_number(index, "test")
    episode = run_expert_episode("STG1", episode_seed(0, index), MPCConfig(), maze=maze)
    assert episode["success"], f"test maze {index}: not solved in {len(episode['actions'])} steps"
    assert len(episode["actions"]) < Task.STG1.time_limit
    assert episode["channels"][-1, 0] == maze.outermost_channel - 1  # through the outermost wall
    assert not episode["truncations"].any()


def test_stg_episode_is_the_prefix_of_the_full_episode_with_the_same_seed():
    """With the radial planning reward the expert's plans do not depend on the task: an STGk episode
    is the FULL episode of the same seed cut when the marble first passes the k-th wall (what
    bench_expert_mazes.py --derive-stg relies on)."""
    maze, seed = maze_number(1, "test"), episode_seed(0, 1)
    stg1 = run_expert_episode("STG1", seed, MPCConfig(), maze=maze)
    steps = len(stg1["actions"])
    full = run_expert_episode("FULL", seed, MPCConfig(), maze=maze, max_steps=steps + 3)
    np.testing.assert_array_equal(stg1["actions"], full["actions"][:steps])
    np.testing.assert_array_equal(stg1["sim_states"], full["sim_states"][: steps + 1])
    passed = np.flatnonzero(full["channels"][:, 0] <= maze.outermost_channel - 1)
    assert passed[0] == steps
