"""PPO's settings: its own optimisation part (:class:`PPOOptimizationSettings`) and :class:`PPOConfig`,
which composes it with the network and schedule parts every on-policy learner shares
(:mod:`bimgame.learn.learner_settings`). Defaults follow the recurrent PPO of CleanRL's
``ppo_atari_lstm.py`` (clip 0.2, GAE λ 0.95, 4 epochs of 4 minibatches, Adam 2.5e-4), with A3C's
entropy and value weights."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar

from bimgame.envs.puzzles import puzzle
from bimgame.learn.common import LearnerSettings, NetworkSettings
from bimgame.learn.devices import DEVICES, Device
from bimgame.learn.learner_settings import (
    CurriculumSettings,
    ScheduleSettings,
    check_at_most,
    check_choice,
    check_number,
    check_start_curriculum,
)
from bimgame.util.settings import require_int

__all__ = ["POLICY_LAGS", "PPOOptimizationSettings", "PPOFinetuneSettings", "PPOConfig"]


#: The policy lags PPO takes: 0 (synchronous) or 1 (rollout and update overlap).
POLICY_LAGS = (0, 1)


@dataclasses.dataclass(frozen=True)
class PPOOptimizationSettings:
    """PPO's rollouts, clipped objective and optimiser (Schulman et al. 2017)."""

    n_steps: int = 128
    """Steps each environment acts per rollout."""
    epochs: int = 4
    """Passes over each rollout."""
    minibatches: int = 4
    """Minibatches per epoch, each a random set of whole sequences (at most the number of sequences:
    environments × ``n_steps`` / ``sequence_length``)."""
    sequence_length: int | None = 16
    """Steps of the sequences a minibatch unrolls the LSTM over, each from the LSTM state the acting
    network had at its first step (a divisor of ``n_steps``); None: each environment's whole rollout
    (CleanRL's recurrent PPO). Shorter sequences backpropagate through fewer steps one after the
    other: the update is faster, the gradient of memory truncated. The default, 16, ran at 1.6–2.2×
    the steps/s of whole 128-step rollouts and reached 80% on STG1 in 105k, 67.5k and 135k steps
    against their 67.5k, 270k and 135k (three seeds; ``benchmarks/results/learners.json``)."""
    clip: float = 0.2
    """The ratio clip ε of the surrogate objective."""
    value_clip: float | None = None
    """Clip the value function's change per rollout to this (PPO2's value clipping); None: no clipping."""
    gamma: float = 0.99
    """Discount."""
    gae_lambda: float = 0.95
    """λ of generalised advantage estimation."""
    lr: float = 2.5e-4
    """Adam's learning rate."""
    lr_anneal: bool = False
    """Decay the learning rate linearly from ``lr`` to zero over the run's steps (CleanRL's
    ``anneal_lr``): each update takes ``lr`` × (1 − step / steps) at the step of its rollout, so a
    resumed run continues the same schedule."""
    optimizer_eps: float = 1e-5
    """Adam's epsilon."""
    entropy_coef: float = 0.01
    """Weight of the entropy bonus."""
    value_coef: float = 0.5
    """Weight of the value loss."""
    max_grad_norm: float = 0.5
    """Clip each minibatch's gradient to this global norm."""
    advantage_norm: bool = True
    """Normalise the advantages of each minibatch to zero mean and unit variance."""
    aux_coef: float = 1.0
    """Weight of the auxiliary heads' loss when the network has them (``aux_heads``)."""
    sample_temperature: float = 1.0
    """The temperature of the policy that acts during training and that the clipped objective and the
    entropy bonus are of: the logits divided by it (a Gaussian's standard deviation times it). Below 1
    training episodes act closer to the greedy policy, so that a state where the greedy action
    repeats itself while the marble stays still shows up, and is paid for, in training rather than
    only in greedy evaluations; the greedy action is the same at every temperature. Evaluations
    and scoring sample at 1."""
    final_max_std: float | None = None
    """A ceiling on a Gaussian policy's standard deviation (each action dimension, in units of the
    action range) that falls geometrically from 1 at step 0 to this at the run's last step: after each
    update the learned log σ is clipped to (s / steps)·log(final_max_std), s the step at the end of
    the update's rollout. σ is free early (exploration) and ends at most this (precision):
    on the labyrinth the greedy policies of PPO from DAgger steered through the turns in 53-90% of the
    episodes while sampling at their own σ (≈ 0.45) lost the marble in half, and the same weights
    sampled at half their σ succeeded in 61-82%. None: σ is learned freely. Continuous actions only."""
    policy_lag: int = 0
    """0: collect a rollout, then update on it (PPO as published). 1: collect the next rollout while
    updating on the last one, in a second thread, so that stepping the environments and the update
    overlap on two cores: each rollout is then acted by the weights of one update before those it is
    trained from, and the clipped ratio is taken against the policy that acted (APPO's one-update lag,
    as in Sample Factory). One process only (``workers`` 1)."""

    def __post_init__(self) -> None:
        owner = type(self).__name__
        for name in ("n_steps", "epochs", "minibatches"):
            require_int(owner, name, getattr(self, name), 1)
        if type(self.policy_lag) is not int or self.policy_lag not in POLICY_LAGS:
            raise ValueError(f"{owner}.policy_lag must be one of {POLICY_LAGS}, got {self.policy_lag!r}")
        check_at_most(owner, "n_steps", self.n_steps, 10_000, "steps kept in memory per rollout")
        if self.sequence_length is not None:
            require_int(owner, "sequence_length", self.sequence_length, 1)
            if self.n_steps % self.sequence_length:
                raise ValueError(
                    f"{owner}.sequence_length must divide n_steps ({self.n_steps}) or be None, "
                    f"got {self.sequence_length!r}"
                )
        for name in ("gamma", "gae_lambda"):
            check_number(owner, name, getattr(self, name), 0.0, 1.0)
        for name in ("clip", "lr", "optimizer_eps", "max_grad_norm", "sample_temperature"):
            check_number(owner, name, getattr(self, name), 0.0, math.inf, low_open=True)
        if self.value_clip is not None:
            check_number(owner, "value_clip", self.value_clip, 0.0, math.inf, low_open=True)
        if self.final_max_std is not None:
            check_number(owner, "final_max_std", self.final_max_std, 0.0, 1.0, low_open=True)
        for name in ("entropy_coef", "value_coef", "aux_coef"):
            check_number(owner, name, getattr(self, name), 0.0, math.inf)
        for name in ("advantage_norm", "lr_anneal"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{owner}.{name} must be True or False, got {getattr(self, name)!r}")

    def lr_at(self, step: int, steps: int) -> float:
        """Adam's learning rate for the update of the rollout at ``step`` of a run of ``steps``."""
        if not self.lr_anneal:
            return self.lr
        return self.lr * max(0.0, 1.0 - step / steps)

    def max_log_std_at(self, step: int, steps: int) -> float | None:
        """The ceiling on log σ after the update of the rollout ending at ``step`` of a run of
        ``steps`` (:attr:`final_max_std`); None without one."""
        if self.final_max_std is None:
            return None
        return min(1.0, step / steps) * math.log(self.final_max_std)


@dataclasses.dataclass(frozen=True)
class PPOFinetuneSettings:
    """Keeping a pre-trained π^s while PPO fine-tunes it: kickstarting's KL(π^s ‖ π) on the learner's
    own rollouts (Schmitt et al. 2018) and a critic warm-up, the two parts of A3C's ``keep`` preset
    that PPO takes. The same flat names as A3C's fine-tuning settings; PPO has its own part because
    A3C's also holds ``advantage_norm`` (a running RMS), a name PPO's optimisation already uses for its
    per-minibatch normalisation. The teacher and the KL are A3C's (:class:`~bimgame.learn.loss_terms.TeacherKL`)."""

    kl_coef: float = 0.0
    """Initial weight of KL(π^s ‖ π); π^s is the network the run started from (``--init``)."""
    kl_decay_steps: int = 0
    """Steps over which the KL weight decays linearly to zero (0: it stays constant)."""
    kl_temperature: float = 1.0
    """Temperature of the teacher's distribution: 1 is π^s itself, below 1 a sharper π^s."""
    kl_means_only: bool = False
    """Continuous actions: keep only π^s's means, not its spread. The KL compares the learner's mean
    with the teacher's at the teacher's standard deviation, KL(N(μ_t, σ_t) ‖ N(μ, σ_t)) =
    Σ (μ − μ_t)² / 2σ_t², so the learner's σ is free and a narrower σ does not weight the mean's
    difference by 1/σ² (the full KL's term (μ − μ_t)² / 2σ², which pins a narrow learner to π^s)."""
    kl_teacher: str | None = None
    """A policy trained on the labyrinth's state (its run directory or a checkpoint in one) that the
    KL pulls towards instead of π^s: kickstarting from a privileged teacher, which reads the state the
    envs record (:class:`~bimgame.learn.teachers.StateTeacher`) while the learner observes pixels or
    CyberRunner's observation. None: π^s, the network the run started from."""
    kl_teacher_refresh_steps: int = 0
    """Every this many steps the KL's teacher becomes the policy as it is then (its weights copied, its
    LSTM state the acting network's at the rollout's start): kickstarting towards the policy's own
    recent past instead of π^s, a trust region this many steps wide. 0: π^s stays the teacher. Why: on
    the hard labyrinth a KL to the policy's start stops forgetting but holds the policy near π^s's
    level; a teacher moved to the policy itself every 1M or 250k steps carried it farther (measured in
    ``docs/guide/labyrinth-experiments.md``). The teacher is saved with each checkpoint, so a resumed
    run continues with the same teacher."""
    critic_warmup_steps: int = 0
    """Steps at the run's start in which only the critic learns (the value head, and an asymmetric
    critic's state reader): the policy acts as it was loaded while the value fits its returns, so
    that its first advantages are not a fresh critic's noise (0: none). A network from ``--init``
    cloned for its policy (a DAgger iterate) brings a critic that does not know the learner's returns."""

    def __post_init__(self) -> None:
        owner = type(self).__name__
        check_number(owner, "kl_coef", self.kl_coef, 0.0, math.inf)
        if not isinstance(self.kl_means_only, bool):
            raise ValueError(f"{owner}.kl_means_only must be True or False, got {self.kl_means_only!r}")
        if self.kl_means_only and self.kl_coef == 0:
            raise ValueError(
                f"{owner}.kl_means_only shapes the KL term to π^s: give kl_coef > 0 with it, got kl_coef 0"
            )
        if self.kl_teacher is not None and not (isinstance(self.kl_teacher, str) and self.kl_teacher):
            raise ValueError(f"{owner}.kl_teacher must be a run directory or checkpoint path, got {self.kl_teacher!r}")
        if self.kl_teacher is not None and self.kl_coef == 0:
            raise ValueError(f"{owner}.kl_teacher is the KL term's teacher: give kl_coef > 0 with it, got kl_coef 0")
        require_int(owner, "kl_decay_steps", self.kl_decay_steps, 0)
        require_int(owner, "kl_teacher_refresh_steps", self.kl_teacher_refresh_steps, 0)
        if self.kl_teacher_refresh_steps and (self.kl_coef == 0 or self.kl_teacher is not None):
            raise ValueError(
                f"{owner}.kl_teacher_refresh_steps moves the KL's teacher π^s to the policy itself: give "
                f"kl_coef > 0 and no kl_teacher (a state teacher observes otherwise), got kl_coef "
                f"{self.kl_coef!r}, kl_teacher {self.kl_teacher!r}"
            )
        require_int(owner, "critic_warmup_steps", self.critic_warmup_steps, 0)
        check_number(owner, "kl_temperature", self.kl_temperature, 0.0, math.inf, low_open=True)

    def kl_weight(self, step: int) -> float:
        """The KL weight at the run's ``step``: ``kl_coef``, decayed linearly to zero over
        ``kl_decay_steps`` when that is positive."""
        if self.kl_decay_steps <= 0:
            return self.kl_coef
        return self.kl_coef * max(0.0, 1.0 - step / self.kl_decay_steps)

    def refreshes_teacher(self, taught_since: int, step: int) -> bool:
        """Whether the update of the rollout at the run's ``step`` first moves the teacher (to the policy
        as it is then), the teacher having been set at step ``taught_since``: a multiple of
        ``kl_teacher_refresh_steps`` lies in (taught_since, step]."""
        every = self.kl_teacher_refresh_steps
        return every > 0 and step // every > taught_since // every

    def critic_only(self, step: int) -> bool:
        """Whether the update of the rollout at the run's ``step`` trains the critic alone."""
        return step < self.critic_warmup_steps


def _single_process_schedule() -> ScheduleSettings:
    """PPO's schedule unless told otherwise: one process (``workers`` > 1 averages the gradients of
    several; on a 2-core machine that measured slower, see :mod:`bimgame.learn.ppo.parallel`)."""
    return ScheduleSettings(workers=1)


@dataclasses.dataclass(frozen=True)
class PPOConfig(LearnerSettings):
    """Settings of a PPO run: the task and its episodes, the network, PPO's optimisation and the
    schedule. Every setting also has a flat name (:meth:`from_flat`, :meth:`to_dict`), its flag and
    its key in ``config.json``."""

    device: Device = "cpu"
    """Where the update runs: ``cpu``, ``cuda`` or ``auto`` (CUDA when there is one). The
    environments and the acting network stay on the CPU (:mod:`bimgame.learn.devices`)."""
    collectors: int = 0
    """Processes that step the environments and act (:mod:`bimgame.learn.ppo.collectors`): 0, this
    process; N, N child processes of ``envs_per_worker`` / N environments each, acting with a copy of
    the weights sent before every rollout. With ``policy_lag`` 1 and one collector, collecting and
    updating run on two cores."""
    network: NetworkSettings = dataclasses.field(default_factory=NetworkSettings)
    """The actor-critic's observations, sizes and inputs (the same networks as A3C's)."""
    optimization: PPOOptimizationSettings = dataclasses.field(default_factory=PPOOptimizationSettings)
    """Rollouts, the clipped objective and Adam."""
    schedule: ScheduleSettings = dataclasses.field(default_factory=_single_process_schedule)
    """Steps and environments; checkpoints, evaluations and logs. ``workers`` processes (ranks), each
    stepping ``envs_per_worker`` environments, their gradients averaged (:mod:`bimgame.learn.ppo.parallel`)."""
    finetuning: PPOFinetuneSettings | None = None
    """The KL to π^s while fine-tuning from ``--init``; None: no term (also with ``--init``)."""
    expert_data: str | None = None
    """Expert dataset directory (``bimgame generate``) for demonstration starts (``start_curriculum='demo'``)."""
    curriculum: CurriculumSettings | None = None
    """Start curriculum of the training episodes (:mod:`bimgame.learn.curricula`; on the labyrinth
    ``reverse``, along its printed path); None: the task's own starts."""

    PARTS: ClassVar[dict[str, type]] = {
        "network": NetworkSettings,
        "optimization": PPOOptimizationSettings,
        "schedule": ScheduleSettings,
        "finetuning": PPOFinetuneSettings,
        "curriculum": CurriculumSettings,
    }
    OPTIONAL_PARTS: ClassVar[frozenset[str]] = frozenset({"finetuning", "curriculum"})
    NONE_VALUES: ClassVar[dict[str, Any]] = {"start_curriculum": "none"}
    SETTINGS_NAME: ClassVar[str] = "PPO settings"
    # What a resumed run may change without changing what is being learned.
    RESUMABLE_CHANGES: ClassVar[tuple[str, ...]] = (
        "device",
        "collectors",
        "steps",
        "checkpoint_every",
        "eval_every",
        "eval_episodes",
        "log_every",
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        owner = type(self).__name__
        check_choice(owner, "device", self.device, DEVICES)
        check_start_curriculum(owner, self.task, self.curriculum, self.expert_data)
        if self.device == "cuda" and self.schedule.workers > 1:
            raise ValueError(
                f"{owner}: device 'cuda' takes one process (workers 1; a GPU learner is fed by its own "
                f"environments), got workers {self.schedule.workers!r}"
            )
        if self.optimization.policy_lag and self.schedule.workers > 1:
            raise ValueError(
                f"{owner}: policy_lag {self.optimization.policy_lag} overlaps one process's rollout and update "
                f"(workers 1); with workers > 1 use policy_lag 0, got workers {self.schedule.workers!r}"
            )
        self._check_collectors(owner)
        if self.optimization.final_max_std is not None and self.network.action_type != "continuous":
            raise ValueError(
                f"{owner}: final_max_std caps a Gaussian policy's standard deviation (action_type 'continuous'), "
                f"got action_type {self.network.action_type!r}; leave final_max_std None"
            )
        if self.state_teacher is not None and puzzle(self.task).is_maze:
            raise ValueError(
                f"{owner}: kl_teacher is a policy trained on the labyrinth's state; task {self.task} is the "
                f"circular maze (its kickstarting teacher is π^s: leave kl_teacher unset)"
            )
        if self.finetuning is not None and self.finetuning.kl_means_only and self.network.action_type != "continuous":
            raise ValueError(
                f"{owner}: kl_means_only compares a Gaussian policy's means (action_type 'continuous'), "
                f"got action_type {self.network.action_type!r}; leave kl_means_only False"
            )
        if self.optimization.minibatches > self.sequences_per_rollout:
            raise ValueError(
                f"{owner}.minibatches must be at most the sequences of a rollout ({self.sequences_per_rollout}: "
                f"envs_per_worker {self.schedule.envs_per_worker} × n_steps / sequence_length): minibatches "
                f"split the sequences, got {self.optimization.minibatches!r}"
            )

    def _check_collectors(self, owner: str) -> None:
        """Collector processes split one process's environments evenly (workers 1)."""
        require_int(owner, "collectors", self.collectors, 0)
        collectors, envs = self.collectors, self.schedule.envs_per_worker
        if collectors and envs % collectors:
            raise ValueError(
                f"{owner}.collectors must be 0 (this process steps the environments) or a divisor of "
                f"envs_per_worker ({envs}): each collector process steps an equal share, got {collectors!r}"
            )
        if collectors and self.schedule.workers > 1:
            raise ValueError(
                f"{owner}: collectors {collectors} feed one learning process (workers 1); with workers > 1 "
                f"use collectors 0, got workers {self.schedule.workers!r}"
            )

    @property
    def has_teacher(self) -> bool:
        """Whether the run has a KL term, to π^s or to a state teacher (``kl_teacher``)."""
        return self.finetuning is not None and self.finetuning.kl_coef > 0

    @property
    def state_teacher(self) -> str | None:
        """The state teacher the KL pulls towards (``kl_teacher``), None when the KL's teacher is π^s."""
        return None if self.finetuning is None else self.finetuning.kl_teacher

    @property
    def keeps_pi_s(self) -> bool:
        """Whether the run keeps π^s (the weights it started from, ``teacher.pt``) for its KL term."""
        return self.has_teacher and self.state_teacher is None

    @property
    def records_state(self) -> bool:
        """Whether the envs record the simulator's state (``Segment.privileged``): for the network's
        auxiliary heads or asymmetric critic, or for a state teacher to read."""
        return self.network.privileged or self.state_teacher is not None

    @property
    def steps_per_rollout(self) -> int:
        """Environment steps of one rollout, every rank's together."""
        return self.optimization.n_steps * self.schedule.envs_per_worker * self.schedule.workers

    @property
    def sequences_per_rollout(self) -> int:
        """The sequences minibatches are drawn from: every environment's rollout, cut to ``sequence_length``."""
        length = self.optimization.sequence_length or self.optimization.n_steps
        return self.schedule.envs_per_worker * (self.optimization.n_steps // length)
