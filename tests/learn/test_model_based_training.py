"""Tests of the model-based learner's loop (bimgame.learn.model_based.training): from a few thousand
steps of random play it completes the easy labyrinth, far beyond a random policy; it is seeded; its
settings refuse bad values."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.expert.labyrinth_mpc import LabyrinthMPCConfig
from bimgame.learn.model_based import ModelBasedSettings, learn_model_based
from bimgame.learn.model_based.agent import ModelBasedAgent, play_episode


@pytest.fixture(scope="module")
def easy_run():
    settings = ModelBasedSettings(explore_steps=2000, iterations=1, episodes_per_iteration=1, max_episode_steps=150)
    return learn_model_based("easy", settings, seed=0, progress=False)


def test_a_law_from_two_thousand_random_steps_completes_the_easy_layout(easy_run):
    env = LabyrinthEnv("easy")
    agent = ModelBasedAgent.for_env(env, easy_run.law, rng=np.random.default_rng(0))
    learned = play_episode(env, agent, seed=0, max_steps=1500)
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    random_progress = 0.0
    for _ in range(1500):
        _, _, terminated, truncated, info = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        random_progress = info["progress_fraction"]
        if terminated or truncated:
            break
    env.close()
    assert learned["success"], learned
    assert learned["progress_fraction"] > random_progress + 0.5


def test_the_run_counts_every_environment_step_and_is_seeded(easy_run):
    record = easy_run.iterations[0]
    assert record["env_steps_before"] == 2000
    assert easy_run.env_steps == 2000 + sum(e["steps"] for e in record["episodes"])
    settings = ModelBasedSettings(explore_steps=2000, iterations=1, episodes_per_iteration=1, max_episode_steps=150)
    again = learn_model_based("easy", settings, seed=0, progress=False)
    np.testing.assert_array_equal(again.law.coefficients, easy_run.law.coefficients)
    assert again.iterations == easy_run.iterations


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [("explore_steps", 0, "explore_steps must be an integer ≥ 1"), ("iterations", -1, "iterations must be"),
     ("episodes_per_iteration", 1.5, "episodes_per_iteration"), ("free_margin", -1.0, "free_margin"),
     ("planner", {"n_samples": 8}, "LabyrinthMPCConfig")],
)
def test_bad_settings_are_refused(field, value, message):
    with pytest.raises((ValueError, TypeError), match=message):
        ModelBasedSettings(**{field: value})


def test_envs_the_learner_cannot_play_are_refused_before_it_explores():
    with pytest.raises(ValueError, match="action_type 'continuous' with obs_mode 'state'"):
        learn_model_based("easy", seed=0, progress=False, action_type="discrete")


def test_the_planner_settings_reach_the_planner():
    env = LabyrinthEnv("easy")
    from bimgame.learn.model_based.marble_law import MarbleLaw
    from bimgame.learn.model_based.marble_law import FEATURES

    law = MarbleLaw(np.zeros((len(FEATURES), 6)), env.board.max_tilt)
    agent = ModelBasedAgent.for_env(env, law, LabyrinthMPCConfig(n_samples=8, horizon=12), rng=np.random.default_rng(0))
    assert (agent.planner.config.n_samples, agent.planner.config.horizon) == (8, 12)
    env.close()
