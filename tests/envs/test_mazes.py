"""Envs over many mazes: a maze per episode, shown to the agent, identical in the vector env."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import bimgame  # noqa: F401
from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.mazes import MAZE_ENCODING_ANGLES, maze_encoding
from bimgame.sim.generate import maze_hash
from bimgame.sim.maze import MazeSpec
from bimgame.sim.maze_sets import maze_number


@pytest.mark.parametrize("obs_mode", ["state", "pixels"])
def test_check_env_with_many_mazes(obs_mode):
    env = BallInMazeEnv("STG1", obs_mode=obs_mode, num_mazes=5)
    check_env(env, skip_render_check=True)
    env.close()


def test_episodes_draw_mazes_of_the_set_and_observe_them():
    env = BallInMazeEnv("STG2", obs_mode="state", num_mazes=4, start_maze=20)
    seen = set()
    obs, info = env.reset(seed=0)
    for _ in range(30):
        assert 20 <= info["maze"] < 24
        assert env.maze == maze_number(info["maze"])
        np.testing.assert_array_equal(obs[7:], maze_encoding(env.maze))
        assert obs.shape == (7 + 4 * MAZE_ENCODING_ANGLES,)
        seen.add(info["maze"])
        obs, info = env.reset()
    assert seen == {20, 21, 22, 23}
    obs, info = env.reset(options={"maze": 22})
    assert info["maze"] == 22 and env.maze == maze_number(22)
    with pytest.raises(ValueError, match=r"options\['maze'\] must be a maze number of this env's set \(20..23\)"):
        env.reset(options={"maze": 3})
    # The same seed gives the same mazes and starts.
    other = BallInMazeEnv("STG2", obs_mode="state", num_mazes=4, start_maze=20)
    a = [env.reset(seed=9)[0]] + [env.reset()[0] for _ in range(5)]
    b = [other.reset(seed=9)[0]] + [other.reset()[0] for _ in range(5)]
    np.testing.assert_array_equal(np.stack(a), np.stack(b))


def test_the_encoding_shows_merls_gates_where_they_are():
    encoding = maze_encoding(MazeSpec.merl()).reshape(4, MAZE_ENCODING_ANGLES)
    # Wall 0's one 50° gate is centred at 180°: the first and last bins (at ±180°) are open.
    assert encoding[0, 0] == 1.0 and encoding[0, -1] == 1.0
    assert encoding[0, MAZE_ENCODING_ANGLES // 2] == 0.0  # 0° is solid
    # Each wall's open share is its gates' total width.
    for k, wall in enumerate(MazeSpec.merl().walls):
        share = sum(g.width for g in wall.gates) / (2 * np.pi)
        assert abs(encoding[k].mean() - share) < 0.01


def test_pixels_show_each_episodes_maze():
    env = BallInMazeEnv("STG1", obs_mode="pixels", num_mazes=2)
    frames = {}
    for seed in range(10):
        obs, info = env.reset(seed=seed)
        frames.setdefault(info["maze"], obs)
    assert set(frames) == {0, 1}
    backgrounds = [
        BallInMazeEnv("STG1", obs_mode="pixels", maze=maze_number(i)).observer.raster.background for i in (0, 1)
    ]
    for number, frame in frames.items():
        # Away from the marble (on the outermost channel), the frame is the maze's own background.
        inner = (slice(25, 59), slice(25, 59))
        np.testing.assert_array_equal(frame[0][inner], backgrounds[number][inner])
    assert not np.array_equal(backgrounds[0], backgrounds[1])


def test_test_split_and_unlimited_mazes():
    env = BallInMazeEnv("STG1", obs_mode="state", num_mazes=3, maze_split="test")
    _, info = env.reset(seed=0)
    assert env.maze == maze_number(info["maze"], "test")
    unlimited = BallInMazeEnv("STG1", obs_mode="state", num_mazes=0)
    numbers = [unlimited.reset(seed=1)[1]["maze"]] + [unlimited.reset()[1]["maze"] for _ in range(9)]
    assert len(set(numbers)) == 10
    hashes = {maze_hash(maze_number(n)) for n in numbers}
    assert len(hashes) == 10


def test_bad_maze_arguments_are_refused_by_name():
    with pytest.raises(ValueError, match="unknown maze_split 'dev'; allowed: train, test"):
        BallInMazeEnv("STG1", num_mazes=3, maze_split="dev")
    with pytest.raises(ValueError, match="num_mazes must be an integer >= 0"):
        BallInMazeEnv("STG1", num_mazes=-2)
    with pytest.raises(ValueError, match="reset option 'maze' needs an env built with num_mazes"):
        BallInMazeEnv("STG1", obs_mode="state").reset(options={"maze": 1})
    with pytest.raises(ValueError, match="marble_radius"):
        BallInMazeEnv("STG1", obs_mode="state", num_mazes=3, randomize={"marble_radius": (0.95, 1.02)})


def test_pickled_env_keeps_its_maze_and_episode():
    env = BallInMazeEnv("STG1", obs_mode="state", num_mazes=50)
    env.reset(seed=3)
    for _ in range(5):
        env.step(1)
    clone = pickle.loads(pickle.dumps(env))
    assert clone.maze_number == env.maze_number and clone.maze == env.maze
    for action in (3, 3, 2, 0):
        a, b = env.step(action), clone.step(action)
        np.testing.assert_array_equal(a[0], b[0])


@pytest.mark.parametrize("obs_mode", ["state", "pixels"])
def test_vector_env_with_many_mazes_equals_sync_vector_env(obs_mode):
    num_envs, steps = 4, 120
    kwargs = dict(obs_mode=obs_mode, max_episode_steps=30, num_mazes=6)
    sync = gym.make_vec("BiMGame/STG1-v0", num_envs=num_envs, vectorization_mode="sync", **kwargs)
    fast = gym.make_vec("BiMGame/STG1-v0", num_envs=num_envs, **kwargs)
    obs_a, info_a = sync.reset(seed=11)
    obs_b, info_b = fast.reset(seed=11)
    np.testing.assert_array_equal(obs_a, obs_b)
    np.testing.assert_array_equal(info_a["maze"], info_b["maze"])
    mazes = set(info_b["maze"].tolist())
    for action in np.random.default_rng(0).integers(5, size=(steps, num_envs)):
        a, b = sync.step(action), fast.step(action)
        for x, y in zip(a[:4], b[:4]):
            np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(a[4]["maze"], b[4]["maze"])
        np.testing.assert_allclose(a[4]["geodesic_distance"], b[4]["geodesic_distance"], atol=1e-12)
        np.testing.assert_allclose(a[4]["goal_distance"], b[4]["goal_distance"], atol=1e-12)
        mazes |= set(b[4]["maze"].tolist())
    assert len(mazes) >= 4  # autoresets switched mazes during the test
    sync.close()
    fast.close()


def test_vector_env_reset_can_choose_each_envs_first_maze():
    env = gym.make_vec("BiMGame/STG1-v0", num_envs=3, obs_mode="state", num_mazes=100, maze_split="test")
    _, info = env.reset(seed=0, options={"maze": [7, 3, 99]})
    assert info["maze"].tolist() == [7, 3, 99]
    assert env.unwrapped._env_mazes[2] == maze_number(99, "test")
    with pytest.raises(ValueError, match=r"options\['maze'\] must hold 3 maze numbers"):
        env.reset(options={"maze": [1, 2]})
    with pytest.raises(ValueError, match=r"must be a maze number of this env's set \(0..99\)"):
        env.reset(options={"maze": [1, 2, 100]})
    with pytest.raises(ValueError, match="takes only the option 'maze'"):
        env.reset(options={"marble_xy": 1})
    plain = gym.make_vec("BiMGame/STG1-v0", num_envs=2, obs_mode="state")
    with pytest.raises(ValueError, match="needs a vector env built with num_mazes"):
        plain.reset(options={"maze": [0, 1]})


def test_the_goal_distance_is_each_episodes_maze_own_distance_to_the_tasks_goal():
    env = BallInMazeEnv("STG1", obs_mode="state", num_mazes=0)
    for seed in range(4):
        obs, info = env.reset(seed=seed)
        goal = env.maze.outermost_channel - 1  # STG1: through the outermost wall
        expected = env.maze.geodesic_distance(float(obs[0]), float(obs[1]), goal)
        assert info["goal_distance"][0] == pytest.approx(float(expected), abs=1e-6)  # obs: float32 positions
        assert 0 < info["goal_distance"][0] < info["geodesic_distance"][0]
