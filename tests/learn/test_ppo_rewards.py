"""PPO with reward shaping (bimgame.learn.rewards through bimgame.learn.ppo): the shaped reward is what
a rank's rollout holds while the physics and the logged task return stay the task's, the run records its
shaping and a resume keeps it, worker processes step their environments through it too, and shaping
the labyrinth is refused by name."""

from __future__ import annotations

import csv
import json

import pytest
import torch

from bimgame.envs.shaping import GeodesicReward
from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.learn.ppo.learner import RankLearner, adam
from bimgame.learn.rewards import RewardSettings

TINY = dict(task="STG1", obs="state", hidden=16, features=16, envs_per_worker=4, n_steps=32, minibatches=2,
            eval_every=0, eval_episodes=2, log_every=64)
COEF = 10.0


def _segment(config: PPOConfig, env_wrapper=None):
    net = config.network.build_policy(config.seed)
    learner = RankLearner(config, net, adam(net, config), rank=0, step=0, on_episode=lambda episode: None,
                          global_step=lambda: 0, env_wrapper=env_wrapper)
    return learner.collector.collect(config.optimization.n_steps, 0)


def test_a_rank_learns_from_the_geodesic_progress_and_steps_the_same_physics():
    config = PPOConfig.from_flat(TINY)
    plain, shaped = _segment(config), _segment(config, GeodesicReward(COEF))
    # The same seed acts the same: the shaping changes rewards only, never the marble's path.
    assert torch.equal(plain.obs, shaped.obs) and torch.equal(plain.actions, shaped.actions)
    progress = shaped.rewards - plain.rewards  # COEF × metres of geodesic progress per step
    assert (progress != 0).float().mean() > 0.5  # a dense reward: the marble moves on most steps
    assert progress.abs().max() < COEF * 0.05  # no marble travels 5 cm in one 1/30 s step


def test_a_run_records_its_shaping_and_a_resume_keeps_it_or_refuses_another(tmp_path):
    config = PPOConfig.from_flat(TINY, steps=128)
    reward = RewardSettings(geodesic_coef=COEF)
    assert train_ppo(config, tmp_path / "run", reward=reward, progress=False).stopped == "finished"
    stored = json.loads((tmp_path / "run" / "config.json").read_text())["reward"]
    assert stored == {"value_reward": None, "geodesic_coef": COEF}
    longer = PPOConfig.from_flat(TINY, steps=256)
    assert train_ppo(longer, tmp_path / "run", resume=True, progress=False).steps == 256  # keeps its own
    with pytest.raises(ValueError, match="--resume must keep the run's reward"):
        train_ppo(PPOConfig.from_flat(TINY, steps=384), tmp_path / "run", resume=True, progress=False,
                  reward=RewardSettings(geodesic_coef=2.0))
    assert json.loads((tmp_path / "run" / "config.json").read_text())["reward"] == stored


def test_worker_processes_step_through_the_shaping_and_return_the_task_reward(tmp_path):
    config = PPOConfig.from_flat(TINY, workers=2, envs_per_worker=2, steps=256, max_episode_steps=10)
    result = train_ppo(config, tmp_path / "two", reward=RewardSettings(geodesic_coef=COEF), progress=False)
    assert result.stopped == "finished"
    with open(tmp_path / "two" / "episodes.csv") as handle:
        returns = [float(row["return"]) for row in csv.DictReader(handle)]
    # 10-step episodes rarely reach STG1's gate: the logged returns are the task's (0 or 1), never
    # the shaped sums (COEF × metres travelled: fractions).
    assert returns and all(value in (0.0, 1.0) for value in returns)


def test_shaping_the_labyrinth_is_refused_before_anything_is_written(tmp_path):
    config = PPOConfig.from_flat(TINY, task="LABYRINTH-EASY")
    with pytest.raises(ValueError, match="RewardSettings.geodesic_coef applies to the circular maze's tasks only"):
        train_ppo(config, tmp_path / "lab", reward=RewardSettings(geodesic_coef=COEF), progress=False)
    assert not (tmp_path / "lab").exists()
