"""PPO's update of one rollout: advantages under the network that acted, then ``epochs`` passes of
``minibatches`` minibatches, each a set of whole sequences over which the LSTM is unrolled again from
the state the acting network had at their first step, with the clipped surrogate objective. A
sequence is an environment's whole rollout (CleanRL's ``ppo_atari_lstm.py`` splits by environment
for the same reason) or, with ``sequence_length``, a piece of it."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import NamedTuple

import torch
import torch.distributed as dist

from bimgame.learn.finetune import keep_critic_gradients, policy_kl
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.ppo.settings import PPOOptimizationSettings
from bimgame.learn.rollout import Segment, advantages_and_targets, in_sequences, sequence_start_states, unroll

__all__ = [
    "AUX_LOSSES",
    "UPDATE_STATISTICS",
    "GradientAverage",
    "KLTarget",
    "RolloutTargets",
    "rollout_targets",
    "ppo_minibatch_loss",
    "ppo_update",
]

#: The statistics an update reports, averaged over its minibatches (``kl`` only when fine-tuning keeps
#: π^s): the columns of a run's update log.
UPDATE_STATISTICS = ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction", "grad_norm", "kl")
#: The auxiliary heads' losses (frame head, memory head): reported by a network that has them.
AUX_LOSSES = ("aux_frame", "aux_memory")
_AVERAGED = (*UPDATE_STATISTICS, *AUX_LOSSES)


class GradientAverage:
    """Averages each minibatch's gradient over the ranks of a multi-process PPO run, in place: one
    all-reduce (``torch.distributed``, gloo) of all gradients flattened into one buffer, which also
    carries a count of the ranks whose loss was not finite. Every rank then holds the same gradient,
    and after Adam's step the same weights."""

    def __init__(self, world: int):
        self.world = world

    def __call__(self, net: torch.nn.Module, finite_loss: bool) -> bool:
        """Average the gradients of ``net`` over the ranks; True when every rank's loss was finite."""
        params = list(net.parameters())
        grads = [p.grad if p.grad is not None else torch.zeros_like(p) for p in params]
        flag = torch.tensor([0.0 if finite_loss else 1.0])
        flat = torch.cat([g.reshape(-1) for g in grads] + [flag])
        dist.all_reduce(flat)
        offset = 0
        for param, grad in zip(params, grads, strict=True):
            count = grad.numel()
            param.grad = (flat[offset : offset + count] / self.world).view_as(param).clone()
            offset += count
        return bool(flat[-1].item() == 0.0)


class KLTarget(NamedTuple):
    """π^s's part of a fine-tuning update: its π over the rollout (T, B, P) as its action head freezes
    it (:meth:`~bimgame.learn.policy_heads.ActionHead.frozen`: log-probabilities, or a Gaussian's
    mean and log standard deviation) and the weight of KL(π^s ‖ π) in the loss; ``means_only``, the
    KL at π^s's own standard deviation (:attr:`~bimgame.learn.ppo.settings.PPOFinetuneSettings.kl_means_only`)."""

    policy: torch.Tensor
    weight: float
    means_only: bool = False


@dataclasses.dataclass
class RolloutTargets:
    """What every minibatch of a rollout is trained towards: GAE advantages, value targets, and the
    values and log-probabilities of the network that acted — each (T, B) — and, when fine-tuning
    keeps π^s, its part (:class:`KLTarget`, π^s over the same steps)."""

    advantages: torch.Tensor
    returns: torch.Tensor
    values: torch.Tensor
    log_probs: torch.Tensor
    kl: KLTarget | None = None

    def _map(self, change: Callable[[torch.Tensor], torch.Tensor]) -> RolloutTargets:
        return RolloutTargets(
            change(self.advantages),
            change(self.returns),
            change(self.values),
            change(self.log_probs),
            None if self.kl is None else self.kl._replace(policy=change(self.kl.policy)),
        )

    def envs(self, index: torch.Tensor) -> RolloutTargets:
        """The targets of the environments ``index`` (as :meth:`Segment.envs`)."""
        return self._map(lambda value: value[:, index])

    def sequences(self, length: int) -> RolloutTargets:
        """The targets cut into sequences as :meth:`Segment.sequences` cuts the segment."""
        steps = int(self.advantages.shape[0])
        return self._map(lambda value: in_sequences(value, length, steps))


@torch.no_grad()
def rollout_targets(
    net: RecurrentActorCritic, segment: Segment, settings: PPOOptimizationSettings, kl: KLTarget | None = None
) -> tuple[Segment, RolloutTargets]:
    """What the update trains on: the segment's sequences (:meth:`Segment.sequences`, started from
    the LSTM states of ``net`` before any update, the network that acted; the whole segment without
    a ``sequence_length``) and their targets: GAE advantages and value targets under that network,
    bootstrapped from the value of the observation after the segment's last step, and the
    log-probabilities recorded while acting (and ``kl``, π^s's part, carried along)."""
    if segment.log_probs is None:
        raise ValueError("a PPO update needs the segment's log-probabilities of the acting policy (Segment.log_probs)")
    length = settings.sequence_length or segment.steps
    all_values, states = sequence_start_states(net, segment, length)
    values, bootstrap = all_values[:-1], all_values[-1]
    advantages, returns = advantages_and_targets(
        segment.rewards, segment.ends, values, bootstrap, settings.gamma, settings.gae_lambda
    )
    targets = RolloutTargets(advantages, returns, values, segment.log_probs, kl)
    if length == segment.steps:
        return segment, targets
    return segment.sequences(length, states), targets.sequences(length)


def ppo_minibatch_loss(
    net: RecurrentActorCritic,
    segment: Segment,
    targets: RolloutTargets,
    settings: PPOOptimizationSettings,
    *,
    critic_only: bool = False,
) -> tuple[torch.Tensor, dict[str, float]]:
    """The PPO loss of one minibatch (``segment`` and ``targets`` of the same environments): the
    clipped surrogate, the (optionally clipped) value loss, the entropy bonus and, for a network with
    auxiliary heads, their loss; when fine-tuning keeps π^s, the weighted KL(π^s ‖ π) (logged as
    ``kl``). Log-probabilities and entropy are those of the network's action
    distribution (categorical or Gaussian: :meth:`~bimgame.learn.nets.RecurrentActorCritic.distribution`).
    ``critic_only`` (a critic warm-up): the loss is the weighted value loss alone; the surrogate's
    parts are still logged (the KL and auxiliary losses are not computed)."""
    out = unroll(net, segment)
    policy = net.distribution(out.logits[:-1], settings.sample_temperature)
    chosen = policy.log_prob(segment.actions)
    entropy = policy.entropy().mean()
    log_ratio = chosen - targets.log_probs
    ratio = log_ratio.exp()
    advantages = targets.advantages
    if settings.advantage_norm:
        advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    surrogate = torch.max(-advantages * ratio, -advantages * ratio.clamp(1 - settings.clip, 1 + settings.clip))
    policy_loss = surrogate.mean()
    values = out.values[:-1]
    value_error = (values - targets.returns).pow(2)
    if settings.value_clip is not None:
        clipped = targets.values + (values - targets.values).clamp(-settings.value_clip, settings.value_clip)
        value_error = torch.max(value_error, (clipped - targets.returns).pow(2))
    value_loss = 0.5 * value_error.mean()
    loss = policy_loss - settings.entropy_coef * entropy + settings.value_coef * value_loss
    with torch.no_grad():
        parts = {
            "policy_loss": policy_loss.item(),
            "value_loss": value_loss.item(),
            "entropy": entropy.item(),
            "approx_kl": ((ratio - 1) - log_ratio).mean().item(),  # Schulman's low-variance estimator
            "clip_fraction": ((ratio - 1).abs() > settings.clip).float().mean().item(),
        }
    if critic_only:
        return settings.value_coef * value_loss, parts
    if net.config.aux_heads:
        if segment.privileged is None:
            raise ValueError(
                "a network with auxiliary heads needs the segment's privileged states (Segment.privileged)"
            )
        aux, aux_parts = net.aux_loss(out.features, out.hidden, segment.privileged)
        parts.update(aux_parts)
        loss = loss + settings.aux_coef * aux
    if targets.kl is not None:
        kl = policy_kl(net, targets.kl.policy, out.logits[:-1], means_only=targets.kl.means_only)
        parts["kl"] = kl.item()
        if targets.kl.weight > 0:
            loss = loss + targets.kl.weight * kl
    return loss, parts


def ppo_update(
    net: RecurrentActorCritic,
    optimizer: torch.optim.Optimizer,
    segment: Segment,
    settings: PPOOptimizationSettings,
    generator: torch.Generator,
    *,
    average: GradientAverage | None = None,
    kl: KLTarget | None = None,
    critic_only: bool = False,
) -> dict[str, float]:
    """Train ``net`` on one rollout: ``epochs`` passes over minibatches of whole sequences (each
    environment's rollout, or its pieces of ``sequence_length`` steps), drawn from ``generator``.
    Returns the losses and statistics averaged over the minibatches, and ``applied``: False if a
    loss or gradient was not finite (that minibatch, and the rest of the update, is then skipped so
    that no non-finite value reaches the weights). With ``average``, each minibatch's gradient is
    averaged over the run's ranks before the step, and a loss that is not finite on any rank skips
    the update on every rank. With ``kl``, the loss also holds its weight times KL(π^s ‖ π). With
    ``critic_only`` (a critic warm-up) only the critic's weights change, on the value loss alone: the
    trunk the policy shares with it (encoder, LSTM) and the policy head keep theirs."""
    segment, targets = rollout_targets(net, segment, settings, kl)
    sums: dict[str, float] = {}
    count = 0
    for _ in range(settings.epochs):
        order = torch.randperm(segment.batch, generator=generator)
        for index in order.chunk(settings.minibatches):
            loss, parts = ppo_minibatch_loss(
                net, segment.envs(index), targets.envs(index), settings, critic_only=critic_only
            )
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            finite = math.isfinite(loss.item())
            if average is not None:
                finite = average(net, finite)
            if critic_only:
                keep_critic_gradients(net)
            grad_norm = float(torch.nn.utils.clip_grad_norm_(net.parameters(), settings.max_grad_norm))
            if not (finite and math.isfinite(grad_norm)):
                return {**parts, "grad_norm": grad_norm, "loss": loss.item(), "applied": False}
            optimizer.step()
            for key in _AVERAGED:
                if key == "grad_norm" or key in parts:  # (kl: when fine-tuning keeps π^s; aux_*: with heads)
                    sums[key] = sums.get(key, 0.0) + (grad_norm if key == "grad_norm" else parts[key])
            count += 1
    return {**{key: value / count for key, value in sums.items()}, "applied": True}
