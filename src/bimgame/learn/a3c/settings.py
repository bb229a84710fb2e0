"""A3C's settings: its own optimisation part (:class:`OptimizationSettings`) and :class:`A3CConfig`,
which composes it with the parts every on-policy learner shares (the network, the schedule, and the
optional fine-tuning and start-curriculum parts of :mod:`bimgame.learn.learner_settings`)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar, Literal, get_args

from bimgame.envs.randomization import OBSERVATION_FIELDS, RANDOMIZATION_PRESETS
from bimgame.learn.augment import MAX_SHIFT
from bimgame.learn.common import LearnerSettings, NetworkSettings
from bimgame.learn.learner_settings import (
    CurriculumSettings,
    FinetuneSettings,
    ScheduleSettings,
    check_at_most,
    check_choice,
    check_expert_data,
    check_number,
    check_start_curriculum,
    refuse_maze_only,
)
from bimgame.learn.policy_heads import require_discrete
from bimgame.util.settings import require_int

__all__ = ["Optimizer", "OPTIMIZERS", "OptimizationSettings", "A3CConfig"]

Optimizer = Literal["rmsprop", "adam"]
OPTIMIZERS: tuple[str, ...] = get_args(Optimizer)


@dataclasses.dataclass(frozen=True)
class OptimizationSettings:
    """A3C's segments, loss and optimiser. Defaults follow the A3C paper and its widely used reference
    implementations (OpenAI Baselines' A2C settings for the loss, RMSProp with shared statistics)."""

    n_steps: int = 20
    """t_max: steps per update (n-step returns)."""
    gamma: float = 0.99
    """Discount."""
    gae_lambda: float = 1.0
    """1.0 gives A3C's n-step returns; below 1, generalised advantage estimation."""
    lr: float = 7e-4
    """Learning rate of the shared optimiser."""
    optimizer: Optimizer = "rmsprop"
    """``rmsprop`` (A3C's, statistics shared by all workers) or ``adam`` (also shared)."""
    rmsprop_alpha: float = 0.99
    """RMSProp's smoothing constant."""
    optimizer_eps: float = 1e-5
    """The optimiser's epsilon (numerical stability)."""
    entropy_coef: float = 0.01
    """Weight of the entropy bonus in the loss."""
    value_coef: float = 0.5
    """Weight of the value loss against the policy loss."""
    max_grad_norm: float = 0.5
    """Clip each update's gradient to this global norm (losses are means over the segment)."""
    entropy_target: float | None = None
    """Final target entropy of the policy in nats (at most ln 5 ≈ 1.61); the entropy coefficient then
    adapts (starting from ``entropy_coef``) so that the entropy follows a target falling linearly from
    the policy's initial entropy to this over ``entropy_target_steps``. None: a fixed ``entropy_coef``."""
    entropy_target_steps: int = 0
    """Steps over which the entropy target falls to ``entropy_target`` (0: at once)."""
    aux_coef: float = 1.0
    """Weight of the auxiliary heads' loss (predicting the simulator's state) when the network has
    them (``aux_heads``)."""
    augment_shift: int = 0
    """Pixels: shift each environment's frames in an update by up to this many pixels (DrQ random
    shifts, replicate padding; 0: none). Acting always sees the frames as rendered."""

    def __post_init__(self) -> None:
        owner = type(self).__name__
        check_choice(owner, "optimizer", self.optimizer, OPTIMIZERS)
        require_int(owner, "n_steps", self.n_steps, 1)
        check_at_most(owner, "n_steps", self.n_steps, 10_000, "steps kept in memory per update")
        for name in ("gamma", "gae_lambda", "rmsprop_alpha"):
            check_number(owner, name, getattr(self, name), 0.0, 1.0)
        for name in ("lr", "optimizer_eps", "max_grad_norm"):
            check_number(owner, name, getattr(self, name), 0.0, math.inf, low_open=True)
        if self.entropy_target is not None and not (
            isinstance(self.entropy_target, (int, float)) and 0 < self.entropy_target <= math.log(5)
        ):
            raise ValueError(
                f"{owner}.entropy_target must be None or in (0, ln 5 = {math.log(5):.4f}] nats, "
                f"got {self.entropy_target!r}"
            )
        require_int(owner, "entropy_target_steps", self.entropy_target_steps, 0)
        require_int(owner, "augment_shift", self.augment_shift, 0)
        if self.augment_shift > MAX_SHIFT:
            raise ValueError(f"{owner}.augment_shift must be 0..{MAX_SHIFT} pixels, got {self.augment_shift!r}")
        for name in ("entropy_coef", "value_coef", "aux_coef"):
            check_number(owner, name, getattr(self, name), 0.0, math.inf)


@dataclasses.dataclass(frozen=True)
class A3CConfig(LearnerSettings):
    """Settings of an A3C run: the task and its episodes, and the run's parts — the network, the
    optimisation, the schedule, and optionally fine-tuning and a start curriculum. Every setting also
    has a flat name (``lr``, ``hidden``, ``kl_coef``: :meth:`from_flat`, :meth:`to_dict`), its flag
    and its key in ``config.json``."""

    randomize: str | None = None
    """Domain randomisation of the training episodes: a preset of
    :data:`~bimgame.envs.randomization.RANDOMIZATION_PRESETS` (``physics``, ``camera``, ``all``; the
    camera needs pixels); None: the nominal board. Evaluations use the nominal board."""
    expert_data: str | None = None
    """Expert dataset directory (``bimgame generate``) for the behaviour-cloning term and
    demonstration starts."""
    network: NetworkSettings = dataclasses.field(default_factory=NetworkSettings)
    """The actor-critic's observations, sizes and inputs."""
    optimization: OptimizationSettings = dataclasses.field(default_factory=OptimizationSettings)
    """Segments, loss and optimiser."""
    schedule: ScheduleSettings = dataclasses.field(default_factory=ScheduleSettings)
    """Steps, processes and environments; checkpoints, evaluations and logs."""
    finetuning: FinetuneSettings | None = None
    """Fine-tuning π^s without forgetting it; None: a run from scratch."""
    curriculum: CurriculumSettings | None = None
    """Start curriculum; None: the task's own starts."""

    PARTS: ClassVar[dict[str, type]] = {
        "network": NetworkSettings,
        "optimization": OptimizationSettings,
        "schedule": ScheduleSettings,
        "finetuning": FinetuneSettings,
        "curriculum": CurriculumSettings,
    }
    OPTIONAL_PARTS: ClassVar[frozenset[str]] = frozenset({"finetuning", "curriculum"})
    NONE_VALUES: ClassVar[dict[str, Any]] = {"start_curriculum": "none"}
    SETTINGS_NAME: ClassVar[str] = "A3C settings"
    # What a resumed run may change without changing what is being learned.
    RESUMABLE_CHANGES: ClassVar[tuple[str, ...]] = (
        "steps",
        "workers",
        "checkpoint_every",
        "eval_every",
        "eval_episodes",
        "log_every",
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.finetuning is not None and self.finetuning.changes_nothing:
            object.__setattr__(self, "finetuning", None)
        # A3C's loss, fine-tuning terms and teacher are those of a categorical policy.
        require_discrete("A3C", self.network.action_type, "use --algo ppo")
        refuse_maze_only("A3CConfig", self.task, {"randomize": self.randomize is not None})
        bc = self.finetuning is not None and self.finetuning.bc_coef > 0
        refuse_maze_only("A3CConfig", self.task, {"bc_coef": bc})
        check_start_curriculum("A3CConfig", self.task, self.curriculum, self.expert_data)
        check_expert_data("A3CConfig", self.expert_data, {"bc_coef": bc})  # behaviour cloning reads it too
        self._check_pixel_settings()

    def _check_pixel_settings(self) -> None:
        """Settings that only mean something for pixels: randomising the camera, shifting frames."""
        obs = self.network.obs
        if self.randomize is not None:
            check_choice("A3CConfig", "randomize", self.randomize, tuple(RANDOMIZATION_PRESETS), optional=True)
            if obs != "pixels" and RANDOMIZATION_PRESETS[self.randomize].active(OBSERVATION_FIELDS):
                raise ValueError(
                    f"A3CConfig.randomize={self.randomize!r} randomises the camera, which needs "
                    f"obs='pixels'; with state observations use 'physics'"
                )
        if self.optimization.augment_shift and obs != "pixels":
            raise ValueError(
                f"A3CConfig.augment_shift must be 0..{MAX_SHIFT} pixels, and 0 for state observations, "
                f"got {self.optimization.augment_shift!r} with obs={obs!r}"
            )

    @property
    def steps_per_update(self) -> int:
        return self.optimization.n_steps * self.schedule.envs_per_worker

    @property
    def has_teacher(self) -> bool:
        """Whether the run keeps π^s (the weights it started from) for a KL term."""
        return self.finetuning is not None and self.finetuning.kl_coef > 0

    @property
    def schedules_actor(self) -> bool:
        """Whether the actor's learning rate follows a schedule (critic warm-up or actor ramp): the
        policy head then has its own optimiser parameter group."""
        return self.finetuning is not None and self.finetuning.schedules_actor
