"""The batched vector env reproduces Gymnasium's SyncVectorEnv exactly, faster."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import bimgame  # noqa: F401
from bimgame.envs.vector import BallInMazeVectorEnv


@pytest.mark.parametrize("obs_mode", ["state", "pixels"])
def test_vector_env_equals_sync_vector_env(obs_mode):
    num_envs, steps = 4, 120
    # A short time limit so that truncation and next-step autoreset happen during the test.
    sync = gym.make_vec("BiMGame/STG1-v0", num_envs=num_envs, vectorization_mode="sync",
                        obs_mode=obs_mode, max_episode_steps=40)
    fast = gym.make_vec("BiMGame/STG1-v0", num_envs=num_envs, obs_mode=obs_mode, max_episode_steps=40)
    assert isinstance(fast, BallInMazeVectorEnv)
    obs_a, _ = sync.reset(seed=5)
    obs_b, _ = fast.reset(seed=5)
    assert np.array_equal(obs_a, obs_b)
    actions = np.random.default_rng(0).integers(5, size=(steps, num_envs))
    truncations = 0
    for action in actions:
        a = sync.step(action)
        b = fast.step(action)
        for x, y in zip(a[:4], b[:4]):
            np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(a[4]["channel"], b[4]["channel"])
        np.testing.assert_allclose(a[4]["geodesic_distance"], b[4]["geodesic_distance"], atol=1e-12)
        truncations += int(b[3].sum())
    assert truncations >= num_envs  # every env was truncated and autoreset at least once
    sync.close()
    fast.close()


def test_vector_env_terminates_and_autoresets_next_step():
    env = BallInMazeVectorEnv(2, task="STG1", obs_mode="state", max_episode_steps=3)
    env.reset(seed=0)
    for _ in range(3):
        _, _, terminated, truncated, _ = env.step(np.zeros(2, dtype=np.int64))
    assert truncated.all() and not terminated.any()
    obs, reward, terminated, truncated, _ = env.step(np.zeros(2, dtype=np.int64))
    # The reset step: fresh starts, no reward, no termination.
    assert not truncated.any() and not terminated.any() and not reward.any()
    assert np.all(obs[:, 2:6] == 0)


def test_vector_env_bad_actions():
    env = BallInMazeVectorEnv(3, task="FULL", obs_mode="state")
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(3, dtype=np.int64))
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"3 integers in 0\.\.4"):
        env.step(np.array([0, 1, 7]))
    with pytest.raises(ValueError, match=r"3 integers in 0\.\.4"):
        env.step(np.array([0, 1]))
    with pytest.raises(ValueError, match="num_envs"):
        BallInMazeVectorEnv(0)


def test_same_step_autoreset_gives_the_same_transitions_as_next_step():
    """SAME_STEP drops NEXT_STEP's reset steps: final observations and the reset observations that
    follow are the ones NEXT_STEP returns one call apart."""
    kwargs = dict(task="STG1", obs_mode="state", max_episode_steps=15)
    nxt = BallInMazeVectorEnv(2, **kwargs)
    same = BallInMazeVectorEnv(2, autoreset_mode="same_step", **kwargs)
    assert same.metadata["autoreset_mode"].value == "SameStep"
    rng = np.random.default_rng(3)
    obs_n, _ = nxt.reset(seed=7)
    obs_s, _ = same.reset(seed=7)
    finished = 0
    for _ in range(40):
        actions = rng.integers(0, 5, size=2)
        obs_n, r_n, term_n, trunc_n, _ = nxt.step(actions)
        obs_s, r_s, term_s, trunc_s, info_s = same.step(actions)
        np.testing.assert_array_equal(r_n, r_s)
        np.testing.assert_array_equal(term_n | trunc_n, term_s | trunc_s)
        done = term_n | trunc_n
        if done.any():
            finished += int(done.sum())
            np.testing.assert_array_equal(info_s["_final_obs"], done)
            np.testing.assert_array_equal(info_s["final_obs"][done], obs_n[done])
            # NEXT_STEP spends one call resetting; the other env must wait, so only step when all done.
            assert done.all(), "the test keeps both envs in lock-step (same time limit, no success)"
            obs_n, r_n, *_ = nxt.step(actions)
            np.testing.assert_array_equal(r_n, 0)
        np.testing.assert_array_equal(obs_n, obs_s)
    assert finished >= 4


def test_state_info_is_the_state_of_the_frame_it_comes_with():
    """``infos["state"]`` lines up with the pixel observation of the same step — also across
    same-step autoresets, where both belong to the new episode — and ``final_info`` holds the state
    of ``final_obs``: re-rendering the reported marble position gives the frame exactly."""
    from bimgame.sim.render import MazeRenderer
    env = BallInMazeVectorEnv(8, task="STG1", obs_mode="pixels", max_episode_steps=15, autoreset_mode="same_step",
                              state_info=True)
    renderer = MazeRenderer(env.maze, 84)
    obs, info = env.reset(seed=4)
    rng = np.random.default_rng(0)
    resets = 0
    for _ in range(40):
        assert info["state"].shape == (8, 7) and info["state"].dtype == np.float32
        np.testing.assert_array_equal(renderer.gray(info["state"][:, None, :2].astype(np.float64))[:, None], obs)
        np.testing.assert_array_equal(info["state"][:, 6], info["channel"][:, 0])
        np.testing.assert_allclose(info["state"][:, 4:6], info["tilt"], atol=1e-6)
        obs, _, terminated, truncated, info = env.step(rng.integers(0, 5, 8))
        if "final_obs" in info:
            done = info["_final_obs"]
            resets += int(done.sum())
            final_state = info["final_info"]["state"][done]
            np.testing.assert_array_equal(renderer.gray(final_state[:, None, :2].astype(np.float64))[:, None],
                                          info["final_obs"][done])
    assert resets >= 8
    plain = BallInMazeVectorEnv(2, task="STG1", obs_mode="pixels")
    assert "state" not in plain.reset(seed=0)[1]
    with pytest.raises(ValueError, match="state_info"):
        BallInMazeVectorEnv(2, state_info="yes")
