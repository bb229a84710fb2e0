"""Fine-tuning a pre-trained policy π^s with A3C without forgetting it.

The paper's open problem: A3C started from π^s "gradually forgets its previous training" on the
sparse tasks (STG3, STG4). Measured here, three causes: the inherited critic does not fit the new
task, so the first advantages are noise; the entropy bonus (0.01 · ln 5) dwarfs a sparse +1 that
is worth 0.99^400 ≈ 0.02 at the start, so the entropy term alone unlearns the cloned policy; and the
step size of a from-scratch run is too large for a policy that is already good. The methods here
address one cause each, as A3C settings (:class:`~bimgame.learn.a3c.update.A3CConfig`):

- **critic warm-up** (``critic_warmup_steps``): only the value head learns, on the learner's own
  rollouts, so the advantages mean something before the policy moves; then the actor's learning
  rate (and its loss terms) ramp up from zero over ``actor_ramp_steps``;
- **kickstarting** (Schmitt et al. 2018, ``kl_coef`` / ``kl_decay_steps``): an annealed
  KL(π^s ‖ π) on the learner's own rollouts; the frozen teacher follows the same episodes with its
  own LSTM state (:class:`Teacher`);
- **behaviour cloning on the expert data** (DAPG, Rajeswaran et al. 2018, ``expert_data`` /
  ``bc_coef`` / ``bc_decay_steps``): a cross-entropy term on windows of the expert episodes
  (:class:`DemoWindows`), its weight decaying to zero;
- **advantage scaling** (``advantage_norm``): advantages divided by a running RMS of the
  advantages (:class:`RunningScale`), so the policy gradient has unit scale whatever the task's
  reward density — this is what keeps the entropy bonus and the KL weight meaningful on every task
  without tuning them per task. A running scale instead of per-segment normalisation: a segment
  without any reward holds only the critic's noise, which per-segment normalisation would blow up
  to unit size.

Demonstration-start and reverse curricula change where episodes start, not the loss: see
:mod:`bimgame.learn.starts`.

:data:`~bimgame.learn.learner_settings.FINETUNE_PRESETS` names the combinations: ``paper`` (plain
fine-tuning, which forgets) and ``keep`` (the default of ``bimgame train --init``: critic warm-up and
actor ramp, a constant KL to a sharpened π^s, advantage scaling). How ``keep`` was chosen, and what
did not help, is measured in ``docs/finetune/README.md``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import torch

from bimgame.expert.datasets import iterate_sequences
from bimgame.expert.episode import Episode, relabel
from bimgame.learn.learner_settings import FinetuneSettings
from bimgame.learn.nets import LSTMState, RecurrentActorCritic
from bimgame.learn.policy_heads import categorical_kl
from bimgame.learn.rollout import Segment
from bimgame.learn.supervised import padded_batch
from bimgame.sim.maze import MazeSpec

__all__ = [
    "LossWeights",
    "loss_weights",
    "keep_critic_gradients",
    "Teacher",
    "kl_to_teacher",
    "policy_kl",
    "RunningScale",
    "EntropyTarget",
    "DemoWindows",
    "bc_loss",
]


@dataclasses.dataclass(frozen=True)
class LossWeights:
    """The weights of an update's loss terms at one point of a run."""

    actor: float = 1.0
    """Multiplies the policy-gradient and entropy terms and the policy head's learning rate."""
    kl: float = 0.0
    """Weight of KL(π^s ‖ π)."""
    bc: float = 0.0
    """Weight of the behaviour-cloning cross-entropy."""
    critic_only: bool = False
    """Critic warm-up: only the value head learns."""


def _linear_decay(initial: float, step: int, over: int) -> float:
    if over <= 0:
        return initial
    return initial * max(0.0, 1.0 - step / over)


def loss_weights(settings: FinetuneSettings | None, step: int) -> LossWeights:
    """The loss weights at environment step ``step`` of a run with fine-tuning ``settings`` (None: a run
    from scratch, whose weights never change)."""
    if settings is None:
        return LossWeights()
    warmup, ramp = settings.critic_warmup_steps, settings.actor_ramp_steps
    if step < warmup:
        actor = 0.0
    elif ramp > 0:
        actor = min(1.0, (step - warmup) / ramp)
    else:
        actor = 1.0
    return LossWeights(
        actor=actor,
        kl=_linear_decay(settings.kl_coef, step, settings.kl_decay_steps),
        bc=_linear_decay(settings.bc_coef, step, settings.bc_decay_steps),
        critic_only=step < warmup,
    )


def keep_critic_gradients(net: RecurrentActorCritic) -> None:
    """Drop every gradient of ``net`` but the critic's
    (:meth:`~bimgame.learn.nets.RecurrentActorCritic.critic_parameters`), after the backward pass of a
    critic warm-up: the optimiser leaves a parameter without a gradient untouched, so only the value
    estimate changes and the policy acts as loaded (A3C and PPO alike)."""
    critic = {id(param) for param in net.critic_parameters()}
    for param in net.parameters():
        if id(param) not in critic:
            param.grad = None


class Teacher:
    """The frozen pre-trained policy π^s, following the learner's episodes.

    It sees exactly what the learner saw (observations, previous actions and rewards, tilts, episode
    starts), one segment at a time, and carries its own LSTM state across segments, so its action
    distribution is the one π^s would have had in the learner's situation."""

    def __init__(self, net: RecurrentActorCritic, batch: int, temperature: float = 1.0):
        self.net = net.eval()
        self.temperature = temperature
        for param in self.net.parameters():
            param.requires_grad_(False)
        self.state: LSTMState = net.initial_state(batch)

    def become(self, weights: dict[str, torch.Tensor], state: LSTMState) -> None:
        """The teacher becomes the policy of ``weights`` (on any device; copied), following its episodes
        from ``state`` on (the LSTM states are never changed in place, so it is not copied)."""
        self.net.load_state_dict(weights)
        self.state = state

    @torch.no_grad()
    def follow(self, segment: Segment) -> torch.Tensor:
        """The teacher's π over a segment's T acting steps (the segment holds T+1 observations, the
        last being the bootstrap one), (T, B, P) as its action head freezes it
        (:meth:`~bimgame.learn.policy_heads.ActionHead.frozen`): discrete, the log-probabilities of its
        logits divided by the temperature (below 1: a sharper teacher, towards its greedy action);
        continuous, its Gaussian's mean and log standard deviation, the deviation times the
        temperature. Advances its state."""
        steps = segment.steps
        tilt = segment.tilt
        logits, _, self.state = self.net.unroll(
            segment.obs[:steps],
            segment.prev_action[:steps],
            segment.prev_reward[:steps],
            None if tilt is None else tilt[:steps],
            self.state,
            segment.starts[:steps],
        )
        return self.net.action_head.frozen(logits, self.net.log_std, self.temperature)


def policy_kl(
    net: RecurrentActorCritic, teacher: torch.Tensor, output: torch.Tensor, *, means_only: bool = False
) -> torch.Tensor:
    """Mean over steps of KL(π^s ‖ π) for either kind of action: ``teacher`` from
    :meth:`Teacher.follow`, ``output`` the learner's policy-head output on the same steps (with its
    ``log_std``, continuous). Discrete, it equals :func:`kl_to_teacher` of the log-softmax.
    ``means_only`` (continuous): the learner's Gaussian taken at the teacher's standard deviation,
    KL(N(μ_t, σ_t) ‖ N(μ, σ_t)) = Σ (μ − μ_t)² / 2σ_t², which leaves the learner's σ free."""
    log_std = net.action_head.frozen_log_std(teacher) if means_only else net.log_std
    return net.action_head.kl_from(teacher, output, log_std).mean()


def kl_to_teacher(teacher_log_probs: torch.Tensor, log_probs: torch.Tensor) -> torch.Tensor:
    """Mean over steps of KL(π^s ‖ π) = Σ_a π^s(a) (log π^s(a) − log π(a)); zero when π = π^s.
    Its gradient is that of the cross-entropy to the teacher's distribution (kickstarting)."""
    return categorical_kl(teacher_log_probs, log_probs).mean()


class RunningScale:
    """A running root-mean-square of the advantages (exponential average over updates), that
    advantages are divided by: the policy gradient then has unit scale on every task."""

    def __init__(self, decay: float = 0.99, eps: float = 1e-8):
        self.decay, self.eps = decay, eps
        self.mean_square: float | None = None

    def update(self, advantages: torch.Tensor) -> float:
        """Fold in one update's advantages; returns the scale to divide them by."""
        value = float(advantages.detach().pow(2).mean())
        if math.isfinite(value):
            self.mean_square = (
                value if self.mean_square is None else self.decay * self.mean_square + (1.0 - self.decay) * value
            )
        return math.sqrt(self.mean_square or 0.0) + self.eps


class EntropyTarget:
    """An entropy coefficient that adapts so that the policy's entropy follows a target, instead of a
    fixed bonus whose effect depends on the scale of the task's rewards.

    The target falls linearly from the policy's entropy at the first update (π^s's, when fine-tuning)
    to ``final`` nats over ``steps`` environment steps. After each update the coefficient β moves by
    ``rate · (target − entropy)``, within ±``bound``: above the target β turns negative and the
    term sharpens the policy, below it β turns positive and keeps the policy from collapsing. Why:
    the cloned π^s is nearly uniform (entropy ≈ 1.45 of at most ln 5 ≈ 1.61 nats); a fixed bonus
    keeps it so, and a nearly uniform policy that succeeds when sampled has an arbitrary greedy
    action (measured in ``docs/finetune/README.md``)."""

    def __init__(self, final: float, steps: int, initial_coef: float, *, rate: float = 1e-3, bound: float = 0.05):
        self.final, self.steps, self.rate, self.bound = final, steps, rate, bound
        self.coef = float(initial_coef)
        self.start: float | None = None

    def target(self, step: int) -> float:
        start = self.final if self.start is None else self.start
        if self.steps <= 0:
            return self.final
        return start + (self.final - start) * min(1.0, step / self.steps)

    def update(self, entropy: float, step: int) -> float:
        """Fold in an update's mean entropy at environment step ``step``; returns the coefficient of
        the next update."""
        if not math.isfinite(entropy):
            return self.coef
        if self.start is None:
            self.start = max(entropy, self.final)
        self.coef = min(self.bound, max(-self.bound, self.coef + self.rate * (self.target(step) - entropy)))
        return self.coef


class DemoWindows:
    """Windows of the expert's episodes for the behaviour-cloning term: ``batch`` windows of
    ``length`` steps, each from a random episode and a random start, the LSTM starting from zero at
    the window's first step (the loss skips the first ``burn_in`` steps, where its state is not yet
    the one the episode would have built). Episodes are relabelled for the task, so they end where
    the task's goal is reached."""

    def __init__(self, episodes: list[Episode], max_tilt: float, *, length: int = 40, burn_in: int = 10):
        if not episodes:
            raise ValueError("the behaviour-cloning data holds no episode")
        self.episodes = episodes
        self.max_tilt = max_tilt
        self.length, self.burn_in = length, burn_in

    @classmethod
    def from_dataset(cls, path: str, task: str, obs: str, gamma: float, maze: MazeSpec, **kwargs: Any) -> DemoWindows:
        episodes = [relabel(e, task, gamma, maze) for e in iterate_sequences(path, obs=obs, gamma=gamma)]
        return cls([e for e in episodes if len(e) > 0], maze.max_tilt, **kwargs)

    def sample(self, batch: int, rng: np.random.Generator) -> dict[str, torch.Tensor]:
        """(L, B, …) tensors ``obs``, ``prev_action``, ``prev_reward``, ``tilt``, ``actions`` and
        ``mask`` (real steps after the burn-in), as :func:`~bimgame.learn.supervised.padded_batch`
        lays episodes out."""
        windows, starts = [], []
        for _ in range(batch):
            episode = self.episodes[int(rng.integers(len(self.episodes)))]
            start = int(rng.integers(max(1, len(episode) - self.burn_in)))
            windows.append(episode.window(start, start + self.length))
            starts.append(start)
        out = padded_batch(windows, self.max_tilt, steps=self.length)
        for b, start in enumerate(starts):
            if start > 0:  # the LSTM starts from zero mid-episode: no loss until its state has built up
                out["mask"][: self.burn_in, b] = False
        return out


def bc_loss(net: RecurrentActorCritic, windows: dict[str, torch.Tensor]) -> torch.Tensor:
    """Mean cross-entropy of the expert's actions over the real, burnt-in steps of ``windows``."""
    steps, batch = windows["actions"].shape
    starts = torch.zeros(steps, batch, dtype=torch.bool)
    starts[0] = True
    logits, _, _ = net.unroll(
        windows["obs"],
        windows["prev_action"],
        windows["prev_reward"],
        windows["tilt"] if net.config.tilt_input else None,
        net.initial_state(batch),
        starts,
    )
    ce = torch.nn.functional.cross_entropy(
        logits.reshape(-1, logits.shape[-1]), windows["actions"].reshape(-1), reduction="none"
    ).reshape(steps, batch)
    mask = windows["mask"].float()
    return (ce * mask).sum() / mask.sum().clamp(min=1.0)
