"""Runs whose networks read the labyrinth's surroundings: settings, env arguments, network sizes,
DAgger's single envs, training and scoring."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.envs.labyrinth_surroundings import RAY_RANGE, SURROUNDINGS_SIZE
from bimgame.envs.puzzles import puzzle
from bimgame.experiments.labyrinth_protocol import score_labyrinth
from bimgame.learn.common import NetworkSettings
from bimgame.learn.ppo import PPOConfig, train_ppo


def _config(**given):
    return PPOConfig.from_flat(
        {"task": "LABYRINTH-EASY", "obs": "state", "action_type": "continuous", "aux_heads": False, **given}
    )


def test_surroundings_reach_the_envs_and_widen_the_network_input():
    config = _config(surroundings=True)
    assert config.maze_options == {"surroundings": True}
    assert _config().maze_options == {}  # earlier runs' env arguments are unchanged
    net_config, inputs = config.network.net_config(puzzle("LABYRINTH-EASY").spec)
    assert net_config.obs_shape == (17 + SURROUNDINGS_SIZE,)
    np.testing.assert_array_equal(inputs["obs_scale"][17:], np.float32(RAY_RANGE))
    plain, _ = _config().network.net_config(puzzle("LABYRINTH-EASY").spec)
    assert plain.obs_shape == (17,)
    env = puzzle("LABYRINTH-EASY").env(obs_mode="state", action_type="continuous", **config.maze_options)
    assert env.reset(seed=0)[0].shape == (17 + SURROUNDINGS_SIZE,)  # DAgger's rollouts build these


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: NetworkSettings(obs="pixels", surroundings=True), "surroundings applies to state observations only"),
        (lambda: PPOConfig.from_flat({"task": "STG1", "obs": "state", "surroundings": True}), "labyrinth's holes"),
        (lambda: puzzle("STG1").env(obs_mode="state", action_type="discrete", surroundings=True), "not STG1's"),
    ],
)
def test_surroundings_are_refused_where_they_do_not_apply(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_a_surroundings_run_trains_and_is_scored_with_them(tmp_path):
    """A short PPO run trains on 33-value observations and the labyrinth's protocol gives its network
    the surroundings it reads (without them the input sizes would not match)."""
    config = _config(surroundings=True, steps=1024, eval_episodes=2, seed=3)
    result = train_ppo(config, tmp_path / "run", progress=False)
    assert result.steps >= 1024
    summary = score_labyrinth(str(tmp_path / "run"), "LABYRINTH-EASY", episodes=2, progress=False)
    assert summary["episodes"] == 2
