"""Episodes started from given physics states: the single env's ``reset(options={"sim_state": …})``
and the vector env's ``start_sampler``, both exact and both refusing states no episode can start from."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.sim.maze import MazeSpec

SPEC = MazeSpec.merl()


def _record(task: str = "FULL", steps: int = 150, seed: int = 3, obs_mode: str = "state"):
    """An episode of seeded random actions: its actions, and the state, observation and channels
    before every step and after the last."""
    env = BallInMazeEnv(task, obs_mode=obs_mode)
    actions = np.random.default_rng(seed).integers(0, 5, size=steps)
    obs, info = env.reset(seed=seed)
    states, observations, channels = [env.sim.get_state()], [obs], [info["channel"]]
    for action in actions:
        obs, _, terminated, _, info = env.step(int(action))
        states.append(env.sim.get_state())
        observations.append(obs)
        channels.append(info["channel"])
        assert not terminated, "the test wants a random episode that does not end"
    env.close()
    return actions, np.array(states), np.array(observations), np.array(channels)


@pytest.mark.parametrize("obs_mode", ["state", "pixels"])
def test_reset_from_a_recorded_state_replays_the_episode_bit_for_bit(obs_mode):
    actions, states, observations, channels = _record(obs_mode=obs_mode)
    env = BallInMazeEnv("FULL", obs_mode=obs_mode)
    env.reset(seed=99)  # an earlier episode of this env must not matter
    for _ in range(7):
        env.step(1)
    for t in (0, 1, 60, 149):
        obs, info = env.reset(options={"sim_state": states[t]})
        assert np.array_equal(env.sim.get_state(), states[t])
        assert np.array_equal(obs, observations[t]) and np.array_equal(info["channel"], channels[t])
        for k, action in enumerate(actions[t:], start=t + 1):
            obs, _, _, _, info = env.step(int(action))
            assert np.array_equal(env.sim.get_state(), states[k]), f"state {k} from the state at step {t}"
            assert np.array_equal(obs, observations[k]), f"observation {k} from the state at step {t}"


def test_reset_from_a_state_past_the_goal_is_allowed_and_ends_at_the_first_step():
    env = BallInMazeEnv("STG1", obs_mode="state")
    env.reset(options={"marble_xy": [[SPEC.channel_centre_radius(3), 0.0]]})  # past wall 3: STG1's goal
    state = env.sim.get_state()
    _, info = env.reset(options={"sim_state": state})
    assert info["channel"].tolist() == [3]
    _, reward, terminated, _, _ = env.step(0)
    assert terminated and reward == 0.0


def test_reset_refuses_bad_sim_states_naming_the_option():
    env = BallInMazeEnv("FULL", obs_mode="state")
    env.reset(seed=0)
    good = env.sim.get_state()
    layout = env.sim.layout
    with pytest.raises(ValueError, match=r"options\['sim_state'\] must have shape \(%d,\)" % good.size):
        env.reset(options={"sim_state": good[:-1]})
    nan = good.copy()
    nan[3] = np.nan
    with pytest.raises(ValueError, match=r"options\['sim_state'\] is not finite"):
        env.reset(options={"sim_state": nan})
    tilted = good.copy()
    tilted[layout.tilt[0]] = math.radians(6.0)
    with pytest.raises(ValueError, match=r"options\['sim_state'\]: the board tilt .* exceeds ±max_tilt"):
        env.reset(options={"sim_state": tilted})
    target = good.copy()
    target[layout.target_tilt[1]] = -math.radians(5.01)
    with pytest.raises(ValueError, match=r"options\['sim_state'\]: the target tilt .* exceeds ±max_tilt"):
        env.reset(options={"sim_state": target})
    inside = good.copy()
    inside[layout.marble_pos[0]] = (SPEC.walls[2].mid_radius, 0.0, SPEC.marble_radius)  # wall 2 has a gate at 0°
    env.reset(options={"sim_state": inside})  # in a gate: fine
    inside[layout.marble_pos[0]] = (0.0, -SPEC.walls[1].mid_radius, SPEC.marble_radius)
    with pytest.raises(ValueError, match=r"options\['sim_state'\]: marble_xy\[0\] .* overlaps walls\[1\]"):
        env.reset(options={"sim_state": inside})
    # Pressed into the rim by less than STATE_OVERLAP, as in a fast impact: fine; deeper: refused.
    rm = SPEC.marble_radius
    for sink, ok in [(0.7 * rm, True), (0.8 * rm, False)]:
        rim = good.copy()
        rim[layout.marble_pos[0]] = (0.0, SPEC.rim_radius - rm + sink, rm)
        if ok:
            env.reset(options={"sim_state": rim})
        else:
            with pytest.raises(ValueError, match=r"overlaps the rim .*overlaps up to 4\.76 mm are allowed"):
                env.reset(options={"sim_state": rim})
    flying = good.copy()
    flying[layout.marble_pos[0][2]] = 0.05
    with pytest.raises(ValueError, match=r"options\['sim_state'\]: marble 0's centre is 50\.00 mm above"):
        env.reset(options={"sim_state": flying})
    with pytest.raises(ValueError, match="'marble_xy' and 'sim_state' exclude each other"):
        env.reset(options={"sim_state": good, "marble_xy": [[0.088, 0.0]]})
    with pytest.raises(ValueError, match=r"unknown reset options \['state'\]; allowed: 'marble_xy', 'sim_state'"):
        env.reset(options={"state": good})
    with pytest.raises(RuntimeError, match="reset"):  # a refused reset leaves no episode running
        env.step(0)


def test_states_of_a_real_run_pass_the_check():
    """Soft contacts let a simulated marble sink into walls and the rim: every state of a run, and
    with it every expert state, must still be a valid start."""
    env = BallInMazeVectorEnv(16, task="FULL", obs_mode="state", max_episode_steps=400)
    env.reset(seed=1)
    rng = np.random.default_rng(1)
    actions = rng.integers(0, 5, size=16)
    single = BallInMazeEnv("FULL", obs_mode="state")
    for step in range(400):
        actions = np.where(rng.random(16) < 0.05, rng.integers(0, 5, size=16), actions)  # long pushes
        env.step(actions)
        if step % 10 == 0:
            for state in env._states:
                single.reset(options={"sim_state": state})


# ------------------------------------------------------------------ the vector env's start_sampler
class FixedSampler:
    """Starts env ``index`` from ``states[index]`` (None: the task's start), tagged ``tags[index]``;
    records its calls."""

    def __init__(self, states, tags):
        self.states, self.tags, self.calls = states, tags, []

    def __call__(self, index, rng):
        self.calls.append(index)
        return self.states[index], self.tags[index]


@pytest.mark.parametrize("mode", ["next_step", "same_step"])
def test_sampled_states_start_the_episodes_on_reset_and_on_autoreset(mode):
    _, states, observations, _ = _record()
    sampler = FixedSampler([states[40], None, states[90]], [7, -1, 3])
    env = BallInMazeVectorEnv(3, task="FULL", obs_mode="state", max_episode_steps=5, autoreset_mode=mode,
                              start_sampler=sampler)
    obs, _ = env.reset(seed=0)
    assert sampler.calls == [0, 1, 2] and env.start_tags.tolist() == [7, -1, 3]
    assert env.start_tags.dtype == np.int64
    assert np.array_equal(env._states[0], states[40]) and np.array_equal(env._states[2], states[90])
    assert np.array_equal(obs[0], observations[40]) and np.array_equal(obs[2], observations[90])
    plain = BallInMazeVectorEnv(3, task="FULL", obs_mode="state")
    assert np.array_equal(obs[1], plain.reset(seed=0)[0][1])  # None: the task's own start, same draw
    sampler.tags = [8, -1, 4]
    for _ in range(5 if mode == "same_step" else 6):
        obs, *_ = env.step(np.zeros(3, dtype=np.int64))
    assert sampler.calls == [0, 1, 2, 0, 1, 2] and env.start_tags.tolist() == [8, -1, 4]
    assert np.array_equal(env._states[0], states[40]) and np.array_equal(obs[2], observations[90])


def test_a_sampled_start_steps_exactly_as_the_single_env_from_that_state():
    actions, states, observations, _ = _record()
    env = BallInMazeVectorEnv(1, task="FULL", obs_mode="state", start_sampler=lambda i, rng: (states[20], 0))
    env.reset(seed=0)
    for k, action in enumerate(actions[20:60], start=21):
        obs, *_ = env.step(np.array([action]))
        assert np.array_equal(env._states[0], states[k]) and np.array_equal(obs[0], observations[k])


def test_without_a_sampler_tags_are_zero_and_starts_unchanged():
    a = BallInMazeVectorEnv(4, task="STG1", obs_mode="state")
    b = BallInMazeVectorEnv(4, task="STG1", obs_mode="state", start_sampler=lambda i, rng: (None, i))
    obs_a, _ = a.reset(seed=5)
    obs_b, _ = b.reset(seed=5)
    assert np.array_equal(obs_a, obs_b)
    assert a.start_tags.tolist() == [0, 0, 0, 0] and b.start_tags.tolist() == [0, 1, 2, 3]


def test_samplers_drawing_from_the_env_rng_are_deterministic():
    _, states, _, _ = _record()

    def sampler(index, rng):
        t = int(rng.integers(len(states)))
        return (states[t], t) if rng.random() < 0.7 else (None, -1)

    runs = []
    for _ in range(2):
        env = BallInMazeVectorEnv(4, task="FULL", obs_mode="state", max_episode_steps=3,
                                  autoreset_mode=AutoresetMode.SAME_STEP, start_sampler=sampler)
        obs, _ = env.reset(seed=11)
        record = [obs.copy(), env.start_tags.copy()]
        for _ in range(9):
            record += [env.step(np.full(4, 3))[0], env.start_tags.copy()]
        runs.append(record)
    for x, y in zip(*runs):
        assert np.array_equal(x, y)
    assert len({tuple(tags) for tags in runs[0][1::2]}) > 1  # the starts did change


def test_bad_samplers_and_bad_sampled_states_raise_clear_errors():
    _, states, _, _ = _record()
    with pytest.raises(ValueError, match="start_sampler must be None or a callable"):
        BallInMazeVectorEnv(2, task="FULL", start_sampler=3)
    bad = states[10].copy()
    bad[BallInMazeVectorEnv(1, task="FULL").sim.layout.tilt[1]] = 0.2
    env = BallInMazeVectorEnv(2, task="FULL", obs_mode="state",
                              start_sampler=lambda i, rng: (bad if i == 1 else None, 5))
    with pytest.raises(ValueError, match=r"start_sampler's state for env 1 \(tag 5\): the board tilt"):
        env.reset(seed=0)
    env = BallInMazeVectorEnv(2, task="FULL", obs_mode="state", start_sampler=lambda i, rng: (states[0][:4], 5))
    with pytest.raises(ValueError, match=r"start_sampler's state for env 0 \(tag 5\) must have shape"):
        env.reset(seed=0)
    for result in (states[0], (states[0], 1.5), (None,)):
        env = BallInMazeVectorEnv(2, task="FULL", obs_mode="state", start_sampler=lambda i, rng, r=result: r)
        with pytest.raises(ValueError, match=r"must return \(state or None, integer tag\); for env 0"):
            env.reset(seed=0)
