"""PPO's behaviour policy at a temperature (``sample_temperature``, bimgame.learn.ppo): the tempered
distributions of both kinds of action, the same greedy action, and a loss whose ratio is taken of
the policy that acted (1 under the acting network at its temperature, not at another)."""

from __future__ import annotations

import math

import pytest
import torch

from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.learn.actor import RecurrentActor
from bimgame.learn.policy_heads import ContinuousActions, DiscreteActions
from bimgame.learn.ppo import PPOConfig, PPOOptimizationSettings, ppo_minibatch_loss
from bimgame.learn.ppo.update import rollout_targets
from bimgame.learn.rollout import RolloutCollector

TINY = dict(task="STG1", obs="state", hidden=16, features=16, envs_per_worker=4, n_steps=16, minibatches=2,
            eval_every=0, eval_episodes=2, log_every=64)


def test_a_tempered_categorical_divides_the_logits_and_keeps_the_argmax():
    logits = torch.tensor([[0.3, -1.0, 2.0, 0.0, 0.5], [1.0, 1.5, -0.5, 0.2, 0.1]])
    head = DiscreteActions(5)
    own, sharp = head.distribution(logits, None), head.distribution(logits, None, 0.5)
    assert torch.allclose(sharp.log_probs, torch.log_softmax(logits * 2.0, dim=-1))
    assert torch.equal(sharp.greedy(), own.greedy())
    assert (sharp.entropy() < own.entropy()).all()
    assert torch.equal(head.distribution(logits, None, 1.0).log_probs, own.log_probs)


def test_a_tempered_gaussian_scales_the_standard_deviation_and_keeps_the_mean():
    mean, log_std = torch.tensor([[0.2, -0.4]]), torch.tensor([-0.5, -0.3])
    head = ContinuousActions()
    own, wide = head.distribution(mean, log_std), head.distribution(mean, log_std, 2.0)
    assert torch.allclose(wide.log_std, own.log_std + math.log(2.0))
    assert torch.equal(wide.greedy(), own.greedy())
    assert torch.allclose(wide.entropy() - own.entropy(), torch.tensor([2 * math.log(2.0)]))


def test_the_settings_take_a_positive_temperature():
    assert PPOConfig.from_flat(TINY).optimization.sample_temperature == 1.0
    assert PPOConfig.from_flat(TINY, sample_temperature=0.5).optimization.sample_temperature == 0.5
    for bad in (0.0, -0.5, "hot", math.nan):
        with pytest.raises(ValueError, match=r"PPOOptimizationSettings\.sample_temperature"):
            PPOConfig.from_flat(TINY, sample_temperature=bad)


def test_the_ratio_is_taken_of_the_policy_that_acted_at_its_temperature():
    config = PPOConfig.from_flat(TINY, sample_temperature=0.5)
    net = config.network.build_policy(config.seed)
    # A policy far from uniform, so that its temperature matters.
    with torch.no_grad():
        net.policy.bias.copy_(torch.tensor([1.5, -1.0, 0.5, 0.0, -0.5]))
    envs = config.schedule.envs_per_worker
    env = BallInMazeVectorEnv(envs, task="STG1", obs_mode="state", nthread=1, max_episode_steps=config.time_limit,
                              autoreset_mode="same_step")
    actor = RecurrentActor(net, envs, generator=torch.Generator().manual_seed(0), temperature=0.5)
    collector = RolloutCollector(env, env, actor, gamma=0.99, tilt_input=config.network.tilt_input)
    collector.reset(0, 0)
    segment = collector.collect(config.optimization.n_steps, 0)
    settings = config.optimization
    segment, targets = rollout_targets(net, segment, settings)
    _, parts = ppo_minibatch_loss(net, segment, targets, settings)
    assert parts["approx_kl"] == pytest.approx(0.0, abs=1e-6) and parts["clip_fraction"] == 0.0
    untempered = PPOOptimizationSettings(**{**settings.__dict__, "sample_temperature": 1.0})
    _, parts = ppo_minibatch_loss(net, segment, targets, untempered)
    assert parts["approx_kl"] > 1e-3
