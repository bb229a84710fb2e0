"""Action distributions and heads (bimgame.learn.policy_heads): the Gaussian's and the categorical's
log-probabilities and entropies against torch.distributions, greedy actions, seeded sampling, and what
each kind of action feeds back to the network and sends to the env."""

from __future__ import annotations

import math

import pytest
import torch

from bimgame.envs.env import NO_ACTION
from bimgame.learn.policy_heads import (
    LOG_STD_INIT,
    Categorical,
    ContinuousActions,
    DiagonalGaussian,
    DiscreteActions,
    action_head,
    require_discrete,
)


def _gaussian(seed: int = 0) -> tuple[DiagonalGaussian, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    mean = torch.randn(3, 4, 2, generator=g)
    log_std = torch.tensor([-0.7, 0.3])
    return DiagonalGaussian(mean, log_std), mean, log_std


def test_gaussian_log_prob_and_entropy_match_independent_normals():
    policy, mean, log_std = _gaussian()
    actions = torch.randn(3, 4, 2, generator=torch.Generator().manual_seed(1)) * 2
    normal = torch.distributions.Normal(mean, log_std.exp())
    torch.testing.assert_close(policy.log_prob(actions), normal.log_prob(actions).sum(-1))
    torch.testing.assert_close(policy.entropy(), normal.entropy().sum(-1))
    # By hand for one action: Σ_d −(a−μ)²/(2σ²) − log σ − ½ log 2π.
    a, mu, sigma = actions[0, 0], mean[0, 0], log_std.exp()
    by_hand = sum(-((a[d] - mu[d]) ** 2) / (2 * sigma[d] ** 2) - sigma[d].log() - 0.5 * math.log(2 * math.pi)
                  for d in range(2))
    torch.testing.assert_close(policy.log_prob(actions)[0, 0], by_hand)
    assert policy.entropy().shape == (3, 4)


def test_gaussian_greedy_is_the_mean_and_samples_follow_it():
    policy, mean, log_std = _gaussian()
    assert torch.equal(policy.greedy(), mean)
    many = DiagonalGaussian(torch.tensor([[0.5, -0.25]]).expand(20_000, 2), log_std)
    samples = many.sample(torch.Generator().manual_seed(2))
    torch.testing.assert_close(samples.mean(0), torch.tensor([0.5, -0.25]), atol=0.03, rtol=0)
    torch.testing.assert_close(samples.std(0), log_std.exp(), atol=0.03, rtol=0)


@pytest.mark.parametrize("make", [lambda: _gaussian()[0], lambda: Categorical(torch.randn(6, 5))])
def test_sampling_draws_from_the_generator_only(make):
    policy = make()
    global_state = torch.random.get_rng_state()
    first = policy.sample(torch.Generator().manual_seed(7))
    assert torch.equal(first, policy.sample(torch.Generator().manual_seed(7)))  # same seed, same actions
    assert not torch.equal(first, policy.sample(torch.Generator().manual_seed(8)))
    assert torch.equal(torch.random.get_rng_state(), global_state)  # the global generator untouched


def test_categorical_matches_torch_and_its_greedy_action_is_the_argmax():
    logits = torch.randn(3, 4, 5, generator=torch.Generator().manual_seed(0))
    policy, reference = Categorical(logits), torch.distributions.Categorical(logits=logits)
    actions = torch.randint(0, 5, (3, 4), generator=torch.Generator().manual_seed(1))
    torch.testing.assert_close(policy.log_prob(actions), reference.log_prob(actions))
    torch.testing.assert_close(policy.entropy(), reference.entropy())
    assert torch.equal(policy.greedy(), logits.argmax(-1))
    assert policy.sample(torch.Generator().manual_seed(0)).shape == (3, 4)


def test_discrete_actions_feed_back_one_hot_and_execute_unchanged():
    head = action_head("discrete", 5)
    assert isinstance(head, DiscreteActions) and head.output_size == head.input_size == 5
    assert torch.equal(head.no_action(3), torch.full((3,), NO_ACTION))
    encoded = head.encode(torch.tensor([NO_ACTION, 0, 4]))
    torch.testing.assert_close(encoded, torch.tensor([[0, 0, 0, 0, 0], [1, 0, 0, 0, 0], [0, 0, 0, 0, 1.0]]))
    actions = torch.tensor([0, 3])
    assert head.executed(actions) is actions


def test_continuous_actions_feed_back_the_vector_and_execute_it_clipped():
    head = action_head("continuous", 5)
    assert isinstance(head, ContinuousActions) and head.output_size == head.input_size == 2
    assert torch.equal(head.no_action(3), torch.zeros(3, 2))
    vector = torch.tensor([[0.25, -1.0]])
    assert torch.equal(head.encode(vector), vector)
    with pytest.raises(ValueError, match=r"previous actions of shape \(…, 2\), got \(3,\)"):
        head.encode(torch.tensor([0, 1, 2]))
    assert torch.equal(head.executed(torch.tensor([[1.7, -0.3], [-2.0, 1.0]])), torch.tensor([[1.0, -0.3], [-1.0, 1.0]]))
    policy = head.distribution(torch.zeros(2, 2), torch.full((2,), LOG_STD_INIT))
    torch.testing.assert_close(policy.greedy(), torch.zeros(2, 2))
    with pytest.raises(ValueError, match="needs its log standard deviation"):
        head.distribution(torch.zeros(2, 2), None)


def test_unknown_action_types_and_discrete_only_users_name_the_allowed_values():
    with pytest.raises(ValueError, match=r"NetConfig\.action_type must be one of \('discrete', 'continuous'\), got 'box'"):
        action_head("box", 5)
    require_discrete("A3C", "discrete", "use --algo ppo")  # nothing to refuse
    with pytest.raises(ValueError, match=r"A3C supports action_type 'discrete' only; got 'continuous' \(use --algo ppo\)"):
        require_discrete("A3C", "continuous", "use --algo ppo")


def test_teacher_kl_matches_torch_for_both_kinds_and_is_zero_for_the_teacher_itself():
    g = torch.Generator().manual_seed(4)
    # Continuous: KL(N_t ‖ N) against torch.distributions, per state summed over the two axes.
    head = ContinuousActions()
    mean_t, mean = torch.randn(5, 3, 2, generator=g), torch.randn(5, 3, 2, generator=g)
    log_std_t, log_std = torch.tensor([-0.4, 0.2]), torch.tensor([0.1, -0.6])
    frozen = head.frozen(mean_t, log_std_t, 1.0)
    expected = torch.distributions.kl_divergence(
        torch.distributions.Normal(mean_t, log_std_t.exp()), torch.distributions.Normal(mean, log_std.exp())
    ).sum(-1)
    torch.testing.assert_close(head.kl_from(frozen, mean, log_std), expected)
    assert head.kl_from(frozen, mean_t, log_std_t).abs().max() < 1e-6
    # A cooler teacher: the same mean, the deviation times the temperature.
    cool = head.frozen(mean_t, log_std_t, 0.5)
    torch.testing.assert_close(cool[..., 2:], (log_std_t + math.log(0.5)).expand(5, 3, 2))
    # Discrete: Σ p_t (log p_t − log p).
    discrete = DiscreteActions(5)
    logits_t, logits = torch.randn(4, 5, generator=g), torch.randn(4, 5, generator=g)
    expected = torch.distributions.kl_divergence(
        torch.distributions.Categorical(logits=logits_t), torch.distributions.Categorical(logits=logits)
    )
    torch.testing.assert_close(discrete.kl_from(discrete.frozen(logits_t, None, 1.0), logits, None), expected)
    with pytest.raises(ValueError, match="log standard deviation"):
        head.frozen(mean_t, None, 1.0)
