"""A3C's settings and the pieces both the parent and the worker processes use: :class:`A3CConfig`,
the network and shared optimiser a run starts from, the loss of one segment and the Hogwild update,
and the run's periodic evaluation. :mod:`bimgame.learn.a3c` describes the algorithm and re-exports
all of these."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar

import torch

from bimgame.envs.randomization import OBSERVATION_FIELDS, RANDOMIZATION_PRESETS
from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.learn.augment import MAX_SHIFT
from bimgame.learn.common import NetworkSettings, check_seed, evaluate_greedy_and_sampled, evaluation_seed
from bimgame.learn.finetune import FINETUNE_PRESETS, LossWeights, RunningScale
from bimgame.learn.loss_terms import LossTerm
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.rollout import Segment, advantages_and_targets
from bimgame.sim.maze import MazeSpec
from bimgame.sim.tasks import Task, task_setting
from bimgame.util.settings import require_int

__all__ = [
    "A3CConfig",
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

OPTIMIZERS = ("rmsprop", "adam")
#: Where training episodes start: ``none`` (the task's own starts), ``demo`` (demonstration starts,
#: from ``expert_data``) or ``reverse`` (reverse curriculum, no expert); see :mod:`bimgame.learn.starts`.
START_CURRICULA = ("none", "demo", "reverse")
#: The most environment steps a run (or a checkpoint or evaluation interval) may count: 10¹², about
#: 30 years at this machine's 1,000 steps/s. More is a typo (``--steps 1e30``), found before any work.
MAX_STEPS = 10**12
#: The largest value of the settings that size what is allocated at once (processes, environments,
#: segment memory, evaluation episodes run side by side), far above any sensible value: larger is a
#: typo that would otherwise fail only when memory runs out.
_LARGEST = {
    **{
        name: (MAX_STEPS, "1e12 environment steps")
        for name in ("steps", "checkpoint_every", "eval_every", "log_every", "max_episode_steps")
    },
    "workers": (256, "processes"),
    "envs_per_worker": (4096, "environments in one process"),
    "n_steps": (10_000, "steps kept in memory per update"),
    "eval_episodes": (10_000, "episodes run side by side"),
}
#: A callable that wraps a worker's vector env (e.g. reward shaping). It is sent to spawned worker
#: processes, so it must be picklable (a module-level function or an instance of a module-level class).
EnvWrapper = Callable[[BallInMazeVectorEnv], Any]


#: Settings that are integers >= 1, >= 0, reals in [0, 1], finite reals > 0 and finite reals >= 0.
_POSITIVE_INTS = ("steps", "workers", "envs_per_worker", "n_steps", "checkpoint_every", "eval_episodes", "log_every")
_NON_NEGATIVE_INTS = (
    "critic_warmup_steps",
    "actor_ramp_steps",
    "kl_decay_steps",
    "bc_decay_steps",
    "entropy_target_steps",
)
_UNIT_INTERVAL = ("gamma", "gae_lambda", "rmsprop_alpha")
_POSITIVE_REALS = ("lr", "optimizer_eps", "max_grad_norm")
_NON_NEGATIVE_REALS = ("entropy_coef", "value_coef", "kl_coef", "bc_coef", "aux_coef")


def _check_choice(name: str, value: Any, allowed: tuple[str, ...], *, optional: bool = False) -> None:
    """Raise unless ``value`` is one of ``allowed`` (or, if ``optional``, None)."""
    if value not in allowed:
        prefix = "None or " if optional else ""
        raise ValueError(f"A3CConfig.{name} must be {prefix}one of {allowed}, got {value!r}")


def _check_number(config: Any, name: str, value: Any, low: float, high: float, *, low_open: bool = False) -> None:
    """Raise unless ``value`` is a real number in [low, high] (finite and above ``low`` if
    ``low_open``; finite if ``high`` is infinite)."""
    ok = isinstance(value, (int, float)) and (math.isfinite(value) or math.isfinite(high))
    ok = ok and (value > low if low_open else value >= low) and value <= high
    if ok:
        return
    if math.isfinite(high):
        raise ValueError(f"A3CConfig.{name} must be in [{low}, {high}], got {value!r}")
    relation = ">" if low_open else ">="
    raise ValueError(f"A3CConfig.{name} must be a finite number {relation} {low:g}, got {value!r}")


@dataclasses.dataclass(frozen=True)
class A3CConfig(NetworkSettings):
    """Settings of an A3C run. Learning defaults follow the A3C paper and its widely used reference
    implementations (OpenAI Baselines' A2C settings for the loss, RMSProp with shared statistics).
    The network settings (``obs``, ``hidden``, ``features``, …) are inherited from
    :class:`~bimgame.learn.common.NetworkSettings`."""

    task: str = "STG1"
    """FULL, STG1 … STG4."""
    steps: int = 5_000_000
    """Environment steps to train for (all workers together)."""
    workers: int = 2
    """Worker processes (one thread each)."""
    envs_per_worker: int = 16
    """Environments per worker, stepped as one batch (one forward pass acts for all); 1 is exactly
    the paper's A3C. Batching is what makes the network affordable on a CPU: one LSTM step costs
    about the same for 1 environment as for 16."""
    n_steps: int = 20
    """t_max: steps per update (n-step returns)."""
    gamma: float = 0.99
    """Discount."""
    gae_lambda: float = 1.0
    """1.0 gives A3C's n-step returns; below 1, generalised advantage estimation."""
    lr: float = 7e-4
    """Learning rate of the shared optimiser."""
    optimizer: str = "rmsprop"
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
    seed: int = 0
    """Seeds the network's initial weights, the workers' environments and sampling, and the evaluations."""
    max_episode_steps: int | None = None
    """Time limit; None uses the task's (STG1 300, STG2 500, STG3 750, STG4/FULL 1000)."""
    checkpoint_every: int = 100_000
    """Environment steps between checkpoints (``--resume`` loses at most this many)."""
    eval_every: int = 100_000
    """Environment steps between evaluations; 0 disables the evaluator process."""
    eval_episodes: int = 10
    """Episodes per evaluation, each greedy and sampled."""
    log_every: int = 2_000
    """Environment steps (per worker) between loss reports."""
    finetune: str | None = None
    """Fine-tuning preset the fine-tuning settings below started from (``paper``: plain fine-tuning,
    which forgets; ``keep``: the default with ``--init``); None: none (a run from scratch). See
    :mod:`bimgame.learn.finetune`."""
    critic_warmup_steps: int = 0
    """Fine-tuning: environment steps at the start during which only the value head learns."""
    actor_ramp_steps: int = 0
    """Fine-tuning: steps after the warm-up over which the actor's learning rate and loss terms ramp
    up linearly from zero."""
    kl_coef: float = 0.0
    """Fine-tuning (kickstarting): initial weight of KL(π^s ‖ π) on the learner's rollouts; π^s is
    the network the run started from (``--init``)."""
    kl_decay_steps: int = 0
    """Steps over which the KL weight decays linearly to zero (0: it stays constant)."""
    kl_temperature: float = 1.0
    """Temperature of the teacher's distribution in the KL term: 1 is π^s itself, below 1 a sharper
    π^s (towards its greedy action)."""
    advantage_norm: bool = False
    """Divide advantages by their running RMS, so the policy gradient (against the entropy and KL
    terms) has the same scale on every task."""
    expert_data: str | None = None
    """Expert dataset directory (``bimgame generate``) for the behaviour-cloning term and
    demonstration starts."""
    bc_coef: float = 0.0
    """Fine-tuning (DAPG): initial weight of the cross-entropy to the expert's actions on windows of
    ``expert_data``."""
    bc_decay_steps: int = 0
    """Steps over which the behaviour-cloning weight decays linearly to zero (0: constant)."""
    start_curriculum: str = "none"
    """Where training episodes start: ``none`` (the task's own starts), ``demo`` (states of the
    expert's episodes, moving back from the goal as success grows) or ``reverse`` (grown backwards
    from the goal by random exploration, no expert). Evaluations always use the task's own starts."""
    entropy_target: float | None = None
    """Final target entropy of the policy in nats (at most ln 5 ≈ 1.61); the entropy coefficient then
    adapts (starting from ``entropy_coef``) so that the entropy follows a target falling linearly from
    the policy's initial entropy to this over ``entropy_target_steps``. None: a fixed ``entropy_coef``."""
    entropy_target_steps: int = 0
    """Steps over which the entropy target falls to ``entropy_target`` (0: at once)."""
    curriculum_threshold: float = 0.8
    """Start curricula: success on the current starts that moves them further from the goal."""
    aux_coef: float = 1.0
    """Weight of the auxiliary heads' loss (predicting the simulator's state) when the network has
    them (``aux_heads``)."""
    augment_shift: int = 0
    """Pixels: shift each environment's frames in an update by up to this many pixels (DrQ random
    shifts, replicate padding; 0: none). Acting always sees the frames as rendered."""
    randomize: str | None = None
    """Domain randomisation of the training episodes: a preset of
    :data:`~bimgame.envs.randomization.RANDOMIZATION_PRESETS` (``physics``, ``camera``, ``all``; the
    camera needs pixels); None: the nominal board. Evaluations use the nominal board."""

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "task", task_setting("A3CConfig", self.task))
        _check_choice("optimizer", self.optimizer, OPTIMIZERS)
        for name in _POSITIVE_INTS:
            require_int("A3CConfig", name, getattr(self, name), 1)
        check_seed("A3CConfig", self.seed)  # numpy's seed sequences take no negative seeds, torch none of 2**64
        if not (isinstance(self.eval_every, int) and self.eval_every >= 0):
            raise ValueError(f"A3CConfig.eval_every must be an integer >= 0 (0: no evaluator), got {self.eval_every!r}")
        require_int("A3CConfig", "max_episode_steps", self.max_episode_steps, 1, optional=True)
        for name, (largest, unit) in _LARGEST.items():
            value = getattr(self, name)
            if value is not None and value > largest:
                raise ValueError(f"A3CConfig.{name} must be at most {largest:,} ({unit}), got {value!r}")
        for name in _UNIT_INTERVAL:
            _check_number(self, name, getattr(self, name), 0.0, 1.0)
        for name in _POSITIVE_REALS:
            _check_number(self, name, getattr(self, name), 0.0, math.inf, low_open=True)
        if self.finetune is not None:
            _check_choice("finetune", self.finetune, tuple(FINETUNE_PRESETS), optional=True)
        _check_choice("start_curriculum", self.start_curriculum, START_CURRICULA)
        if self.entropy_target is not None and not (
            isinstance(self.entropy_target, (int, float)) and 0 < self.entropy_target <= math.log(5)
        ):
            raise ValueError(
                f"A3CConfig.entropy_target must be None or in (0, ln 5 = {math.log(5):.4f}] nats, "
                f"got {self.entropy_target!r}"
            )
        for name in _NON_NEGATIVE_INTS:
            require_int("A3CConfig", name, getattr(self, name), 0)
        self._check_expert_data()
        if not (isinstance(self.curriculum_threshold, (int, float)) and 0 < self.curriculum_threshold <= 1):
            raise ValueError(f"A3CConfig.curriculum_threshold must be in (0, 1], got {self.curriculum_threshold!r}")
        _check_number(self, "kl_temperature", self.kl_temperature, 0.0, math.inf, low_open=True)
        self._check_randomize_and_augment()
        for name in _NON_NEGATIVE_REALS:
            _check_number(self, name, getattr(self, name), 0.0, math.inf)

    def _check_expert_data(self) -> None:
        needs_data = [
            name
            for name, on in (
                ("bc_coef", self.bc_coef > 0),
                ("start_curriculum='demo'", self.start_curriculum == "demo"),
            )
            if on
        ]
        if needs_data and self.expert_data is None:
            raise ValueError(f"A3CConfig.{needs_data[0]} needs expert_data (an expert dataset directory)")

    def _check_randomize_and_augment(self) -> None:
        if self.randomize is not None:
            _check_choice("randomize", self.randomize, tuple(RANDOMIZATION_PRESETS), optional=True)
            if self.obs != "pixels" and RANDOMIZATION_PRESETS[self.randomize].active(OBSERVATION_FIELDS):
                raise ValueError(
                    f"A3CConfig.randomize={self.randomize!r} randomises the camera, which needs "
                    f"obs='pixels'; with state observations use 'physics'"
                )
        require_int("A3CConfig", "augment_shift", self.augment_shift, 0)
        if self.augment_shift > MAX_SHIFT or (self.augment_shift and self.obs != "pixels"):
            raise ValueError(
                f"A3CConfig.augment_shift must be 0..{MAX_SHIFT} pixels, and 0 for state observations, "
                f"got {self.augment_shift!r} with obs={self.obs!r}"
            )

    @classmethod
    def from_flat(cls, values: Mapping[str, Any]) -> A3CConfig:
        """The settings from flat names (``{"lr": 1e-3, "obs": "state", …}``: the command line's flags,
        a reproduction's overrides, config.json files of every version); unknown names are an error
        naming them."""
        return cls.from_dict(dict(values))

    @property
    def time_limit(self) -> int:
        return self.max_episode_steps or Task(self.task).time_limit

    @property
    def steps_per_update(self) -> int:
        return self.n_steps * self.envs_per_worker

    @property
    def schedules_actor(self) -> bool:
        """Whether the actor's learning rate follows a schedule (critic warm-up or actor ramp): the
        policy head then has its own optimiser parameter group."""
        return self.critic_warmup_steps > 0 or self.actor_ramp_steps > 0

    SETTINGS_NAME: ClassVar[str] = "A3C settings"

    # What a resumed run may change without changing what is being learned.
    RESUMABLE_CHANGES = ("steps", "workers", "checkpoint_every", "eval_every", "eval_episodes", "log_every")


def network_for(config: A3CConfig, maze: MazeSpec | None = None) -> RecurrentActorCritic:
    """A fresh network for ``config``'s run, initialised from its seed."""
    return config.build_policy(config.seed, maze)


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
    if config.optimizer == "rmsprop":
        return torch.optim.RMSprop(params, lr=config.lr, alpha=config.rmsprop_alpha, eps=config.optimizer_eps)
    return torch.optim.Adam(params, lr=config.lr, eps=config.optimizer_eps)


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
        segment.rewards, segment.ends, values.detach(), bootstrap, config.gamma, config.gae_lambda
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
        added.append(config.aux_coef * aux)
    for term in terms:
        contribution, term_parts = term.loss(net, log_probs, weights)
        parts.update(term_parts)
        if contribution is not None:
            added.append(contribution)
    if weights.critic_only:
        return config.value_coef * value_loss, parts
    beta = config.entropy_coef if entropy_coef is None else entropy_coef
    loss = weights.actor * (policy_loss - beta * entropy) + config.value_coef * value_loss
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
    grad_norm = float(torch.nn.utils.clip_grad_norm_(local.parameters(), config.max_grad_norm))
    applied = math.isfinite(loss.item()) and math.isfinite(grad_norm)
    if applied:
        if config.schedules_actor:
            optimizer.param_groups[0]["lr"] = config.lr * weights.actor
        for shared_param, param in zip(shared_params, local.parameters(), strict=True):
            shared_param.grad = param.grad
        optimizer.step()
    return {**parts, "loss": loss.item(), "grad_norm": grad_norm, "applied": applied}


def evaluate(net: RecurrentActorCritic, config: A3CConfig) -> dict[str, float]:
    """The run's periodic evaluation: greedy and sampled, on its evaluation episodes and seed."""
    return evaluate_greedy_and_sampled(
        net,
        task=config.task,
        obs=config.obs,
        episodes=config.eval_episodes,
        seed=evaluation_seed(config.seed),
        time_limit=config.time_limit,
    )
