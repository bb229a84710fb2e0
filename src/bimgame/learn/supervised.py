"""Supervised learning on whole episodes: the paper's pre-training loss, shared by pre-training
(:mod:`bimgame.learn.pretrain`) and DAgger's retraining step (:mod:`bimgame.learn.dagger`), so that
neither learner imports the other.

The A3C network itself is trained on whole episodes with the paper's loss, per step

    L = −log π(a*|s) + value_coef · ½ (V(s) − G)²        (+ l2 · ‖θ‖² per update)

where a* is the expert's action and G the discounted return-to-go. Episodes are fed as sequences,
from their first step, with the previous action and reward as inputs — exactly what the LSTM sees
in A3C — in chunks of ``bptt`` steps (the LSTM state carries over between the chunks of an episode,
the gradient does not: truncated backpropagation through time, as A3C's ``n_steps`` segments).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Iterator
from typing import ClassVar

import numpy as np
import torch

from bimgame.envs.env import NO_ACTION
from bimgame.envs.puzzles import puzzle, puzzle_task_setting
from bimgame.expert.episode import Episode
from bimgame.learn.common import NetworkSettings, check_seed
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.util.settings import require_int

__all__ = [
    "PretrainConfig",
    "TARGETS",
    "split_episodes",
    "padded_batch",
    "l2_penalty",
    "policy_loss_terms",
    "policy_epoch",
    "policy_batches",
    "summarise",
    "train_policy_epochs",
]

TARGETS = ("policy", "value")


@dataclasses.dataclass(frozen=True)
class PretrainConfig(NetworkSettings):
    """Settings of supervised learning on episodes: pre-training π^s or V̂, and DAgger's learner.
    The network settings (``obs``, ``hidden``, ``features``, …) are inherited from
    :class:`~bimgame.learn.common.NetworkSettings`."""

    task: str = "FULL"
    """Task whose rewards give the value targets (episodes are relabelled, see
    :func:`bimgame.expert.episode.relabel`)."""
    target: str = "policy"
    """``policy``: the actor-critic π^s; ``value``: the value-only network V̂."""
    epochs: int = 30
    """Upper bound on passes over the training episodes (early stopping usually ends sooner)."""
    patience: int = 5
    """Stop after this many epochs without a better held-out loss."""
    lr: float = 1e-3
    """Adam's learning rate."""
    l2: float = 1e-5
    """λ of the L2 penalty λ‖θ‖² on the weight matrices (biases and norms excluded)."""
    value_coef: float = 1.0
    """Weight of ½(V − G)² against the cross-entropy (the paper's loss: 1)."""
    gamma: float = 0.99
    """Discount of the return targets (A3C's γ)."""
    batch_episodes: int = 16
    """Policy: episodes per batch (sequences run side by side)."""
    batch_frames: int = 64
    """Value: frames per batch (256 underfit a 60-episode dataset: held-out RMSE 0.12 against 0.09)."""
    bptt: int = 50
    """Policy: steps per truncated-backpropagation chunk."""
    max_grad_norm: float = 1.0
    """Clip each update's gradient to this global norm."""
    val_fraction: float = 0.2
    """Share of episodes held out for validation (at least one)."""
    seed: int = 0
    """Seeds the network's initial weights, the train/held-out split and the batch order."""
    eval_episodes: int = 50
    """Episodes to measure π^s alone as a policy after training (0: skip)."""
    aux_coef: float = 1.0
    """Weight of the auxiliary heads' loss (predicting the recorded states) when the network has
    them (``aux_heads``)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "task", puzzle_task_setting("PretrainConfig", self.task))
        if self.target not in TARGETS:
            raise ValueError(f"PretrainConfig.target must be one of {TARGETS}, got {self.target!r}")
        for name in ("epochs", "patience", "batch_episodes", "batch_frames", "bptt"):
            require_int("PretrainConfig", name, getattr(self, name), 1)
        check_seed("PretrainConfig", self.seed)  # numpy's seed sequences take no negative seeds, torch none of 2**64
        require_int("PretrainConfig", "eval_episodes", self.eval_episodes, 0)
        for name, low, high, open_low in (
            ("lr", 0, math.inf, True),
            ("max_grad_norm", 0, math.inf, True),
            ("l2", 0, math.inf, False),
            ("value_coef", 0, math.inf, False),
            ("aux_coef", 0, math.inf, False),
            ("gamma", 0, 1, False),
            ("val_fraction", 0, 1, True),
        ):
            value = getattr(self, name)
            ok = (
                isinstance(value, (int, float))
                and math.isfinite(value)
                and value <= high
                and (value > low if open_low else value >= low)
            )
            if not ok or (name == "val_fraction" and value >= 1):
                bound = "(0, 1)" if name == "val_fraction" else (f"({low}, {high}]" if open_low else f"[{low}, {high}]")
                raise ValueError(f"PretrainConfig.{name} must be in {bound}, got {value!r}")

    @property
    def time_limit(self) -> int:
        """The task's time limit (evaluations of the learned policy use it)."""
        return puzzle(self.task).time_limit

    SETTINGS_NAME: ClassVar[str] = "pre-training settings"


# ------------------------------------------------------------------------------------- data
def split_episodes(count: int, val_fraction: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(training, held-out) episode indices: a seeded shuffle, at least one episode in each."""
    if count < 2:
        raise ValueError(f"pre-training needs at least 2 episodes (one held out), got {count}")
    order = rng.permutation(count)
    held = min(count - 1, max(1, round(val_fraction * count)))
    return np.sort(order[held:]), np.sort(order[:held])


def padded_batch(sequences: list[Episode], max_tilt: float, steps: int | None = None) -> dict[str, torch.Tensor]:
    """Episodes side by side, (T, B, …), padded at the end to the longest (or to ``steps``); ``mask``
    marks real steps. ``privileged`` holds the state observations when every episode has them.
    Actions keep the episodes' kind: (T, B) int64 discrete or (T, B, 2) float32 continuous."""
    steps = max(len(s) for s in sequences) if steps is None else steps
    batch = len(sequences)
    obs_shape = sequences[0].obs.shape[1:]
    obs = np.zeros((steps, batch, *obs_shape), dtype=sequences[0].obs.dtype)
    actions = sequences[0].actions
    continuous = np.issubdtype(actions.dtype, np.floating)
    out: dict[str, np.ndarray] = {
        "actions": np.zeros((steps, batch, *actions.shape[1:]), actions.dtype),
        "prev_action": np.full((steps, batch, *actions.shape[1:]), 0 if continuous else NO_ACTION, actions.dtype),
        "prev_reward": np.zeros((steps, batch), np.float32),
        "tilt": np.zeros((steps, batch, 2), np.float32),
        "returns": np.zeros((steps, batch), np.float32),
        "mask": np.zeros((steps, batch), bool),
    }
    for b, s in enumerate(sequences):
        n = len(s)
        obs[:n, b] = s.obs
        out["actions"][:n, b] = s.actions
        out["prev_action"][:n, b] = s.prev_actions
        out["prev_reward"][:n, b] = s.prev_rewards
        out["tilt"][:n, b] = s.tilt / max_tilt
        out["returns"][:n, b] = s.returns
        out["mask"][:n, b] = True
    state_obs = [s.state_obs for s in sequences if s.state_obs is not None]
    if len(state_obs) == len(sequences):
        out["privileged"] = np.zeros((steps, batch, state_obs[0].shape[1]), np.float32)
        for b, (s, states) in enumerate(zip(sequences, state_obs, strict=True)):
            out["privileged"][: len(s), b] = states
    tensors = {k: torch.as_tensor(v) for k, v in out.items()}
    tensors["obs"] = torch.as_tensor(obs)
    return tensors


# --------------------------------------------------------------------------------- the loss
def l2_penalty(net: torch.nn.Module) -> torch.Tensor:
    """‖θ‖² over weight matrices and kernels (biases, norms and fixed buffers excluded)."""
    return sum((p.pow(2).sum() for p in net.parameters() if p.dim() > 1), torch.zeros(()))


def policy_loss_terms(
    net: RecurrentActorCritic,
    batch: dict[str, torch.Tensor],
    config: PretrainConfig,
    optimizer: torch.optim.Optimizer | None = None,
) -> dict[str, float]:
    """The pre-training loss over a padded batch of episodes, chunk by chunk (truncated BPTT);
    with ``optimizer``, one update per chunk. Returns sums over real steps: ``ce`` (−log π of the
    expert's action), ``value_se`` (squared value error), ``correct`` (greedy action = expert's, see
    :func:`_agrees`), ``count``, and for a network with auxiliary heads ``aux`` (their loss, which
    is added with weight ``config.aux_coef``)."""
    steps, width = batch["mask"].shape
    state = net.initial_state(width)
    totals = {"ce": 0.0, "value_se": 0.0, "correct": 0.0, "count": 0.0, "aux": 0.0}
    tilt_on = net.config.tilt_input
    privileged = batch.get("privileged")
    if (net.config.aux_heads or net.config.asymmetric_critic) and privileged is None:
        raise ValueError(
            "this network's auxiliary heads / asymmetric critic need the episodes' state observations "
            "(Episode.state_obs), which these episodes lack"
        )
    for t0 in range(0, steps, config.bptt):
        sl = slice(t0, min(steps, t0 + config.bptt))
        mask = batch["mask"][sl]
        if not mask.any():
            break
        starts = torch.zeros_like(mask)
        if t0 == 0:
            starts[0] = True
        out = net.unroll_features(
            batch["obs"][sl],
            batch["prev_action"][sl],
            batch["prev_reward"][sl],
            batch["tilt"][sl] if tilt_on else None,
            state,
            starts,
            privileged=None if privileged is None else privileged[sl],
        )
        logits, values = out.logits, out.values
        state = type(state)(out.state.h.detach(), out.state.c.detach())
        weights = mask.float()
        count = weights.sum()
        policy = net.distribution(logits)
        ce = -policy.log_prob(batch["actions"][sl])
        value_se = (values - batch["returns"][sl]).pow(2)
        data_loss = ((ce + config.value_coef * 0.5 * value_se) * weights).sum() / count
        if net.config.aux_heads:
            assert privileged is not None  # refused above
            aux, _ = net.aux_loss(out.features, out.hidden, privileged[sl], mask)
            data_loss = data_loss + config.aux_coef * aux
            totals["aux"] += float(aux.detach()) * float(count)
        if optimizer is not None:
            loss = data_loss + config.l2 * l2_penalty(net)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), config.max_grad_norm)
            optimizer.step()
        totals["ce"] += float((ce.detach() * weights).sum())
        totals["value_se"] += float((value_se.detach() * weights).sum())
        totals["correct"] += float((_agrees(policy.greedy(), batch["actions"][sl]) * weights).sum())
        totals["count"] += float(count)
    return totals


#: A continuous action "agrees" with the expert's when each tilt change is within this of it: half the
#: spacing of the labyrinth expert's 5 rate levels (:class:`~bimgame.expert.labyrinth_mpc.LabyrinthMPCConfig`).
CONTINUOUS_AGREEMENT = 0.25


def _agrees(greedy: torch.Tensor, expert: torch.Tensor) -> torch.Tensor:
    """1 where the network's greedy action is the expert's (discrete: the same action; continuous:
    every component within :data:`CONTINUOUS_AGREEMENT`), else 0 — the accuracy's numerator."""
    if expert.is_floating_point():
        return ((greedy - expert).abs() <= CONTINUOUS_AGREEMENT).all(-1).float()
    return (greedy == expert).float()


def summarise(totals: dict[str, float], value_coef: float, policy: bool) -> dict[str, float]:
    """Mean loss (the policy's and value's: what early stopping compares), accuracy, value RMSE and
    the auxiliary heads' loss (NaN without them) from :func:`policy_loss_terms`' sums."""
    count = max(totals["count"], 1.0)
    value_mse = totals["value_se"] / count
    loss = (totals["ce"] / count if policy else 0.0) + value_coef * 0.5 * value_mse
    aux = totals["aux"] / count if totals.get("aux") else float("nan")
    return {
        "loss": loss,
        "accuracy": totals["correct"] / count if policy else float("nan"),
        "value_rmse": math.sqrt(value_mse),
        "aux": aux,
    }


def policy_batches(
    sequences: list[Episode], order: np.ndarray, config: PretrainConfig, max_tilt: float
) -> Iterator[dict[str, torch.Tensor]]:
    """The padded batches of ``config.batch_episodes`` episodes each, in ``order``."""
    for start in range(0, len(order), config.batch_episodes):
        yield padded_batch([sequences[i] for i in order[start : start + config.batch_episodes]], max_tilt)


def policy_epoch(
    net: RecurrentActorCritic,
    batches: Iterable[dict[str, torch.Tensor]],
    config: PretrainConfig,
    optimizer: torch.optim.Optimizer | None,
) -> dict[str, float]:
    """One pass of the loss over ``batches``: training with ``optimizer``, else measuring only."""
    totals = {"ce": 0.0, "value_se": 0.0, "correct": 0.0, "count": 0.0, "aux": 0.0}
    net.train(optimizer is not None)
    with torch.set_grad_enabled(optimizer is not None):
        for batch in batches:
            for key, value in policy_loss_terms(net, batch, config, optimizer).items():
                totals[key] += value
    return summarise(totals, config.value_coef, policy=True)


def train_policy_epochs(
    net: RecurrentActorCritic,
    sequences: list[Episode],
    config: PretrainConfig,
    epochs: int,
    rng: np.random.Generator,
    max_tilt: float,
) -> dict[str, float]:
    """``epochs`` passes of the pre-training loss over all ``sequences`` (no hold-out; DAgger's
    retraining step). Returns the last epoch's training summary."""
    optimizer = torch.optim.Adam(net.parameters(), lr=config.lr)
    summary: dict[str, float] = {}
    for _ in range(epochs):
        order = rng.permutation(np.arange(len(sequences)))
        summary = policy_epoch(net, policy_batches(sequences, order, config, max_tilt), config, optimizer)
    return summary
