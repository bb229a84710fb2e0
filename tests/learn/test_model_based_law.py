"""Tests of the model-based learner's marble law (bimgame.learn.model_based.marble_law): fitted from
random play, it finds a rolling ball's acceleration on a tilted board and predicts the simulator's
marble away from the walls to within a millimetre; it refuses too little data and bad files."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.learn.model_based.marble_law import FEATURES, MIN_FREE_TRANSITIONS, MarbleLaw
from bimgame.learn.model_based.transitions import Transitions, explore, marble_state
from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.sim.labyrinth_physics import LabyrinthSim


@pytest.fixture(scope="module")
def easy_play() -> tuple[Transitions, LabyrinthSpec]:
    env = LabyrinthEnv("easy")
    transitions = Transitions()
    explore(env, 3000, np.random.default_rng(0), transitions)
    env.close()
    return transitions, env.board


@pytest.fixture(scope="module")
def law(easy_play) -> MarbleLaw:
    return MarbleLaw.fit(*easy_play)


def test_the_fitted_acceleration_is_a_rolling_balls_five_sevenths_of_g(law):
    # A solid ball rolling without slipping on a plane tilted by θ accelerates at (5/7)·g·sin θ.
    assert law.acceleration_per_tilt(55.0) == pytest.approx(5 / 7 * 9.81, rel=0.1)
    assert law.free_transitions >= MIN_FREE_TRANSITIONS
    assert np.all(law.r2 > 0.95)


def test_the_law_follows_the_simulators_marble_away_from_the_walls(law, easy_play):
    spec = easy_play[1]
    sim = LabyrinthSim(spec)
    hx, hy = np.asarray(spec.board_size) / 2
    grid = np.stack(np.meshgrid(np.linspace(-hx, hx, 60), np.linspace(-hy, hy, 50)), -1).reshape(-1, 2)
    spot = grid[np.argmax(spec.clearance(grid))]  # the most open place on the board
    assert float(spec.clearance(spot)) > 0.02
    sim.reset(spot, tilt=(math.radians(2), math.radians(-3)))
    change, previous = np.array([0.004, 0.004]), np.zeros(2)
    predicted = None
    for _ in range(12):
        (x, y, _), (vx, vy, _) = sim.marble_kinematics()
        state = np.array([x, y, vx, vy, *sim.tilt])
        predicted = law.step(state[None] if predicted is None else predicted, change[None], previous[None])
        sim.step(change)
        previous = change
    (x, y, _), _ = sim.marble_kinematics()
    moved = math.dist((x, y), spot)
    assert moved > 0.005  # the marble rolled
    assert math.dist((x, y), predicted[0, :2]) < 0.001  # open loop for 12 steps, within a millimetre
    sim.close()


def test_the_tilt_stays_within_the_boards_range(law):
    state = np.array([[0.0, 0.0, 0.0, 0.0, law.max_tilt, -law.max_tilt]])
    after = law.step(state, np.array([[0.01, -0.01]]), np.array([[0.01, -0.01]]))
    assert abs(after[0, 4]) <= law.max_tilt and abs(after[0, 5]) <= law.max_tilt


def test_too_few_free_transitions_are_refused(easy_play):
    transitions, spec = easy_play
    few = Transitions()
    state, change, previous, following = transitions.arrays()
    for row in range(20):
        few.add(state[row], change[row], previous[row], following[row])
    with pytest.raises(ValueError, match="explore longer"):
        MarbleLaw.fit(few, spec)
    with pytest.raises(ValueError, match="free_margin"):
        MarbleLaw.fit(transitions, spec, free_margin=-0.001)


def test_a_saved_law_loads_back_and_other_files_are_refused(law, tmp_path):
    path = law.save(tmp_path / "law.json")
    back = MarbleLaw.load(path)
    np.testing.assert_array_equal(back.coefficients, law.coefficients)
    assert (back.max_tilt, back.free_transitions) == (law.max_tilt, law.free_transitions)
    (tmp_path / "other.json").write_text(json.dumps({"coefficients": [[0.0]]}))
    with pytest.raises(ValueError, match="not a marble law"):
        MarbleLaw.load(tmp_path / "other.json")
    (tmp_path / "keyless.json").write_text(json.dumps({"format": "bimgame-marble-law-1"}))
    with pytest.raises(ValueError, match="broken marble law"):
        MarbleLaw.load(tmp_path / "keyless.json")
    (tmp_path / "broken.json").write_text("{")
    with pytest.raises(ValueError, match="not a readable JSON"):
        MarbleLaw.load(tmp_path / "broken.json")
    with pytest.raises(ValueError, match="coefficients must be finite"):
        MarbleLaw(np.zeros((len(FEATURES), 5)), 0.17)
    with pytest.raises(ValueError, match="max_tilt"):
        MarbleLaw(np.zeros((len(FEATURES), 6)), 0.0)


def test_transitions_refuse_what_is_not_a_state_observation():
    with pytest.raises(ValueError, match="obs_mode 'state'"):
        marble_state(np.zeros((1, 64, 64)))
    with pytest.raises(ValueError, match="finite"):
        Transitions().add(np.zeros(6), np.array([np.nan, 0.0]), np.zeros(2), np.zeros(6))
