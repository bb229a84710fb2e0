"""PPO's moving KL teacher (``kl_teacher_refresh_steps``): when it moves, the refusals, a run whose
teacher becomes the policy it was at the refresh step, and a resumed run that keeps that teacher."""

from __future__ import annotations

import pytest
import torch

from bimgame.learn.checkpoints import load_checkpoint
from bimgame.learn.ppo import PPOConfig, PPOFinetuneSettings, train_ppo

from tests.learn.test_ppo_kl_means import TINY


def test_the_teacher_moves_once_each_time_the_run_passes_a_multiple_of_the_refresh_steps():
    settings = PPOFinetuneSettings(kl_coef=0.1, kl_teacher_refresh_steps=100)
    assert not settings.refreshes_teacher(0, 64)
    assert settings.refreshes_teacher(0, 128)  # passed 100
    assert not settings.refreshes_teacher(128, 192)
    assert settings.refreshes_teacher(192, 200)  # exactly on 200
    assert settings.refreshes_teacher(0, 512)  # several at once: one move, to the policy as it is then
    assert not PPOFinetuneSettings(kl_coef=0.1).refreshes_teacher(0, 10**9)


def test_a_moving_teacher_needs_a_kl_to_the_policys_start_and_a_whole_number():
    with pytest.raises(ValueError, match=r"kl_teacher_refresh_steps moves the KL's teacher .* kl_coef > 0"):
        PPOFinetuneSettings(kl_teacher_refresh_steps=1000)
    with pytest.raises(ValueError, match=r"no kl_teacher .* got kl_coef 0.2, kl_teacher 'runs/teacher'"):
        PPOFinetuneSettings(kl_coef=0.2, kl_teacher="runs/teacher", kl_teacher_refresh_steps=1000)
    with pytest.raises(ValueError, match=r"kl_teacher_refresh_steps must be an integer >= 0, got -5"):
        PPOFinetuneSettings(kl_coef=0.2, kl_teacher_refresh_steps=-5)
    assert (
        PPOConfig.from_flat(TINY, kl_coef=0.2, kl_teacher_refresh_steps=1000).finetuning.kl_teacher_refresh_steps
        == 1000
    )


def test_the_teacher_becomes_the_policy_of_the_refresh_step_and_a_resumed_run_keeps_it(tmp_path):
    """A run to step 128 ends with the weights a refreshing run has when it reaches 128 (same seed, same
    rollouts: 64 steps each); the refreshing run (every 128 steps), stopped at 192 and resumed to
    256, holds exactly those weights as its teacher — not π^s — in its checkpoint."""
    settings = dict(TINY, kl_coef=0.5, checkpoint_every=64)
    train_ppo(PPOConfig.from_flat(TINY, steps=64), tmp_path / "pi_s", progress=False)
    pi_s = load_checkpoint(tmp_path / "pi_s" / "checkpoint.pt")["model"]

    train_ppo(PPOConfig.from_flat(settings, steps=128), tmp_path / "upto128", init=tmp_path / "pi_s", progress=False)
    at_128 = load_checkpoint(tmp_path / "upto128" / "checkpoint.pt")["model"]

    moving = dict(settings, kl_teacher_refresh_steps=128)
    run = tmp_path / "moving"
    train_ppo(PPOConfig.from_flat(moving, steps=192), run, init=tmp_path / "pi_s", progress=False)
    train_ppo(PPOConfig.from_flat(moving, steps=256), run, resume=True, progress=False)
    payload = load_checkpoint(run / "checkpoint.pt")
    assert payload["step"] == 256 and payload["taught_since"] == 128
    for name, weights in payload["teacher"].items():
        torch.testing.assert_close(weights, at_128[name], rtol=0, atol=0)
    assert any(not torch.equal(payload["teacher"][name], pi_s[name]) for name in pi_s)
    # teacher.pt stays π^s, the policy the run started from.
    for name, weights in load_checkpoint(run / "teacher.pt")["model"].items():
        torch.testing.assert_close(weights, pi_s[name], rtol=0, atol=0)
    # Without refreshes the checkpoint holds no teacher of its own.
    assert "teacher" not in load_checkpoint(tmp_path / "upto128" / "checkpoint.pt")


TWO_RANKS_ONE_STEP = dict(task="STG1", obs="state", hidden=16, features=16, workers=2, envs_per_worker=2, n_steps=32,
                          sequence_length=32, minibatches=1, epochs=1, eval_every=0, eval_episodes=2, log_every=64,
                          max_episode_steps=10, action_type="continuous")


def test_every_rank_moves_its_teacher(tmp_path):
    """Two ranks, one gradient step per rollout, the teacher moved at every rollout: if every rank's
    teacher is the policy before the update, the KL to the means is exactly 0 with a zero gradient, and
    the run is bit for bit the run without a KL term. One rank still holding an older teacher adds its
    KL gradient to the average and the weights differ (as the run whose teacher stays π^s shows)."""
    train_ppo(PPOConfig.from_flat(TWO_RANKS_ONE_STEP, workers=1, steps=64), tmp_path / "pi_s", progress=False)
    arms = {
        "free": dict(kl_coef=0.0),
        "moving": dict(kl_coef=0.5, kl_means_only=True, kl_teacher_refresh_steps=128),
        "kept": dict(kl_coef=0.5, kl_means_only=True),
    }
    weights = {}
    for name, extra in arms.items():
        config = PPOConfig.from_flat(TWO_RANKS_ONE_STEP, steps=512, **extra)
        assert config.steps_per_rollout == 128
        train_ppo(config, tmp_path / name, init=tmp_path / "pi_s", progress=False)
        weights[name] = load_checkpoint(tmp_path / name / "checkpoint.pt")["model"]
    for key, free in weights["free"].items():
        torch.testing.assert_close(weights["moving"][key], free, rtol=0, atol=0)
    assert any(not torch.equal(weights["kept"][key], free) for key, free in weights["free"].items())
