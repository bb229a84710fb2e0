"""PPO's falling ceiling on a Gaussian policy's σ (``final_max_std``): the schedule, the refusals,
and a run whose σ ends at the ceiling although its KL term pulls it towards π^s's wider one."""

from __future__ import annotations

import math

import pytest
import torch

from bimgame.learn.checkpoints import load_checkpoint, save_checkpoint
from bimgame.learn.ppo import PPOConfig, PPOOptimizationSettings, train_ppo

TINY = dict(task="STG1", obs="state", hidden=16, features=16, envs_per_worker=4, n_steps=16, minibatches=2,
            eval_every=0, eval_episodes=2, log_every=64, action_type="continuous")


def test_the_ceiling_falls_geometrically_from_one_to_the_final_value():
    settings = PPOOptimizationSettings(final_max_std=0.25)
    assert settings.max_log_std_at(0, 1000) == 0.0
    assert settings.max_log_std_at(500, 1000) == pytest.approx(math.log(0.5))
    assert settings.max_log_std_at(1000, 1000) == pytest.approx(math.log(0.25))
    assert settings.max_log_std_at(1200, 1000) == pytest.approx(math.log(0.25))  # past the end: the final value
    assert PPOOptimizationSettings().max_log_std_at(500, 1000) is None


@pytest.mark.parametrize("value", [0.0, -0.1, 1.5, math.nan, "0.2"])
def test_a_ceiling_outside_zero_to_one_is_refused(value):
    with pytest.raises(ValueError, match=r"PPOOptimizationSettings\.final_max_std"):
        PPOOptimizationSettings(final_max_std=value)


def test_a_discrete_policy_has_no_sigma_to_cap():
    with pytest.raises(ValueError, match=r"final_max_std caps a Gaussian policy's standard deviation"):
        PPOConfig.from_flat(TINY, action_type="discrete", final_max_std=0.2)


def test_sigma_ends_at_the_ceiling_against_a_kl_to_a_wider_teacher(tmp_path):
    """π^s with σ = 0.6 and a strong KL to it: without the ceiling σ stays near 0.6; with it, σ
    ends at most 0.2."""
    source = PPOConfig.from_flat(TINY, steps=64)
    net = source.network.build_policy(0)
    state = net.state_dict()
    state["log_std"] = torch.full_like(state["log_std"], math.log(0.6))
    save_checkpoint(tmp_path / "pi_s.pt", model=state, step=0)
    sigmas = {}
    for ceiling in (None, 0.2):
        config = PPOConfig.from_flat(TINY, steps=512, kl_coef=5.0, final_max_std=ceiling, checkpoint_every=128)
        run = tmp_path / f"run-{ceiling}"
        train_ppo(config, run, init=tmp_path / "pi_s.pt", progress=False)
        sigmas[ceiling] = load_checkpoint(run / "checkpoint.pt")["model"]["log_std"].exp()
    assert torch.all(sigmas[None] > 0.45), sigmas
    assert torch.all(sigmas[0.2] <= 0.2 + 1e-6), sigmas
