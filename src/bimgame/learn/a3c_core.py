"""A3C's settings and the pieces both the parent and the worker processes use: :class:`A3CConfig`,
the network and shared optimiser a run starts from, the loss of one segment and the Hogwild update,
and the run's periodic evaluation. :mod:`bimgame.learn.a3c` describes the algorithm and re-exports
all of these."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any, ClassVar, Literal, get_args

import torch

from bimgame.envs.randomization import OBSERVATION_FIELDS, RANDOMIZATION_PRESETS
from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.learn.augment import MAX_SHIFT
from bimgame.learn.common import NetworkSettings, check_seed, evaluate_greedy_and_sampled, evaluation_seed
from bimgame.learn.finetune import LossWeights, RunningScale
from bimgame.learn.learner_settings import (
    MAX_STEPS,
    START_CURRICULA,
    CurriculumSettings,
    FinetuneSettings,
    FlatSettings,
    ScheduleSettings,
    check_at_most,
    check_choice,
    check_number,
)
from bimgame.learn.loss_terms import LossTerm
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.rollout import Segment, advantages_and_targets
from bimgame.sim.maze import MazeSpec
from bimgame.sim.tasks import Task, task_setting
from bimgame.util.settings import require_int

__all__ = [
    "A3CConfig",
    "OptimizationSettings",
    "OPTIMIZERS",
    "START_CURRICULA",
    "MAX_STEPS",
    "EnvWrapper",
    "network_for",
    "make_optimizer",
    "shared_optimizer_state",
    "a3c_segment_loss",
    "apply_update",
    "evaluate",
]

Optimizer = Literal["rmsprop", "adam"]
OPTIMIZERS: tuple[str, ...] = get_args(Optimizer)
#: A callable that wraps a worker's vector env (e.g. reward shaping). It is sent to spawned worker
#: processes, so it must be picklable (a module-level function or an instance of a module-level class).
EnvWrapper = Callable[[BallInMazeVectorEnv], Any]


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
class A3CConfig(FlatSettings):
    """Settings of an A3C run: the task and its episodes, and the run's parts — the network, the
    optimisation, the schedule, and optionally fine-tuning and a start curriculum. Every setting also
    has a flat name (``lr``, ``hidden``, ``kl_coef``: :meth:`from_flat`, :meth:`to_dict`), its flag
    and its key in ``config.json``."""

    task: str = "STG1"
    """FULL, STG1 … STG4."""
    seed: int = 0
    """Seeds the network's initial weights, the workers' environments and sampling, and the evaluations."""
    max_episode_steps: int | None = None
    """Time limit; None uses the task's (STG1 300, STG2 500, STG3 750, STG4/FULL 1000)."""
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
    RESUMABLE_CHANGES = ("steps", "workers", "checkpoint_every", "eval_every", "eval_episodes", "log_every")

    def __post_init__(self) -> None:
        owner = type(self).__name__
        object.__setattr__(self, "task", task_setting(owner, self.task))
        check_seed(owner, self.seed)  # numpy's seed sequences take no negative seeds, torch none of 2**64
        require_int(owner, "max_episode_steps", self.max_episode_steps, 1, optional=True)
        check_at_most(owner, "max_episode_steps", self.max_episode_steps, MAX_STEPS, "1e12 environment steps")
        for name, part in self.PARTS.items():
            value = getattr(self, name)
            if not (isinstance(value, part) or (value is None and name in self.OPTIONAL_PARTS)):
                allowed = f"None or a {part.__name__}" if name in self.OPTIONAL_PARTS else f"a {part.__name__}"
                raise ValueError(f"{owner}.{name} must be {allowed}, got {value!r}")
        if self.finetuning is not None and self.finetuning.changes_nothing:
            object.__setattr__(self, "finetuning", None)
        self._check_expert_data()
        self._check_pixel_settings()

    def _check_expert_data(self) -> None:
        """Behaviour cloning and demonstration starts read the expert's dataset."""
        needs_data = [
            name
            for name, on in (
                ("bc_coef", self.finetuning is not None and self.finetuning.bc_coef > 0),
                ("start_curriculum='demo'", self.curriculum is not None and self.curriculum.start_curriculum == "demo"),
            )
            if on
        ]
        if needs_data and self.expert_data is None:
            raise ValueError(f"A3CConfig.{needs_data[0]} needs expert_data (an expert dataset directory)")

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
    def time_limit(self) -> int:
        return self.max_episode_steps or Task(self.task).time_limit

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


def network_for(config: A3CConfig, maze: MazeSpec | None = None) -> RecurrentActorCritic:
    """A fresh network for ``config``'s run, initialised from its seed."""
    return config.network.build_policy(config.seed, maze)


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
    out = net.unroll_features(
        segment.obs,
        segment.prev_action,
        segment.prev_reward,
        segment.tilt,
        segment.initial_state,
        segment.starts,
        privileged=privileged,
    )
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
        value_head = {id(p) for p in local.critic_parameters()}
        for param in local.parameters():
            if id(param) not in value_head:
                param.grad = None  # the optimiser leaves parameters without a gradient untouched
    grad_norm = float(torch.nn.utils.clip_grad_norm_(local.parameters(), config.optimization.max_grad_norm))
    applied = math.isfinite(loss.item()) and math.isfinite(grad_norm)
    if applied:
        if config.schedules_actor:
            optimizer.param_groups[0]["lr"] = config.optimization.lr * weights.actor
        for shared_param, param in zip(shared_params, local.parameters(), strict=True):
            shared_param.grad = param.grad
        optimizer.step()
    return {**parts, "loss": loss.item(), "grad_norm": grad_norm, "applied": applied}


def evaluate(net: RecurrentActorCritic, config: A3CConfig) -> dict[str, float]:
    """The run's periodic evaluation: greedy and sampled, on its evaluation episodes and seed."""
    return evaluate_greedy_and_sampled(
        net,
        task=config.task,
        obs=config.network.obs,
        episodes=config.schedule.eval_episodes,
        seed=evaluation_seed(config.seed),
        time_limit=config.time_limit,
    )
