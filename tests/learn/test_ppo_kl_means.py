"""PPO's means-only KL to π^s (``kl_means_only``): the closed form at the teacher's σ, a learner's σ
that the term leaves free while its mean is still pulled, the refusals, and a run that uses it."""

from __future__ import annotations

import json
import math

import pytest
import torch

from bimgame.learn.checkpoints import load_checkpoint, save_checkpoint
from bimgame.learn.finetune import policy_kl
from bimgame.learn.ppo import PPOConfig, PPOFinetuneSettings, ppo_minibatch_loss, train_ppo
from bimgame.learn.ppo.update import KLTarget, rollout_targets

from tests.learn.test_ppo import _segment

TINY = dict(task="STG1", obs="state", hidden=16, features=16, envs_per_worker=4, n_steps=16, minibatches=2,
            eval_every=0, eval_episodes=2, log_every=64, action_type="continuous")


def _teacher(net, seed: int = 1) -> torch.Tensor:
    """A frozen Gaussian teacher over (T, B) = (5, 3) steps: random means, σ = (0.3, 0.7)."""
    g = torch.Generator().manual_seed(seed)
    mean_t = torch.randn(5, 3, 2, generator=g)
    log_std_t = torch.log(torch.tensor([0.3, 0.7])).expand(5, 3, 2)
    return torch.cat([mean_t, log_std_t], dim=-1)


def test_the_means_only_kl_is_the_squared_mean_gap_over_twice_the_teachers_variance():
    net = PPOConfig.from_flat(TINY).network.build_policy(0)
    teacher = _teacher(net)
    output = torch.randn(5, 3, 2, generator=torch.Generator().manual_seed(2))
    mean_t, std_t = teacher[..., :2], teacher[..., 2:].exp()
    expected = ((output - mean_t).pow(2) / (2 * std_t.pow(2))).sum(-1).mean()
    for log_std in (-2.0, 0.0, 0.5):  # whatever the learner's own σ
        with torch.no_grad():
            net.log_std.fill_(log_std)
        torch.testing.assert_close(policy_kl(net, teacher, output, means_only=True), expected)
    # The full KL does depend on the learner's σ, and is zero only for the teacher itself.
    assert not torch.isclose(policy_kl(net, teacher, output), expected)
    assert policy_kl(net, teacher, mean_t, means_only=True).abs() < 1e-7


def test_the_means_only_kl_leaves_sigma_free_and_still_pulls_the_mean():
    """Through PPO's minibatch loss: with a teacher and kl_means_only, log σ's gradient is the one
    without any teacher (the clipped surrogate's and the entropy's alone), while the full KL adds to
    it; the policy head's gradient differs from the teacher-free one in both cases."""
    config = PPOConfig.from_flat(TINY)
    grads = {}
    for name, means_only, weight in (("none", False, 0.0), ("means", True, 50.0), ("full", False, 50.0)):
        net, segment = _segment(config)
        with torch.no_grad():
            net.log_std.fill_(math.log(0.2))  # a learner narrower than its teacher
            teacher = net.action_head.frozen(torch.zeros(16, 4, 2), torch.full((2,), math.log(0.6)), 1.0)
        kl = None if name == "none" else KLTarget(teacher, weight, means_only)
        segment, targets = rollout_targets(net, segment, config.optimization, kl)
        loss, parts = ppo_minibatch_loss(net, segment, targets, config.optimization)
        loss.backward()
        grads[name] = (net.log_std.grad.clone(), net.policy.weight.grad.clone(), parts)
    torch.testing.assert_close(grads["means"][0], grads["none"][0])
    assert not torch.allclose(grads["full"][0], grads["none"][0], atol=1e-3)
    assert not torch.allclose(grads["means"][1], grads["none"][1], atol=1e-3)
    assert "kl" in grads["means"][2] and "kl" not in grads["none"][2]


def test_means_only_is_refused_for_discrete_actions_and_must_be_a_bool():
    with pytest.raises(ValueError, match=r"kl_means_only compares a Gaussian policy's means"):
        PPOConfig.from_flat(TINY, action_type="discrete", kl_coef=0.1, kl_means_only=True)
    with pytest.raises(ValueError, match=r"PPOFinetuneSettings\.kl_means_only must be True or False"):
        PPOFinetuneSettings(kl_means_only="yes")
    with pytest.raises(ValueError, match=r"kl_means_only shapes the KL term to π\^s: give kl_coef > 0"):
        PPOConfig.from_flat(TINY, kl_means_only=True)
    with pytest.raises(ValueError, match=r"no standard deviation"):
        PPOConfig.from_flat(TINY, action_type="discrete").network.build_policy(0).action_head.frozen_log_std(
            torch.zeros(3, 5)
        )


def test_a_means_only_run_lets_sigma_fall_below_the_teachers(tmp_path):
    """π^s with σ = 0.6, a strong KL and a σ ceiling of 0.2: the full KL drags σ back against the
    ceiling every update, the means-only KL does not — both end at most 0.2, and the means-only run
    records its own (smaller) KL, which no longer holds σ's gap to the teacher."""
    source = PPOConfig.from_flat(TINY, steps=64)
    state = source.network.build_policy(0).state_dict()
    state["log_std"] = torch.full_like(state["log_std"], math.log(0.6))
    save_checkpoint(tmp_path / "pi_s.pt", model=state, step=0)
    kls = {}
    for means_only in (False, True):
        config = PPOConfig.from_flat(TINY, steps=512, kl_coef=5.0, kl_means_only=means_only, final_max_std=0.2,
                                     checkpoint_every=128, log_every=64)
        run = tmp_path / f"run-{means_only}"
        train_ppo(config, run, init=tmp_path / "pi_s.pt", progress=False)
        assert torch.all(load_checkpoint(run / "checkpoint.pt")["model"]["log_std"].exp() <= 0.2 + 1e-6)
        assert PPOConfig.from_flat(json.loads((run / "config.json").read_text())["ppo"]).finetuning.kl_means_only \
            is means_only
        rows = (run / "updates.csv").read_text().splitlines()
        header = rows[0].split(",")
        kls[means_only] = float(rows[-1].split(",")[header.index("kl")])
    # σ = 0.2 against σ_t = 0.6: the full KL holds log 3 + 0.5·(1/9) − 0.5 ≈ 0.65 nats per dimension
    # from the spreads alone; the means-only one holds none of it.
    assert kls[False] > 1.0 and kls[True] < 0.5 * kls[False], kls
