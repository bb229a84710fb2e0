"""The labyrinth's pixel observation with the marble's motion (bimgame.envs.labyrinth_pixels): two
frames, the previous observation's then this one's, each the plain pixel observation of its step; the
same frame twice at an episode's first observation; the marble visibly moves between them on a tilted
board; Gymnasium's checker accepts it. The learners' side: tests/learn/test_labyrinth_training.py."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.envs.labyrinth_pixels import pixel_frames, pixel_space

STEPS = 40


def twin_episode(control_hz: int = 55) -> tuple[np.ndarray, np.ndarray]:
    """One seeded episode observed with and without the motion: (T+1, 2, S, S) and (T+1, 1, S, S)."""
    stacked = LabyrinthEnv("easy", obs_mode="pixels", motion=True, control_hz=control_hz)
    plain = LabyrinthEnv("easy", obs_mode="pixels", control_hz=control_hz)
    frames, singles = [stacked.reset(seed=5)[0]], [plain.reset(seed=5)[0]]
    rng = np.random.default_rng(2)
    for _ in range(STEPS):
        action = rng.uniform(-1, 1, 2).astype(np.float32)
        obs, _, terminated, _, _ = stacked.step(action)
        frames.append(obs)
        singles.append(plain.step(action)[0])
        if terminated:
            break
    return np.array(frames), np.array(singles)


@pytest.mark.parametrize("control_hz", [55, 30])
def test_the_two_frames_are_the_previous_and_the_current_observation(control_hz):
    frames, singles = twin_episode(control_hz)
    assert frames.dtype == np.uint8 and frames.shape[1:] == (2, 84, 84)
    np.testing.assert_array_equal(frames[:, 1:], singles)  # the second frame is the plain observation
    np.testing.assert_array_equal(frames[1:, :1], singles[:-1])  # the first is the previous step's
    np.testing.assert_array_equal(frames[0, 0], frames[0, 1])  # an episode's first observation: no motion
    moved = [np.any(f[0] != f[1]) for f in frames[1:]]
    assert sum(moved) >= len(moved) // 2  # the marble rolls on a board tilted by random actions


def test_the_space_and_gymnasiums_checker():
    env = LabyrinthEnv("easy", obs_mode="pixels", motion=True, obs_size=64)
    assert env.observation_space == pixel_space(64, motion=True)
    assert env.observation_space.shape == (2, 64, 64) and pixel_frames(False) == 1
    check_env(env, skip_render_check=True)
