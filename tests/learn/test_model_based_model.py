"""Tests of the model-based learner's planning model (bimgame.learn.model_based.marble_model) and
actor (bimgame.learn.model_based.agent): rollouts through the fitted law stop at the walls, the
expert's MPC plans through the model, and the actor refuses envs it cannot play."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.expert.labyrinth_mpc import LabyrinthMPCConfig
from bimgame.expert.planning_model import PlanningModel
from bimgame.learn.model_based.agent import ModelBasedAgent, play_episode
from bimgame.learn.model_based.contacts import WallContacts
from bimgame.learn.model_based.marble_law import MarbleLaw
from bimgame.learn.model_based.marble_model import MODEL_STATE_SIZE, MarbleModel
from bimgame.learn.model_based.transitions import Transitions, explore


@pytest.fixture(scope="module")
def hard() -> tuple[LabyrinthEnv, MarbleLaw]:
    env = LabyrinthEnv("hard")
    transitions = Transitions()
    explore(env, 3000, np.random.default_rng(0), transitions)
    return env, MarbleLaw.fit(transitions, env.board)


def test_a_rollout_tilted_towards_a_wall_stops_at_it(hard):
    env, law = hard
    model = MarbleModel(law, WallContacts(env.board))
    assert isinstance(model, PlanningModel)
    x, y = env.board.start
    state = np.array([x, y, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    full = env.tilt_step * np.ones((4, 120, 2)) * np.array([[[1, 0]], [[-1, 0]], [[0, 1]], [[0, -1]]])
    states = model.rollout(state, full)
    assert states.shape == (4, 120, MODEL_STATE_SIZE)
    xy = model.marble_xy_of(states)
    assert np.all(env.board.clearance(xy.reshape(-1, 2)) >= env.board.marble_radius - 1e-5)  # within 10 µm
    assert np.abs(xy[:, -1] - xy[:, 0]).max() > 0.005  # the marble did roll
    np.testing.assert_array_equal(states, model.rollout(state, full))  # a pure function
    np.testing.assert_array_equal(states[:, :, 6:], full)  # it remembers the last command


def test_bad_rollout_inputs_are_refused(hard):
    env, law = hard
    model = MarbleModel(law, WallContacts(env.board))
    with pytest.raises(ValueError, match="state must be 8"):
        model.rollout(np.zeros(6), np.zeros((1, 2, 2)))
    with pytest.raises(ValueError, match=r"shape \(K, H, 2\)"):
        model.rollout(np.zeros(8), np.zeros((2, 2)))
    with pytest.raises(TypeError, match="MarbleLaw"):
        MarbleModel("law", WallContacts(env.board))  # type: ignore[arg-type]


def test_the_actor_plans_through_the_model_and_records_what_it_played(hard):
    env, law = hard
    agent = ModelBasedAgent.for_env(env, law, LabyrinthMPCConfig(n_samples=8, horizon=10), rng=np.random.default_rng(0))
    transitions = Transitions()
    episode = play_episode(env, agent, seed=3, max_steps=40, transitions=transitions)
    assert len(transitions) == episode["steps"] > 0
    assert episode["ending"] in ("goal", "hole", "off_path", "time")
    _, changes, previous, _ = transitions.arrays()
    np.testing.assert_array_equal(previous[1:], changes[:-1])  # each step's previous command is the last one's
    assert np.all(np.abs(changes) <= env.tilt_step + 1e-12)


@pytest.mark.parametrize("settings", [{"action_type": "discrete"}, {"obs_mode": "cyberrunner"}])
def test_the_actor_refuses_envs_it_cannot_play(hard, settings):
    _, law = hard
    env = LabyrinthEnv("easy", **settings)
    with pytest.raises(ValueError, match="action_type 'continuous' with obs_mode 'state'"):
        ModelBasedAgent.for_env(env, law, rng=np.random.default_rng(0))
    env.close()
