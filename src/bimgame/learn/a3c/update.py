"""What A3C's parent and worker processes share besides the settings: the network and the shared
optimiser a run starts from, the loss of one segment and the Hogwild update, and the run's periodic
evaluation."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch

from bimgame.envs.puzzles import PuzzleSpec, puzzle
from bimgame.learn.a3c.settings import A3CConfig
from bimgame.learn.finetune import LossWeights, RunningScale, keep_critic_gradients
from bimgame.learn.loss_terms import LossTerm
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.rollout import Segment, advantages_and_targets, unroll

__all__ = [
    "network_for",
    "make_optimizer",
    "shared_optimizer_state",
    "a3c_segment_loss",
    "apply_update",
]


def network_for(config: A3CConfig, maze: PuzzleSpec | None = None) -> RecurrentActorCritic:
    """A fresh network for ``config``'s run, initialised from its seed, on the board ``maze`` (None: its
    task's, :attr:`~bimgame.envs.puzzles.Puzzle.spec`: MERL's maze, or the labyrinth's layout)."""
    return config.network.build_policy(config.seed, maze if maze is not None else puzzle(config.task).spec)


def make_optimizer(config: A3CConfig, net: RecurrentActorCritic) -> torch.optim.Optimizer:
    """The optimiser of ``net``'s parameters; with a scheduled actor, the policy head is parameter
    group 0 (its learning rate is set per update) and the rest group 1."""
    if config.schedules_actor:
        head = {id(p) for p in net.policy.parameters()}
        params: Any = [
            {"params": list(net.policy.parameters())},
            {"params": [p for p in net.parameters() if id(p) not in head]},
        ]
    else:
        params = net.parameters()
    settings = config.optimization
    if settings.optimizer == "rmsprop":
        return torch.optim.RMSprop(params, lr=settings.lr, alpha=settings.rmsprop_alpha, eps=settings.optimizer_eps)
    return torch.optim.Adam(params, lr=settings.lr, eps=settings.optimizer_eps)


def shared_optimizer_state(optimizer: torch.optim.Optimizer) -> list[dict[str, torch.Tensor]]:
    """Create every parameter's optimiser statistics (if not loaded) and move them to shared memory,
    so all workers update the same statistics (A3C's 'shared RMSProp')."""
    params = [p for group in optimizer.param_groups for p in group["params"]]
    if not optimizer.state:
        # One step with zero gradients creates the statistics without changing any weight (RMSProp
        # and Adam both move by 0 for a zero gradient); then the step counts are reset to 0.
        for p in params:
            p.grad = torch.zeros_like(p)
        optimizer.step()
        for p in params:
            p.grad = None
            optimizer.state[p]["step"].zero_()
    states = []
    for p in params:
        state = optimizer.state[p]
        for value in state.values():
            if torch.is_tensor(value):
                value.share_memory_()
        states.append(state)
    return states


def a3c_segment_loss(
    net: RecurrentActorCritic,
    segment: Segment,
    config: A3CConfig,
    weights: LossWeights = LossWeights(),
    *,
    terms: Sequence[LossTerm] = (),
    advantage_scale: RunningScale | None = None,
    entropy_coef: float | None = None,
) -> tuple[torch.Tensor, dict[str, float]]:
    """The actor-critic loss of one :class:`~bimgame.learn.rollout.Segment` (T steps × B envs),
    recomputed with gradients from the LSTM state the segment started from.

    A network with auxiliary heads adds ``aux_coef`` times their loss
    (:meth:`~bimgame.learn.nets.RecurrentActorCritic.aux_loss`), which needs the segment's
    ``privileged`` states. ``terms`` are the run's optional loss terms (:mod:`bimgame.learn.loss_terms`),
    already prepared with this segment; ``weights`` scales the actor's terms and theirs, and during a
    critic warm-up the loss is the value loss alone. ``advantage_scale`` divides the advantages by
    their running RMS; ``entropy_coef`` replaces ``config.entropy_coef`` (an adapting coefficient,
    see :class:`~bimgame.learn.finetune.EntropyTarget`)."""
    settings = config.optimization
    privileged = segment.privileged
    out = unroll(net, segment)
    logits, bootstrap, values = out.logits[:-1], out.values[-1].detach(), out.values[:-1]
    advantages, targets = advantages_and_targets(
        segment.rewards, segment.ends, values.detach(), bootstrap, settings.gamma, settings.gae_lambda
    )
    value_loss = 0.5 * (targets - values).pow(2).mean()
    log_probs = torch.log_softmax(logits, dim=-1)
    entropy = -(log_probs.exp() * log_probs).sum(-1).mean()
    if advantage_scale is not None:
        advantages = advantages / advantage_scale.update(advantages)
    chosen = log_probs.gather(-1, segment.actions.unsqueeze(-1)).squeeze(-1)
    policy_loss = -(chosen * advantages).mean()
    parts = {"policy_loss": policy_loss.item(), "value_loss": value_loss.item(), "entropy": entropy.item()}
    added: list[torch.Tensor] = []
    if net.config.aux_heads:
        if privileged is None:
            raise ValueError(
                "a network with auxiliary heads needs the segment's privileged states (Segment.privileged)"
            )
        aux, aux_parts = net.aux_loss(out.features, out.hidden, privileged)
        parts.update(aux_parts)
        added.append(settings.aux_coef * aux)
    for term in terms:
        contribution, term_parts = term.loss(net, log_probs, weights)
        parts.update(term_parts)
        if contribution is not None:
            added.append(contribution)
    if weights.critic_only:
        return settings.value_coef * value_loss, parts
    beta = settings.entropy_coef if entropy_coef is None else entropy_coef
    loss = weights.actor * (policy_loss - beta * entropy) + settings.value_coef * value_loss
    for contribution in added:
        loss = loss + contribution
    return loss, parts


def apply_update(
    local: RecurrentActorCritic,
    shared_params: Sequence[torch.Tensor],
    optimizer: torch.optim.Optimizer,
    segment: Segment,
    config: A3CConfig,
    weights: LossWeights = LossWeights(),
    *,
    terms: Sequence[LossTerm] = (),
    advantage_scale: RunningScale | None = None,
    entropy_coef: float | None = None,
) -> dict[str, float]:
    """One A3C update: the segment's loss, its gradient (norm clipped) on the local network, applied
    to the shared weights by the shared optimiser. A non-finite loss or gradient is not applied
    (``applied`` is False in the returned losses). ``weights``, ``terms``, ``advantage_scale`` and
    ``entropy_coef`` are those of :func:`a3c_segment_loss`; during a critic warm-up only the value head
    changes, and with a scheduled actor the policy head's learning rate is ``lr · weights.actor``."""
    loss, parts = a3c_segment_loss(
        local, segment, config, weights, terms=terms, advantage_scale=advantage_scale, entropy_coef=entropy_coef
    )
    local.zero_grad(set_to_none=True)
    loss.backward()
    if weights.critic_only:
        keep_critic_gradients(local)
    grad_norm = float(torch.nn.utils.clip_grad_norm_(local.parameters(), config.optimization.max_grad_norm))
    applied = math.isfinite(loss.item()) and math.isfinite(grad_norm)
    if applied:
        if config.schedules_actor:
            optimizer.param_groups[0]["lr"] = config.optimization.lr * weights.actor
        for shared_param, param in zip(shared_params, local.parameters(), strict=True):
            shared_param.grad = param.grad
        optimizer.step()
    return {**parts, "loss": loss.item(), "grad_norm": grad_norm, "applied": applied}
