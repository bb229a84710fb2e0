"""Runs whose networks read gate bearings: settings, env arguments, network sizes, scoring."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.envs.gate_bearings import gate_bearings_size
from bimgame.envs.mazes import maze_encoding_size
from bimgame.experiments.protocol import score
from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.sim.maze import MazeSpec


def _config(**given):
    return PPOConfig.from_flat({"task": "STG1", "obs": "state", "num_mazes": 0, **given})


def test_bearings_reach_the_envs_and_widen_the_maze_inputs():
    config = _config(gate_bearings=True)
    assert config.maze_options == {"num_mazes": 0, "start_maze": 0, "gate_bearings": True}
    assert "gate_bearings" not in _config().maze_options  # earlier runs' env arguments are unchanged
    net_config, inputs = config.network.net_config()
    merl = MazeSpec.merl()
    encoding, bearings = maze_encoding_size(merl), gate_bearings_size(merl)
    assert net_config.maze_size == encoding + bearings
    assert net_config.obs_shape == (7 + encoding + bearings,)
    # The encoding is divided by √128 (its many inputs), the bearings are taken as they are.
    np.testing.assert_allclose(inputs["obs_scale"][7 : 7 + encoding], np.sqrt(encoding))
    np.testing.assert_array_equal(inputs["obs_scale"][-bearings:], 1.0)


@pytest.mark.parametrize(
    ("given", "message"),
    [
        ({"num_mazes": None}, "gate_bearings without num_mazes"),
        ({"maze_frame": "marble"}, "already relative to the marble"),
        ({"obs": "pixels"}, "gate_bearings applies to state observations only"),
    ],
)
def test_bearings_are_refused_where_they_do_not_apply(given, message):
    with pytest.raises(ValueError, match=message):
        _config(gate_bearings=True, **given)


def test_a_bearings_run_trains_and_is_scored_with_its_bearings(tmp_path):
    """A short run on unlimited mazes trains on 147-value observations (7 + 128 + 12), and `score --mazes test`
    gives it the bearings it reads (without them the sizes would not match)."""
    config = _config(gate_bearings=True, steps=2048, eval_episodes=2, seed=3)
    result = train_ppo(config, tmp_path / "run", progress=False)
    assert result.steps >= 2048
    summary = score(str(tmp_path / "run"), "STG1", episodes=3, mazes="test")
    assert summary["episodes"] == 3 and summary["mazes"] == "test"
    assert summary["notes"] == []
