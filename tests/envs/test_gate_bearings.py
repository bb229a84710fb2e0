"""Gate bearings: each wall's nearest gate as seen from the marble, in the state observation."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import bimgame  # noqa: F401
from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.gate_bearings import BEARING_VALUES, GateBearings, gate_bearings_size
from bimgame.envs.mazes import maze_encoding
from bimgame.sim.maze import Gate, MazeSpec

BIN = 2 * math.pi / 32


def _maze(gates_of_wall_0: tuple[Gate, ...]) -> MazeSpec:
    merl = MazeSpec.merl()
    walls = list(merl.walls)
    walls[0] = type(walls[0])(walls[0].inner_radius, walls[0].outer_radius, gates_of_wall_0)
    return merl.replace(walls=tuple(walls))


def test_bearing_to_the_nearest_gate_across_the_wrap():
    """At 170°, a gate at -170° (20° ahead) is nearer than one at 120° (50° behind): its bearing is
    +20°, not -340°; the half-width is in encoding bins (wall 0, the innermost: wide gates)."""
    maze = _maze((Gate.deg(-170, 50), Gate.deg(120, 60)))
    bearings = GateBearings.of(maze)
    angle = math.radians(170)
    out = bearings(np.array([0.1 * math.cos(angle)]), np.array([0.1 * math.sin(angle)]))
    assert out.shape == (1, gate_bearings_size(maze)) == (1, BEARING_VALUES * 4)
    sin, cos, half = out[0, :3]
    assert math.degrees(math.atan2(sin, cos)) == pytest.approx(20, abs=1e-4)
    assert half == pytest.approx(math.radians(25) / BIN, rel=1e-5)
    # Turned to 100°, the 120° gate is the nearest: 20° ahead, 30° half-width.
    angle = math.radians(100)
    sin, cos, half = bearings(np.array([math.cos(angle)]), np.array([math.sin(angle)]))[0, :3]
    assert math.degrees(math.atan2(sin, cos)) == pytest.approx(20, abs=1e-4)
    assert half == pytest.approx(math.radians(30) / BIN, rel=1e-5)


def test_rows_show_their_own_mazes_and_refuse_other_boards():
    a, b = _maze((Gate.deg(0, 50),)), _maze((Gate.deg(90, 50),))
    table = GateBearings(a, 2, 4)
    table.set_row(0, a)
    table.set_row(1, b)
    out = table(np.array([1.0, 1.0]), np.array([0.0, 0.0]))  # both marbles at 0°
    assert out[0, :2] == pytest.approx([0.0, 1.0], abs=1e-6)  # straight ahead
    assert out[1, :2] == pytest.approx([1.0, 0.0], abs=1e-6)  # 90° counter-clockwise
    with pytest.raises(ValueError, match="more than the table's 1"):
        GateBearings(a, 1, 1).set_row(0, _maze((Gate.deg(0, 50), Gate.deg(90, 50))))


def test_env_observations_end_with_the_marbles_bearings():
    env = BallInMazeEnv("STG1", obs_mode="state", num_mazes=0, gate_bearings=True)
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=4)
    size = gate_bearings_size(env.maze)
    for action in [1, 1, 3, 0, 2] * 6:
        encoding = maze_encoding(env.maze)
        assert obs.shape == (7 + len(encoding) + size,) == env.observation_space.shape
        np.testing.assert_array_equal(obs[7 : 7 + len(encoding)], encoding)
        expected = GateBearings.of(env.maze)(obs[:1].astype(float), obs[1:2].astype(float))[0]
        np.testing.assert_allclose(obs[-size:], expected, atol=1e-6)
        obs, *_ = env.step(action)
    env.close()


def test_gate_bearings_need_many_mazes_and_state_observations():
    with pytest.raises(ValueError, match="gate_bearings needs num_mazes and obs_mode='state'"):
        BallInMazeEnv("STG1", obs_mode="state", gate_bearings=True)
    with pytest.raises(ValueError, match="gate_bearings needs num_mazes and obs_mode='state'"):
        BallInMazeEnv("STG1", obs_mode="pixels", num_mazes=3, gate_bearings=True)
    with pytest.raises(ValueError, match="gate_bearings must be True or False"):
        BallInMazeEnv("STG1", obs_mode="state", num_mazes=3, gate_bearings="yes")


def test_vector_env_bearings_equal_sync_vector_env():
    kwargs = dict(obs_mode="state", max_episode_steps=30, num_mazes=6, gate_bearings=True)
    sync = gym.make_vec("BiMGame/STG1-v0", num_envs=3, vectorization_mode="sync", **kwargs)
    fast = gym.make_vec("BiMGame/STG1-v0", num_envs=3, **kwargs)
    np.testing.assert_allclose(sync.reset(seed=5)[0], fast.reset(seed=5)[0], atol=1e-6)
    for action in np.random.default_rng(1).integers(5, size=(80, 3)):
        np.testing.assert_allclose(sync.step(action)[0], fast.step(action)[0], atol=1e-6)
    sync.close()
    fast.close()
