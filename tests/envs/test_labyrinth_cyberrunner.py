"""CyberRunner's observation with the marble's motion (bimgame.envs.labyrinth_cyberrunner): the motion
is the change of the observed position times the control rate — the marble's velocity, measured
against the physics — zero at an episode's first observation, in both the Dict and the flat form; a
bad flat size or a motion outside CyberRunner's observation is refused by name."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from bimgame.envs.labyrinth_cyberrunner import (
    CYBERRUNNER_FLAT_SIZE,
    MOTION_SCALE,
    cyberrunner_flat_size,
    flatten_cyberrunner,
    unflatten_cyberrunner,
)
from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.envs.puzzles import puzzle

STEPS = 120


def twin_episode(control_hz: int, action_type: str = "continuous"):
    """The same seeded episode observed twice: CyberRunner's observation with motion, and the state
    (board-frame position and velocity) — one random tilt rate held for 40 steps at a time."""
    kwargs = dict(control_hz=control_hz, action_type=action_type, end_off_path=False)  # roll anywhere but a hole
    with_motion = LabyrinthEnv("easy", obs_mode="cyberrunner", motion=True, **kwargs)
    state = LabyrinthEnv("easy", obs_mode="state", **kwargs)
    rng = np.random.default_rng(3)
    first, _ = with_motion.reset(seed=11)
    states = [state.reset(seed=11)[0]]
    motions = [first["motion"]]
    for t in range(STEPS):
        if t % 40 == 0:
            action = rng.uniform(-1, 1, 2).astype(np.float32)
        obs, _, terminated, _, _ = with_motion.step(action)
        states.append(state.step(action)[0])
        motions.append(obs["motion"])
        assert not terminated, "the test's episode must stay on the board"
    return np.array(motions), np.array(states)


@pytest.mark.parametrize("control_hz", [55, 30])
def test_the_motion_is_the_observed_positions_change_and_the_marbles_velocity(control_hz):
    motions, states = twin_episode(control_hz)
    assert motions.dtype == np.float32 and motions.shape == (STEPS + 1, 2)
    np.testing.assert_array_equal(motions[0], [0.0, 0.0])  # an episode's first observation: no motion
    xy, velocity = states[:, :2].astype(np.float64), states[:, 2:4]
    change = np.diff(xy, axis=0) * control_hz / MOTION_SCALE
    np.testing.assert_allclose(motions[1:], change, atol=1e-4)  # the states' positions are float32
    # The change over one step is the marble's mean velocity over it, so it follows the physics'
    # velocity at the step's end within a fraction of the speed (more at 30 Hz, whose steps are
    # longer); a bounce off a wall within a step is the exception, hence percentiles.
    moving = np.linalg.norm(velocity[1:], axis=1) > 0.02
    assert moving.sum() > STEPS // 2, "the marble must move for the comparison to mean anything"
    speed = np.abs(velocity[1:][moving]).mean()
    error = np.abs(motions[1:][moving] * MOTION_SCALE - velocity[1:][moving])
    assert np.median(error) < 0.1 * speed and np.percentile(error, 90) < 0.25 * speed


def test_the_flat_form_ends_with_the_motion_and_round_trips():
    env = LabyrinthEnv("easy", obs_mode="cyberrunner_flat", motion=True)
    twin = LabyrinthEnv("easy", obs_mode="cyberrunner", motion=True)
    flat, _ = env.reset(seed=2)
    parts, _ = twin.reset(seed=2)
    for _ in range(5):
        flat = env.step(np.array([1.0, -1.0], np.float32))[0]
        parts = twin.step(np.array([1.0, -1.0], np.float32))[0]
    assert flat.shape == (cyberrunner_flat_size(True),) == (CYBERRUNNER_FLAT_SIZE + 2,)
    assert env.observation_space.contains(flat) and twin.observation_space.contains(parts)
    np.testing.assert_array_equal(flat[-2:], parts["motion"])
    assert np.any(parts["motion"] != 0)
    back = unflatten_cyberrunner(flat)
    assert back.keys() == parts.keys()
    for key in parts:
        np.testing.assert_array_equal(back[key], parts[key])
    np.testing.assert_array_equal(flatten_cyberrunner(back), flat)
    # Without the motion the observation is CyberRunner's own, unchanged.
    plain = LabyrinthEnv("easy", obs_mode="cyberrunner_flat")
    assert plain.reset(seed=2)[0].shape == (CYBERRUNNER_FLAT_SIZE,)
    assert "motion" not in unflatten_cyberrunner(plain.step(np.zeros(2, np.float32))[0])


def test_gymnasiums_checker_accepts_both_forms():
    for obs_mode in ("cyberrunner", "cyberrunner_flat"):
        check_env(LabyrinthEnv("easy", obs_mode=obs_mode, motion=True), skip_render_check=True)


def test_bad_input_is_refused_by_name():
    with pytest.raises(ValueError, match=r"motion .* observation modes .*'pixels'\) only .* obs_mode 'state'"):
        LabyrinthEnv("easy", obs_mode="state", motion=True)
    with pytest.raises(ValueError, match="motion must be True or False"):
        LabyrinthEnv("easy", obs_mode="cyberrunner", motion=1)
    with pytest.raises(ValueError, match=r"has 4110 or 4112 values .* got shape \(4111,\)"):
        unflatten_cyberrunner(np.zeros(4111))
    with pytest.raises(ValueError, match="motion is the labyrinth's .*, not STG1's"):
        puzzle("STG1").env(obs_mode="state", action_type="discrete", motion=True)
    env = LabyrinthEnv("easy", obs_mode="cyberrunner", motion=True)
    state = env.reset(seed=0)[1] and env.sim.get_state()
    with pytest.raises(ValueError, match="previous_state must be a finite float vector"):
        env.observe_state(state, 0.0, state[:3])
