"""Learners on many mazes: the settings, the network's input and a run that trains and evaluates on them."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from bimgame.envs.mazes import MAZE_ENCODING_ANGLES
from bimgame.learn.a3c import A3CConfig, train
from bimgame.learn.common import load_run_network
from bimgame.learn.ppo import PPOConfig, train_ppo

TINY = dict(
    task="STG1",
    obs="state",
    hidden=16,
    features=16,
    envs_per_worker=4,
    n_steps=16,
    minibatches=2,
    eval_every=0,
    eval_episodes=2,
    log_every=64,
)


def test_num_mazes_sets_the_maze_encoding_and_the_network_reads_it():
    config = PPOConfig.from_flat(TINY, num_mazes=10, start_maze=5)
    assert config.network.maze_encoding and config.maze_options == {"num_mazes": 10, "start_maze": 5}
    net = config.network.build_policy(0)
    assert net.config.obs_shape == (7 + 4 * MAZE_ENCODING_ANGLES,)
    # The encoding (128 values in [0, 1]) enters divided by √128, so its pathway learns at a state input's pace.
    assert torch.allclose(net.encoder.scale[7:], torch.tensor(float(np.sqrt(4 * MAZE_ENCODING_ANGLES))))
    assert not PPOConfig.from_flat(TINY).network.maze_encoding
    assert not PPOConfig.from_flat(TINY, obs="pixels", num_mazes=3).network.maze_encoding  # pixels show it
    with pytest.raises(ValueError, match="maze_encoding without num_mazes"):
        PPOConfig.from_flat(TINY, maze_encoding=True)
    with pytest.raises(ValueError, match="start_maze 4 needs num_mazes"):
        A3CConfig.from_flat(obs="state", start_maze=4)
    with pytest.raises(ValueError, match="num_mazes"):
        A3CConfig.from_flat(obs="state", num_mazes=-1)


def test_a_ppo_run_on_many_mazes_stores_them_and_loads_back(tmp_path):
    config = PPOConfig.from_flat(TINY, steps=128, num_mazes=3, eval_episodes=4)
    result = train_ppo(config, tmp_path / "run", progress=False)
    assert result.stopped == "finished" and result.final_eval is not None
    stored = json.loads((tmp_path / "run" / "config.json").read_text())
    assert PPOConfig.from_dict(stored["ppo"]) == config
    net, run, _ = load_run_network(tmp_path / "run")
    assert net.config.obs_shape == (7 + 4 * MAZE_ENCODING_ANGLES,) and run.network.maze_encoding


def test_an_a3c_run_on_many_mazes_trains(tmp_path):
    config = A3CConfig.from_flat(
        task="STG1",
        obs="state",
        hidden=16,
        features=16,
        workers=1,
        envs_per_worker=4,
        steps=256,
        eval_every=0,
        eval_episodes=2,
        num_mazes=0,
    )
    result = train(config, tmp_path / "run", progress=False)
    assert result.steps >= 256
    net, _, _ = load_run_network(tmp_path / "run")
    assert np.prod(net.config.obs_shape) == 7 + 4 * MAZE_ENCODING_ANGLES
