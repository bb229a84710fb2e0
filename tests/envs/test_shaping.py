"""Reward shaping: the formulas on hand-made transitions, the telescoping identities on the real
env, stacking, errors and pickling."""

from __future__ import annotations

import math
import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

import bimgame  # noqa: F401
from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.shaping import (
    GeodesicProgressReward,
    GeodesicProgressVectorEnv,
    GeodesicReward,
    PotentialShapedVectorEnv,
)
from bimgame.envs.vector import BallInMazeVectorEnv

NUM_ENVS = 3


def _transition(obs, tilt_x, reward, terminated=(), truncated=(), final=None):
    """One scripted step of 3 envs with 1-number observations. ``final`` maps an env index to the
    (obs, tilt_x) of its finished episode; ``goal_distance`` equals the observation. Rows of
    ``final_obs``/``final_info`` outside the mask are NaN, so reading them would show."""
    obs = np.array(obs, dtype=np.float64)[:, None]
    tilt = np.zeros((NUM_ENVS, 2))
    tilt[:, 0] = tilt_x
    infos = {"tilt": tilt, "goal_distance": obs.copy()}
    done = np.zeros(NUM_ENVS, dtype=bool)
    done[list(terminated)] = True
    trunc = np.zeros(NUM_ENVS, dtype=bool)
    trunc[list(truncated)] = True
    if final:
        final_obs = np.full((NUM_ENVS, 1), np.nan)
        final_tilt = np.full((NUM_ENVS, 2), np.nan)
        mask = np.zeros(NUM_ENVS, dtype=bool)
        for i, (o, t) in final.items():
            final_obs[i], final_tilt[i, 0], final_tilt[i, 1], mask[i] = o, t, 0.0, True
        infos.update(final_obs=final_obs, _final_obs=mask,
                     final_info={"tilt": final_tilt, "goal_distance": final_obs.copy()})
    return obs, np.array(reward, dtype=np.float64), done, trunc, infos


def _script():
    """Reset, then 4 steps: env 0 terminates and env 1 is truncated at step 2, env 2 is both at
    step 3; steps 3 and 4 follow those resets."""
    reset = _transition([1, 2, 3], [0.1, 0.2, 0.3], [0, 0, 0])
    steps = [
        _transition([1.5, 2.5, 3.5], 0.0, [0, 1, 0]),
        _transition([10, 20, 4], [0.0, 0.2, 0.1], [1, 0, -1], terminated=[0], truncated=[1],
                    final={0: (4, 0.5), 1: (6, -0.1)}),
        _transition([11, 21, 30], 0.0, [0, 0, 0], terminated=[2], truncated=[2], final={2: (5, 0.0)}),
        _transition([12, 22, 31], 0.0, [0, 0, 0]),
    ]
    return reset, steps


class ScriptedVectorEnv(gym.vector.VectorEnv):
    """A SAME_STEP vector env that replays :func:`_script` (fresh info dicts per instance)."""

    def __init__(self, autoreset_mode: AutoresetMode = AutoresetMode.SAME_STEP):
        self.num_envs = NUM_ENVS
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (1,), np.float64)
        self.single_action_space = spaces.Discrete(2)
        self.observation_space = batch_space(self.single_observation_space, NUM_ENVS)
        self.action_space = batch_space(self.single_action_space, NUM_ENVS)
        self.autoreset_mode = autoreset_mode
        self.metadata = {"autoreset_mode": autoreset_mode}
        self._reset, self._steps = _script()
        self.raw_rewards: list[np.ndarray] = []

    def reset(self, *, seed=None, options=None):
        obs, _, _, _, infos = self._reset
        return obs, infos

    def step(self, actions):
        result = self._steps.pop(0)
        self.raw_rewards.append(result[1].copy())
        return result


def _potential(obs: np.ndarray, tilt: np.ndarray) -> np.ndarray:
    return obs[:, 0] * 2 + tilt[:, 0]


def _run(env, steps=4):
    env.reset(seed=0)
    return [env.step(np.zeros(NUM_ENVS, dtype=np.int64)) for _ in range(steps)]


def test_potential_shaping_matches_formula_by_hand():
    gamma = 0.5
    results = _run(PotentialShapedVectorEnv(ScriptedVectorEnv(), _potential, gamma))
    # Φ = 2·obs + tilt_x. Reset: Φ = [2.1, 4.2, 6.3]; step 1: Φ = [3, 5, 7].
    expected = [
        [0 + gamma * 3 - 2.1, 1 + gamma * 5 - 4.2, 0 + gamma * 7 - 6.3],
        # env 0 terminated: Φ(s') = 0; env 1 truncated: Φ(final) = 2·6 − 0.1; env 2 runs on.
        [1 + gamma * 0 - 3, 0 + gamma * (12 - 0.1) - 5, -1 + gamma * (8 + 0.1) - 7],
        # envs 0, 1 start from their new episodes' Φ = 20, 40.2; env 2 terminated (and truncated).
        [gamma * 22 - 20, gamma * 42 - 40.2, 0 + gamma * 0 - 8.1],
        # env 2 starts from its new episode's Φ = 60.
        [gamma * 24 - 22, gamma * 44 - 42, gamma * 62 - 60],
    ]
    raw = [[0, 1, 0], [1, 0, -1], [0, 0, 0], [0, 0, 0]]
    for (_, reward, _, _, infos), want, task in zip(results, expected, raw):
        np.testing.assert_allclose(reward, want, rtol=0, atol=1e-12)
        assert infos["task_reward"].dtype == np.float64
        np.testing.assert_array_equal(infos["task_reward"], task)
        np.testing.assert_allclose(infos["shaping"], np.array(want) - task, rtol=0, atol=1e-12)


def test_geodesic_progress_matches_formula_by_hand():
    coef = 2.0
    results = _run(GeodesicProgressVectorEnv(ScriptedVectorEnv(), coef=coef))
    # d = obs. At a termination d(s') is the real final distance (env 2, step 3), not zeroed.
    expected = [
        [0 + coef * (1 - 1.5), 1 + coef * (2 - 2.5), 0 + coef * (3 - 3.5)],
        [1 + coef * (1.5 - 4), 0 + coef * (2.5 - 6), -1 + coef * (3.5 - 4)],
        [coef * (10 - 11), coef * (20 - 21), coef * (4 - 5)],
        [coef * (11 - 12), coef * (21 - 22), coef * (30 - 31)],
    ]
    for (_, reward, _, _, _), want in zip(results, expected):
        np.testing.assert_allclose(reward, want, rtol=0, atol=1e-12)


@pytest.mark.parametrize("outer", ["potential", "geodesic"])
def test_stacked_wrappers_keep_the_task_reward(outer):
    base = ScriptedVectorEnv()
    inner = PotentialShapedVectorEnv(base, _potential, 0.9)
    env = (PotentialShapedVectorEnv(inner, lambda obs, tilt: -obs[:, 0], 0.9) if outer == "potential"
           else GeodesicProgressVectorEnv(inner, coef=3.0))
    alone = _run(PotentialShapedVectorEnv(ScriptedVectorEnv(), _potential, 0.9))
    for (_, reward, _, _, infos), raw, (_, inner_reward, _, _, _) in zip(_run(env), base.raw_rewards, alone):
        np.testing.assert_array_equal(infos["task_reward"], raw)
        np.testing.assert_allclose(reward, infos["task_reward"] + infos["shaping"], rtol=0, atol=1e-12)
        assert not np.allclose(reward, inner_reward)  # the outer wrapper did add its own term


def _random_actions(steps: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(5, size=(steps, NUM_ENVS))


def _same_step_env(max_episode_steps: int = 20) -> BallInMazeVectorEnv:
    return BallInMazeVectorEnv(NUM_ENVS, task="FULL", obs_mode="state", max_episode_steps=max_episode_steps,
                               autoreset_mode="same_step")


def test_geodesic_reward_telescopes_per_episode_on_the_real_env():
    coef = 10.0
    env = GeodesicProgressVectorEnv(_same_step_env(), coef=coef)
    twin = _same_step_env()  # unwrapped, same seed: its rewards are the task rewards
    _, infos = env.reset(seed=3)
    twin.reset(seed=3)
    d_start = infos["goal_distance"].sum(axis=1)
    added = np.zeros(NUM_ENVS)
    episodes = 0
    for actions in _random_actions(70):
        _, reward, terminated, truncated, infos = env.step(actions)
        _, raw, *_ = twin.step(actions)
        np.testing.assert_array_equal(infos["task_reward"], raw)
        added += reward - infos["task_reward"]
        for i in np.flatnonzero(terminated | truncated):
            d_end = infos["final_info"]["goal_distance"][i].sum()
            assert added[i] == pytest.approx(coef * (d_start[i] - d_end), abs=1e-9)
            added[i] = 0.0
            d_start[i] = infos["goal_distance"][i].sum()  # the new episode's start
            episodes += 1
    assert episodes >= 2 * NUM_ENVS
    assert np.abs(added).max() > 0  # the unfinished episodes got dense rewards too


def test_single_env_wrapper_matches_vector_wrapper():
    steps, seed, limit = 50, 7, 20
    actions = _random_actions(steps, seed=1)
    vector = GeodesicProgressVectorEnv(_same_step_env(limit))
    vector.reset(seed=seed)
    vector_rewards = np.array([vector.step(a)[1] for a in actions])
    for i in range(NUM_ENVS):
        single = GeodesicProgressReward(gym.wrappers.TimeLimit(BallInMazeEnv("FULL", obs_mode="state"), limit))
        single.reset(seed=seed + i)  # the vector env seeds env i with seed + i
        for t in range(steps):
            _, reward, terminated, truncated, info = single.step(actions[t, i])
            assert reward == pytest.approx(vector_rewards[t, i], abs=1e-9)
            assert reward == pytest.approx(info["task_reward"] + info["shaping"], abs=1e-12)
            if terminated or truncated:
                single.reset()


def test_potential_of_geodesic_distance_equals_geodesic_progress_without_terminations():
    """With Φ = −coef·d(obs) and γ = 1, potential shaping is the geodesic progress reward whenever
    no episode terminates (truncations use Φ(final_obs)); also through Gymnasium's SyncVectorEnv,
    whose final_obs is an object array."""
    coef, limit = 10.0, 15
    maze = BallInMazeVectorEnv(1, task="FULL", obs_mode="state").maze

    def potential(obs, tilt):
        return -coef * maze.geodesic_distance(obs[:, 0].astype(np.float64), obs[:, 1].astype(np.float64))

    geodesic = GeodesicProgressVectorEnv(_same_step_env(limit), coef=coef)
    shaped = PotentialShapedVectorEnv(_same_step_env(limit), potential, gamma=1.0)
    sync = PotentialShapedVectorEnv(
        gym.make_vec("BiMGame/FULL-v0", num_envs=NUM_ENVS, vectorization_mode="sync", obs_mode="state",
                     max_episode_steps=limit, vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP}),
        potential, gamma=1.0)
    for env in (geodesic, shaped, sync):
        env.reset(seed=11)
    truncations = 0
    for actions in _random_actions(40, seed=2):
        _, want, terminated, truncated, _ = geodesic.step(actions)
        _, got, *_ = shaped.step(actions)
        _, got_sync, *_ = sync.step(actions)
        assert not terminated.any()
        truncations += int(truncated.sum())
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-5)  # float32 positions in obs
        np.testing.assert_allclose(got_sync, got, rtol=0, atol=1e-12)
    assert truncations >= 2 * NUM_ENVS


def test_next_step_env_is_rejected():
    for env in (BallInMazeVectorEnv(2, task="FULL", obs_mode="state"),
                ScriptedVectorEnv(AutoresetMode.NEXT_STEP)):
        with pytest.raises(ValueError, match="autoreset_mode SAME_STEP, got NEXT_STEP.*final_obs"):
            PotentialShapedVectorEnv(env, _potential, 0.99)
        with pytest.raises(ValueError, match="autoreset_mode SAME_STEP, got NEXT_STEP.*final_info"):
            GeodesicProgressVectorEnv(env)
        with pytest.raises(ValueError, match="autoreset_mode"):
            GeodesicReward()(env)


@pytest.mark.parametrize("gamma", [-0.1, 1.5, math.nan, "0.9", True, None])
def test_bad_gamma_is_rejected(gamma):
    with pytest.raises(ValueError, match=r"gamma must be a number in \[0, 1\]"):
        PotentialShapedVectorEnv(ScriptedVectorEnv(), _potential, gamma)


@pytest.mark.parametrize("coef", [0, -1.0, math.inf, math.nan, "1", True, None])
def test_bad_coef_is_rejected(coef):
    for make in (lambda: GeodesicReward(coef), lambda: GeodesicProgressVectorEnv(ScriptedVectorEnv(), coef),
                 lambda: GeodesicProgressReward(BallInMazeEnv("FULL", obs_mode="state"), coef)):
        with pytest.raises(ValueError, match="coef must be a finite number > 0"):
            make()


def test_bad_potentials_and_misuse_are_rejected():
    with pytest.raises(TypeError, match="potential must be callable"):
        PotentialShapedVectorEnv(ScriptedVectorEnv(), 1.0, 0.9)
    env = PotentialShapedVectorEnv(ScriptedVectorEnv(), lambda obs, tilt: obs, 0.9)  # (3, 1), not (3,)
    with pytest.raises(ValueError, match=r"potential returned shape \(3, 1\).*expected \(3,\)"):
        env.reset()
    env = PotentialShapedVectorEnv(ScriptedVectorEnv(), lambda obs, tilt: obs[:, 0] * np.nan, 0.9)
    with pytest.raises(ValueError, match="non-finite"):
        env.reset()
    with pytest.raises(RuntimeError, match="reset"):
        PotentialShapedVectorEnv(ScriptedVectorEnv(), _potential, 0.9).step(np.zeros(NUM_ENVS, dtype=np.int64))
    with pytest.raises(RuntimeError, match="reset"):
        GeodesicProgressVectorEnv(ScriptedVectorEnv()).step(np.zeros(NUM_ENVS, dtype=np.int64))
    with pytest.raises(RuntimeError, match="reset"):
        GeodesicProgressReward(BallInMazeEnv("FULL", obs_mode="state")).step(0)


def test_geodesic_reward_factory_pickles():
    factory = pickle.loads(pickle.dumps(GeodesicReward(5.0)))
    assert factory == GeodesicReward(5.0) and factory.coef == 5.0
    assert GeodesicReward().coef == 10.0
    env = factory(_same_step_env())
    assert isinstance(env, GeodesicProgressVectorEnv) and env.coef == 5.0
