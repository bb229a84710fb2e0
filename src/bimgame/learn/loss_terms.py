"""The optional terms of an on-policy update's loss, chosen once when a run starts.

A run from scratch has none; fine-tuning from π^s may add kickstarting's KL(π^s ‖ π) on the
learner's own rollouts (:class:`TeacherKL`) and DAPG's behaviour cloning on windows of the expert's
episodes (:class:`BehaviourCloning`); see :mod:`bimgame.learn.finetune`. Each term is a small object
with two steps, so that the update itself never asks which terms a run has:

1. :meth:`LossTerm.prepare` sees every collected segment as the learner acted on it (before any
   augmentation): the teacher follows it to keep its own LSTM state in step with the learner's
   episodes, the expert windows are drawn;
2. :meth:`LossTerm.loss` gives the term's weighted contribution to the loss of the network's unroll
   (or None when it contributes nothing this update) and the values it logs.

A term that has served its time (a KL weight decayed to zero) says so with :attr:`LossTerm.finished`,
and the learner drops it: from then on it costs nothing.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import torch

from bimgame.learn.finetune import DemoWindows, LossWeights, Teacher, bc_loss, kl_to_teacher
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.rollout import Segment

__all__ = ["LossTerm", "TeacherKL", "BehaviourCloning"]


class LossTerm(Protocol):
    """One optional term of the loss (see the module's description)."""

    finished: bool

    def prepare(self, segment: Segment, weights: LossWeights) -> None:
        """Take in a collected segment (before augmentation) with the update's loss weights."""

    def loss(
        self,
        net: RecurrentActorCritic,
        log_probs: torch.Tensor,
        weights: LossWeights,
    ) -> tuple[torch.Tensor | None, dict[str, float]]:
        """The weighted contribution to the loss (None: none this update) and the values to log;
        ``log_probs`` (T, B, A) are the learner's log-probabilities over the prepared segment."""


class TeacherKL:
    """Kickstarting (Schmitt et al. 2018): KL(π^s ‖ π) on the learner's own rollouts, π^s following
    the same episodes with its own LSTM state. Logged as ``kl`` for as long as the teacher follows;
    weighted by ``weights.kl``. With ``decay_steps`` > 0 the term finishes once its weight has decayed
    to zero."""

    def __init__(self, teacher: Teacher, decay_steps: int = 0):
        self.teacher = teacher
        self.decay_steps = decay_steps
        self.finished = False
        self.teacher_log_probs: torch.Tensor | None = None

    def prepare(self, segment: Segment, weights: LossWeights) -> None:
        # It follows every segment, so that its LSTM state stays the learner's.
        self.teacher_log_probs = self.teacher.follow(segment)
        if weights.kl == 0 and self.decay_steps > 0 and segment.step_at_start >= self.decay_steps:
            self.finished, self.teacher_log_probs = True, None  # annealed away: stop paying for it

    def loss(
        self,
        net: RecurrentActorCritic,
        log_probs: torch.Tensor,
        weights: LossWeights,
    ) -> tuple[torch.Tensor | None, dict[str, float]]:
        if self.teacher_log_probs is None:
            return None, {}
        kl = kl_to_teacher(self.teacher_log_probs, log_probs)
        return (weights.kl * kl if weights.kl > 0 else None), {"kl": kl.item()}


class BehaviourCloning:
    """DAPG's behaviour cloning (Rajeswaran et al. 2018): the cross-entropy to the expert's actions
    on ``batch`` random windows of its episodes, drawn from ``rng`` for every update whose weight
    ``weights.bc`` is positive (also during a critic warm-up, which does not use them, so that the
    draws do not depend on the schedule); logged as ``bc`` when it is part of the loss."""

    def __init__(self, demos: DemoWindows, batch: int, rng: np.random.Generator):
        self.demos, self.batch, self.rng = demos, batch, rng
        self.finished = False
        self.windows: dict[str, torch.Tensor] | None = None

    def prepare(self, segment: Segment, weights: LossWeights) -> None:
        self.windows = self.demos.sample(self.batch, self.rng) if weights.bc > 0 else None

    def loss(
        self,
        net: RecurrentActorCritic,
        log_probs: torch.Tensor,
        weights: LossWeights,
    ) -> tuple[torch.Tensor | None, dict[str, float]]:
        if self.windows is None or weights.bc <= 0 or weights.critic_only:
            return None, {}
        bc = bc_loss(net, self.windows)
        return weights.bc * bc, {"bc": bc.item()}
