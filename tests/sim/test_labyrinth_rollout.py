"""Tests of LabyrinthSim.rollout: K open-loop sequences from one state with ``mujoco.rollout``,
bit-identical to stepping the sim action by action (also through the tilt clamp and on threads),
and input checks. Short horizons: the file runs in about a second."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.sim.labyrinth_physics import LabyrinthSim

RATE = math.radians(30.0) / 55.0  # the env's full-rate tilt change per 55 Hz action


@pytest.fixture(scope="module")
def sim() -> LabyrinthSim:
    return LabyrinthSim(LabyrinthSpec.layout("hard"), control_hz=55.0)


def _moving_state(sim: LabyrinthSim, seed: int) -> np.ndarray:
    """A state with the marble rolling and the board tilted: after 15 random full-rate actions."""
    rng = np.random.default_rng(seed)
    sim.reset(sim.spec.start)
    for _ in range(15):
        sim.step(rng.uniform(-1.0, 1.0, 2) * RATE)
    return sim.get_state()


def _stepped(sim: LabyrinthSim, state: np.ndarray, deltas: np.ndarray) -> np.ndarray:
    """(H, state_size): the states of stepping ``deltas`` (H, 2) from ``state`` one action at a time."""
    sim.set_state(state)
    out = []
    for delta in deltas:
        sim.step(delta)
        out.append(sim.get_state())
    return np.array(out)


@pytest.mark.parametrize("nthread", [1, 2])
def test_rollout_equals_stepping_bit_for_bit(sim, nthread):
    state = _moving_state(sim, 0)
    rng = np.random.default_rng(1)
    deltas = rng.uniform(-1.0, 1.0, (5, 25, 2)) * RATE
    deltas[0] = 4 * RATE  # drives the servo target into its ±10° clamp
    deltas[1] = 0.0
    out = sim.rollout(state, deltas, nthread=nthread)
    assert out.shape == (5, 25, sim.state_size)
    for k in range(5):
        np.testing.assert_array_equal(out[k], _stepped(sim, state, deltas[k]))
    np.testing.assert_allclose(out[0, -1, sim.layout.target_tilt], sim.max_tilt, rtol=1e-9)  # clamped


def test_rollout_leaves_the_sims_own_state_alone_and_repeats(sim):
    state = _moving_state(sim, 2)
    deltas = np.random.default_rng(3).uniform(-1.0, 1.0, (3, 10, 2)) * RATE
    first = sim.rollout(state, deltas)
    np.testing.assert_array_equal(sim.get_state(), state)
    np.testing.assert_array_equal(sim.rollout(state, deltas), first)
    np.testing.assert_array_equal(sim.rollout(state, deltas[1])[0], first[1])  # one (H, 2) sequence


@pytest.mark.parametrize(
    ("state", "controls", "nthread", "field"),
    [
        (np.zeros(3), np.zeros((1, 2, 2)), 1, "state"),
        (None, np.zeros((1, 2, 3)), 1, "controls"),
        (None, np.full((1, 2, 2), np.nan), 1, "controls"),
        (None, np.zeros((1, 2, 2)), 0, "nthread"),
    ],
)
def test_bad_rollout_inputs_name_the_argument(sim, state, controls, nthread, field):
    state = sim.get_state() if state is None else state
    with pytest.raises(ValueError, match=field):
        sim.rollout(state, controls, nthread=nthread)
