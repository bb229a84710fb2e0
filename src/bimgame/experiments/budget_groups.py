"""The groups of settings of a reproduction's :class:`~bimgame.experiments.budgets.Budget`: its networks
(:class:`NetworkBudget`), its A3C runs (:class:`A3CBudget`), its expert dataset (:class:`DatasetBudget`),
pre-training π^s (:class:`PretrainBudget`) and V̂ (:class:`ValueBudget`), its DAgger runs
(:class:`DaggerBudget`) and its PPO runs (:class:`PPOBudget`).

Each group validates its own fields when it is made, naming the field by its path in the budget
(``Budget.dataset.episodes must be an integer >= 1, got 0``); what also depends on the grid (every
task of the grid has A3C steps, the dataset labels every task, pixel shifts only for pixels) is
checked by the budget. A group's fields are named as the settings they become
(:mod:`bimgame.experiments.runners`): :class:`~bimgame.learn.common.NetworkSettings`'s,
:class:`~bimgame.learn.a3c.A3CConfig`'s and :class:`~bimgame.learn.ppo.PPOConfig`'s flat names,
:class:`~bimgame.learn.supervised.PretrainConfig`'s and :func:`~bimgame.expert.datasets.generate_dataset`'s
arguments; DAgger's ``episodes`` and ``epochs`` are its ``episodes_per_iteration`` and ``epochs_per_iteration``.

**One step budget.** A3C's and PPO's runs are compared on the same environment steps per task, the
same evaluations and the same checkpoints: the ``a3c`` group's ``steps``, ``eval_every``,
``eval_episodes`` and ``checkpoint_every`` are every such run's, PPO's included. The ``ppo`` group
holds only what is PPO's own (its environments and its optimisation), so a budget cannot give the
two learners different budgets, and a ``plan.json`` written before PPO was in the reproduction
(without a ``ppo`` group) loads with PPO's defaults.

The networks have a group of their own rather than a
:class:`~bimgame.learn.common.NetworkSettings`: that class holds the observations (a grid setting,
which ``--obs`` changes), resolves its None defaults from them and from the machine's CPU when it is
made (a budget keeps "None: the default for the observations", so that another ``--obs`` or another
machine gets its own), and has settings budgets never change (``tilt_input``, ``keypoints``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, ClassVar

from bimgame.learn.augment import MAX_SHIFT
from bimgame.learn.nets import PRECISIONS
from bimgame.learn.ppo import PPOConfig, PPOOptimizationSettings
from bimgame.sim.tasks import Task, parse_task
from bimgame.util.settings import require_int

__all__ = [
    "NetworkBudget",
    "A3CBudget",
    "DatasetBudget",
    "PretrainBudget",
    "ValueBudget",
    "DaggerBudget",
    "PPOBudget",
    "allowed_tasks",
    "task_named",
]


def allowed_tasks() -> str:
    """The task names a budget accepts, for error messages."""
    return ", ".join(t.value for t in Task)


def task_named(path: str, task: str) -> Task:
    """``task`` parsed, or a ValueError naming the setting at ``path`` (``Budget.tasks``, …) and the
    tasks allowed."""
    try:
        return parse_task(task)
    except ValueError:
        raise ValueError(f"{path}: unknown task {task!r}; allowed: {allowed_tasks()}") from None


def _require_ints(owner: str, group: object, names: tuple[str, ...], minimum: int) -> None:
    """Each of ``group``'s fields ``names`` must be an integer >= ``minimum`` (messages name ``owner.name``)."""
    for name in names:
        require_int(owner, name, getattr(group, name), minimum)


@dataclasses.dataclass(frozen=True)
class NetworkBudget:
    """The networks of every piece of the grid (their observations are the budget's ``obs``)."""

    PATH: ClassVar[str] = "Budget.network"

    hidden: int | None = None
    """LSTM size of every network; None: the default for ``obs`` (256 pixels, 128 state)."""
    features: int | None = None
    """Encoder output size; None: the default for ``obs``."""
    subtract_background: bool = False
    """Pixels: subtract the empty-maze frame before the convolutions (ignored for state). The
    presets turn it on: without it the pixel agent did not learn STG1 (see the README)."""
    aux_heads: bool = False
    """Networks with auxiliary heads that predict the simulator's state (see
    :mod:`bimgame.learn.nets`); DAgger's learner never has them (its own rollouts record no states)."""
    asymmetric_critic: bool = False
    """A3C's and π^s's value head also reads the simulator's state (not the paper's)."""
    precision: str = "fp32"
    """The pixel encoder's compute: ``fp32`` or ``bf16``."""

    def __post_init__(self) -> None:
        for name in ("hidden", "features"):
            if getattr(self, name) is not None:
                require_int(self.PATH, name, getattr(self, name), 1)
        for name in ("subtract_background", "aux_heads", "asymmetric_critic"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{self.PATH}.{name} must be True or False, got {getattr(self, name)!r}")
        if self.precision not in PRECISIONS:
            raise ValueError(f"{self.PATH}.precision must be one of {PRECISIONS}, got {self.precision!r}")

    def settings_for(self, obs: str) -> dict[str, Any]:
        """These settings as :class:`~bimgame.learn.common.NetworkSettings` takes them for ``obs``
        observations: ``subtract_background`` is a pixel-only setting, off for state."""
        return {**dataclasses.asdict(self), "subtract_background": self.subtract_background and obs == "pixels"}


@dataclasses.dataclass(frozen=True)
class A3CBudget:
    """How every A3C run of the grid runs: its length per task, its processes, evaluations and
    checkpoints (what it learns is the algorithm's record, :mod:`bimgame.experiments.methods`)."""

    PATH: ClassVar[str] = "Budget.a3c"

    steps: Mapping[str, int] = dataclasses.field(default_factory=lambda: {t.value: 1_000_000 for t in Task})
    """Environment steps per A3C run, per task (every task of the grid needs an entry); PPO's runs take
    the same (one step budget for every method compared)."""
    workers: int = 2
    """A3C worker processes."""
    envs_per_worker: int = 16
    """Environments per A3C worker (stepped as one batch)."""
    augment_shift: int = 0
    """A3C from pixels: DrQ random shifts of up to this many pixels (0: none)."""
    eval_every: int = 100_000
    """A3C and PPO: environment steps between greedy/sampled evaluations (0: only the final one)."""
    eval_episodes: int = 10
    """A3C and PPO: episodes per evaluation."""
    checkpoint_every: int = 50_000
    """A3C and PPO: environment steps between checkpoints (what an interruption can lose)."""

    def __post_init__(self) -> None:
        steps = dict(self.steps)
        for key, value in steps.items():
            task_named(f"{self.PATH}.steps", key)
            require_int(self.PATH, f"steps[{key!r}]", value, 1)
        object.__setattr__(self, "steps", {parse_task(k).value: int(v) for k, v in steps.items()})
        _require_ints(self.PATH, self, ("workers", "envs_per_worker", "eval_episodes", "checkpoint_every"), 1)
        require_int(self.PATH, "eval_every", self.eval_every, 0)
        require_int(self.PATH, "augment_shift", self.augment_shift, 0)
        if self.augment_shift > MAX_SHIFT:
            raise ValueError(self.shift_message())

    def shift_message(self) -> str:
        """The error of an ``augment_shift`` out of range (or not 0 with state observations)."""
        return (
            f"{self.PATH}.augment_shift must be 0..{MAX_SHIFT} pixels, and 0 for state observations, "
            f"got {self.augment_shift!r}"
        )


@dataclasses.dataclass(frozen=True)
class DatasetBudget:
    """The expert dataset that π^s, V̂ and the fine-tuning methods that read demonstrations learn from."""

    PATH: ClassVar[str] = "Budget.dataset"

    task: str = "FULL"
    """Task of the expert dataset; it must be at least as deep as every task of the grid (FULL
    labels every task, see :func:`bimgame.expert.episode.relabel`)."""
    episodes: int = 40
    """Expert episodes in the dataset."""
    seed: int = 0
    """Seed of the dataset: episode ``i`` starts from ``episode_seed(seed, i)``."""
    max_steps: int | None = None
    """Time limit of the expert's episodes; None: the dataset task's."""
    workers: int = 2
    """Processes generating expert episodes (1: in this process)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "task", task_named(f"{self.PATH}.task", self.task).value)
        _require_ints(self.PATH, self, ("episodes", "workers"), 1)
        require_int(self.PATH, "seed", self.seed, 0)
        if self.max_steps is not None:
            require_int(self.PATH, "max_steps", self.max_steps, 1)


@dataclasses.dataclass(frozen=True)
class PretrainBudget:
    """Pre-training π^s, the policy the ``pretrain+…`` algorithms start from."""

    PATH: ClassVar[str] = "Budget.pretrain"

    epochs: int = 30
    """Upper bound on passes over the training episodes (early stopping usually ends sooner)."""
    patience: int = 5
    """Stop after this many epochs without a better held-out loss."""
    eval_episodes: int = 50
    """Episodes measuring π^s alone as a policy (greedy and sampled)."""

    def __post_init__(self) -> None:
        _require_ints(self.PATH, self, ("epochs", "patience"), 1)
        require_int(self.PATH, "eval_episodes", self.eval_episodes, 0)


@dataclasses.dataclass(frozen=True)
class ValueBudget:
    """Pre-training V̂, the value network whose estimates reward the ``…+value`` algorithms."""

    PATH: ClassVar[str] = "Budget.value"

    epochs: int = 100
    """Upper bound on passes over the training episodes (early stopping usually ends sooner)."""
    patience: int = 10
    """Stop after this many epochs without a better held-out loss."""
    batch_frames: int = 64
    """Frames per batch."""

    def __post_init__(self) -> None:
        _require_ints(self.PATH, self, ("epochs", "patience", "batch_frames"), 1)


@dataclasses.dataclass(frozen=True)
class DaggerBudget:
    """Every DAgger run of the grid (its learner is the grid's network, without privileged inputs)."""

    PATH: ClassVar[str] = "Budget.dagger"

    iterations: int = 4
    """Iterations of a run (roll out, label, aggregate, retrain)."""
    episodes: int = 6
    """DAgger: learner rollouts per iteration (each state labelled by the MPC expert, ≈16 ms each)."""
    epochs: int = 5
    """DAgger: passes over the aggregated data per iteration."""
    eval_episodes: int = 20
    """Greedy and sampled evaluation episodes after every iteration (0: none)."""

    def __post_init__(self) -> None:
        _require_ints(self.PATH, self, ("iterations", "episodes", "epochs"), 1)
        require_int(self.PATH, "eval_episodes", self.eval_episodes, 0)


#: PPO's own defaults, which the ``ppo`` group's fields take (read, never copied).
_PPO = PPOOptimizationSettings()


@dataclasses.dataclass(frozen=True)
class PPOBudget:
    """Every PPO run of the grid: its environments and PPO's optimisation settings, PPO's defaults
    unless a budget changes them. Its steps per task, evaluations and checkpoints are the ``a3c``
    group's (see the module notes); it runs in one process with the budget's ``torch_threads``."""

    PATH: ClassVar[str] = "Budget.ppo"

    envs_per_worker: int = PPOConfig().schedule.envs_per_worker
    """Environments stepped as one batch in the run's process (A3C's per worker)."""
    n_steps: int = _PPO.n_steps
    """Steps each environment acts per rollout."""
    epochs: int = _PPO.epochs
    """Passes over each rollout."""
    minibatches: int = _PPO.minibatches
    """Minibatches per epoch (at most the rollout's sequences)."""
    sequence_length: int | None = _PPO.sequence_length
    """Steps of the sequences a minibatch unrolls the LSTM over (a divisor of ``n_steps``); None: each
    environment's whole rollout."""
    clip: float = _PPO.clip
    """The ratio clip ε of the surrogate objective."""
    value_clip: float | None = _PPO.value_clip
    """Clip of the value function's change per rollout; None: none."""
    gamma: float = _PPO.gamma
    """Discount."""
    gae_lambda: float = _PPO.gae_lambda
    """λ of generalised advantage estimation."""
    lr: float = _PPO.lr
    """Adam's learning rate."""
    lr_anneal: bool = _PPO.lr_anneal
    """Decay the learning rate linearly to zero over the run's steps."""
    optimizer_eps: float = _PPO.optimizer_eps
    """Adam's epsilon."""
    entropy_coef: float = _PPO.entropy_coef
    """Weight of the entropy bonus."""
    value_coef: float = _PPO.value_coef
    """Weight of the value loss."""
    max_grad_norm: float = _PPO.max_grad_norm
    """Global norm each minibatch's gradient is clipped to."""
    advantage_norm: bool = _PPO.advantage_norm
    """Normalise each minibatch's advantages."""
    aux_coef: float = _PPO.aux_coef
    """Weight of the auxiliary heads' loss when the networks have them."""
    sample_temperature: float = _PPO.sample_temperature
    """Temperature of the policy that acts in training (and of the clipped objective and entropy)."""
    final_max_std: float | None = _PPO.final_max_std
    """A Gaussian policy's σ ends at most this (a ceiling falling from 1 over the run); None: free."""
    policy_lag: int = _PPO.policy_lag
    """1: each rollout is collected while the last one's update runs (one update of lag); 0: in turn."""

    def __post_init__(self) -> None:
        require_int(self.PATH, "envs_per_worker", self.envs_per_worker, 1)
        try:
            PPOConfig.from_flat(dataclasses.asdict(self))
        except (ValueError, TypeError) as error:
            raise ValueError(self._named(str(error))) from None

    def _named(self, message: str) -> str:
        """A message of PPO's settings with each setting named by its path in the budget."""
        for owner in ("PPOOptimizationSettings.", "ScheduleSettings.", "PPOConfig.", "PPOConfig: "):
            message = message.replace(owner, f"{self.PATH}." if owner.endswith(".") else f"{self.PATH}: ")
        return message
