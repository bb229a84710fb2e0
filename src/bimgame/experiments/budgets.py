"""What a reproduction computes: the :class:`Budget` — the grid (tasks × algorithms × seeds) and
every piece's settings — with its presets: ``quick`` and ``paper`` for the paper's comparison,
``pixels`` for the paper's grid from pixels, ``beyond`` and ``ablation`` for fine-tuning beyond it.

The budget is the one input of a reproduction: it is stored in ``plan.json``
(:mod:`bimgame.experiments.plan`) and decides every piece (:mod:`bimgame.experiments.grid`) and
every piece's settings (:mod:`bimgame.experiments.runners`). It is validated here, when it is
made, so that a bad value fails before anything runs, naming the field and what is allowed.

The compared algorithms are the records of :mod:`bimgame.experiments.algorithms` (each says what it
is); a budget names them. Why the presets have the sizes they have, and what they measured, is in
``docs/budgets.md``.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Mapping

from bimgame.envs.observe import OBS_MODES
from bimgame.experiments.algorithms import LABELS, algorithm_named, algorithm_names, registered
from bimgame.learn.augment import MAX_SHIFT
from bimgame.learn.nets import PRECISIONS
from bimgame.sim.maze import MazeSpec
from bimgame.sim.tasks import Task, parse_task
from bimgame.util.settings import from_dict, require_int

__all__ = ["PAPER_ALGORITHMS", "ALGORITHMS", "ALGORITHM_LABELS", "PAPER_TASKS", "GRID_FIELDS", "Budget", "BUDGETS",
           "budget_named"]

#: The paper's compared methods, in the order of its figures (the presets' default grid).
PAPER_ALGORITHMS = tuple(a.name for a in registered() if a.paper)
#: The built-in algorithms: the paper's, then the fine-tuning methods beyond it (algorithms
#: registered later are in :func:`~bimgame.experiments.algorithms.algorithm_names`).
ALGORITHMS = algorithm_names()
#: The algorithms' names in figures and tables (of every registered algorithm).
ALGORITHM_LABELS = LABELS
#: The tasks of the paper's learning curves (STG3/STG4 can be added: the paper reports them unlearned).
PAPER_TASKS = ("FULL", "STG1", "STG2")
#: Budget fields that only change which pieces exist (not what any piece computes): a reproduction
#: directory may be continued with other values of these, reusing every piece they share.
GRID_FIELDS = ("tasks", "algorithms", "seeds")


@dataclasses.dataclass(frozen=True)
class Budget:
    """Everything that decides what a reproduction computes: the grid and every piece's settings.

    The presets are :data:`BUDGETS` (``quick``, ``paper``, ``beyond``, ``ablation``); any field can
    be changed with :func:`dataclasses.replace`. Invalid values raise ``ValueError`` naming the field."""

    name: str = "custom"
    """A label for reports (``quick``, ``paper`` or anything else)."""
    tasks: tuple[str, ...] = ("STG1",)
    """Tasks of the grid (FULL, STG1 … STG4)."""
    algorithms: tuple[str, ...] = PAPER_ALGORITHMS
    """Methods of the grid, by the names of their records in :mod:`bimgame.experiments.algorithms`:
    the paper's a3c, pretrain+a3c, a3c+value, pretrain+a3c+value, dagger (the default) and the
    fine-tuning methods beyond it; kept in the registry's order."""
    seeds: int = 2
    """Runs per task and algorithm (seeds 0 … seeds−1)."""
    obs: str = "state"
    """``state`` or ``pixels`` (the paper's), for every network of the grid."""
    a3c_steps: Mapping[str, int] = dataclasses.field(default_factory=lambda: {t.value: 1_000_000 for t in Task})
    """Environment steps per A3C run, per task (every task of the grid needs an entry)."""
    workers: int = 2
    """A3C worker processes."""
    envs_per_worker: int = 16
    """Environments per A3C worker (stepped as one batch)."""
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
    augment_shift: int = 0
    """A3C from pixels: DrQ random shifts of up to this many pixels (0: none)."""
    eval_every: int = 100_000
    """A3C: environment steps between greedy/sampled evaluations (0: only the final one)."""
    eval_episodes: int = 10
    """A3C: episodes per evaluation."""
    checkpoint_every: int = 50_000
    """A3C: environment steps between checkpoints (what an interruption can lose)."""
    dataset_task: str = "FULL"
    """Task of the expert dataset; it must be at least as deep as every task of the grid (FULL
    labels every task, see :func:`bimgame.expert.episode.relabel`)."""
    dataset_episodes: int = 40
    dataset_seed: int = 0
    dataset_max_steps: int | None = None
    """Time limit of the expert's episodes; None: the dataset task's."""
    dataset_workers: int = 2
    """Processes generating expert episodes (1: in this process)."""
    pretrain_epochs: int = 30
    pretrain_patience: int = 5
    pretrain_eval_episodes: int = 50
    """Episodes measuring π^s alone as a policy (greedy and sampled)."""
    value_epochs: int = 100
    value_patience: int = 10
    value_batch_frames: int = 64
    dagger_iterations: int = 4
    dagger_episodes: int = 6
    """DAgger: learner rollouts per iteration (each state labelled by the MPC expert, ≈16 ms each)."""
    dagger_epochs: int = 5
    """DAgger: passes over the aggregated data per iteration."""
    dagger_eval_episodes: int = 20
    threshold_fraction: float = 0.8
    """Steps-to-threshold: the success rate to reach, as a fraction of the expert's on the task."""
    torch_threads: int = 1
    """Torch threads of pre-training and DAgger (see :mod:`bimgame.experiments.runners`; A3C workers
    use one each)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "tasks", _checked_tasks(self.tasks))
        object.__setattr__(self, "algorithms", _checked_algorithms(self.algorithms))
        if self.obs not in OBS_MODES:
            raise ValueError(f"Budget.obs must be one of {', '.join(OBS_MODES)}, got {self.obs!r}")
        object.__setattr__(self, "a3c_steps", _checked_steps(self.a3c_steps, self.tasks, self.algorithms))
        self._check_numbers()
        self._check_network()
        object.__setattr__(self, "dataset_task", _checked_dataset_task(self.dataset_task, self.tasks))

    def _check_numbers(self) -> None:
        """The counts: at least 1 (or 0 where 0 means none), None where None means a default."""
        for name in ("seeds", "workers", "envs_per_worker", "eval_episodes", "checkpoint_every", "dataset_episodes",
                     "dataset_workers", "pretrain_epochs", "pretrain_patience", "value_epochs", "value_patience",
                     "value_batch_frames", "dagger_iterations", "dagger_episodes", "dagger_epochs", "torch_threads"):
            require_int("Budget", name, getattr(self, name), 1)
        for name in ("eval_every", "dataset_seed", "pretrain_eval_episodes", "dagger_eval_episodes"):
            require_int("Budget", name, getattr(self, name), 0)
        for name in ("hidden", "features", "dataset_max_steps"):
            if getattr(self, name) is not None:
                require_int("Budget", name, getattr(self, name), 1)
        if not (isinstance(self.threshold_fraction, (int, float)) and not isinstance(self.threshold_fraction, bool)
                and 0.0 < self.threshold_fraction <= 1.0):
            raise ValueError(f"Budget.threshold_fraction must be in (0, 1], got {self.threshold_fraction!r}")

    def _check_network(self) -> None:
        """The networks' switches, precision and augmentation."""
        for name in ("subtract_background", "aux_heads", "asymmetric_critic"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"Budget.{name} must be True or False, got {getattr(self, name)!r}")
        if self.precision not in PRECISIONS:
            raise ValueError(f"Budget.precision must be one of {PRECISIONS}, got {self.precision!r}")
        require_int("Budget", "augment_shift", self.augment_shift, 0)
        if self.augment_shift > MAX_SHIFT or (self.augment_shift and self.obs != "pixels"):
            raise ValueError(f"Budget.augment_shift must be 0..{MAX_SHIFT} pixels, and 0 for state observations, "
                             f"got {self.augment_shift!r}")

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready values (what ``plan.json`` stores)."""
        values = dataclasses.asdict(self)
        values["tasks"] = list(self.tasks)
        values["algorithms"] = list(self.algorithms)
        values["a3c_steps"] = dict(self.a3c_steps)
        return values

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> Budget:
        """The budget of :meth:`to_dict`'s values; unknown keys are an error naming them."""
        return from_dict(cls, dict(values), "budget settings")

    def with_grid(self, *, tasks: tuple[str, ...] | list[str] | None = None,
                  algorithms: tuple[str, ...] | list[str] | None = None, seeds: int | None = None,
                  obs: str | None = None, torch_threads: int | None = None) -> Budget:
        """This budget with the given grid (and observation) overrides; None keeps the value."""
        changes = {k: v for k, v in (("tasks", tasks), ("algorithms", algorithms), ("seeds", seeds), ("obs", obs),
                                     ("torch_threads", torch_threads)) if v is not None}
        return dataclasses.replace(self, **changes)

    def steps_for(self, task: str) -> int:
        """Environment steps of an A3C run on ``task``."""
        return int(self.a3c_steps[parse_task(task).value])

    @property
    def needs_policy(self) -> bool:
        """Whether an algorithm of the grid starts from a pre-trained π^s."""
        return any(uses_policy(a) for a in self.algorithms)

    @property
    def needs_value(self) -> bool:
        """Whether an algorithm of the grid is rewarded with a pre-trained V̂."""
        return any(uses_value(a) for a in self.algorithms)

    @property
    def network_subtract_background(self) -> bool:
        """``subtract_background`` as the networks get it: a pixel-only setting, off for state."""
        return self.subtract_background and self.obs == "pixels"


def _allowed_tasks() -> str:
    return ", ".join(t.value for t in Task)


def _task_named(field: str, task: str) -> Task:
    """``task`` parsed, or a ValueError naming ``field`` and the tasks allowed."""
    try:
        return parse_task(task)
    except ValueError:
        raise ValueError(f"Budget.{field}: unknown task {task!r}; allowed: {_allowed_tasks()}") from None


def _checked_tasks(given: Any) -> tuple[str, ...]:
    """The grid's tasks by their canonical names, each once."""
    tasks = tuple(_task_named("tasks", t).value for t in tuple(given))
    if not tasks:
        raise ValueError(f"Budget.tasks must name at least one task; allowed: {_allowed_tasks()}")
    if len(set(tasks)) != len(tasks):
        raise ValueError(f"Budget.tasks lists a task twice: {list(tasks)}")
    return tasks


def _checked_algorithms(given: Any) -> tuple[str, ...]:
    """The grid's algorithms, each registered and once, in the registry's order whatever order they
    were given in."""
    algorithms = tuple(given)
    allowed = ", ".join(algorithm_names())
    if not algorithms:
        raise ValueError(f"Budget.algorithms must name at least one; allowed: {allowed}")
    unknown = [a for a in algorithms if a not in algorithm_names()]
    if unknown:
        raise ValueError(f"Budget.algorithms: unknown {unknown}; allowed: {allowed}")
    if len(set(algorithms)) != len(algorithms):
        raise ValueError(f"Budget.algorithms lists an algorithm twice: {list(algorithms)}")
    return tuple(a for a in algorithm_names() if a in algorithms)


def _checked_steps(given: Mapping[str, Any], tasks: tuple[str, ...], algorithms: tuple[str, ...]) -> dict[str, int]:
    """A3C's steps per task, by canonical task names; every task of the grid needs an entry when an
    algorithm of the grid trains by steps."""
    steps = dict(given)
    for key, value in steps.items():
        _task_named("a3c_steps", key)
        require_int("Budget", f"a3c_steps[{key!r}]", value, 1)
    missing = [t for t in tasks if t not in steps]
    if missing and any(algorithm_named(a).trains_by_steps for a in algorithms):
        raise ValueError(f"Budget.a3c_steps has no entry for {missing}; give steps for every task of the grid")
    return {parse_task(k).value: int(v) for k, v in steps.items()}


def _checked_dataset_task(given: str, tasks: tuple[str, ...]) -> str:
    """The dataset's task, which must label every task of the grid."""
    data_task = _task_named("dataset_task", given)
    spec = MazeSpec.merl()
    too_deep = [t for t in tasks if Task(t).walls_to_pass(spec) > data_task.walls_to_pass(spec)]
    if too_deep:
        raise ValueError(f"Budget.dataset_task {data_task.value} cannot label {too_deep}: its episodes end "
                         f"before theirs would; use dataset_task='FULL' (it labels every task)")
    return data_task.value


def uses_policy(algorithm: str) -> bool:
    """Whether ``algorithm``'s runs start from the pre-trained π^s (its record says)."""
    return algorithm_named(algorithm).starts_from_policy


def uses_value(algorithm: str) -> bool:
    """Whether ``algorithm``'s runs are rewarded with the pre-trained V̂ (its record says)."""
    return algorithm_named(algorithm).value_reward


#: The settings of the ``beyond`` and ``ablation`` presets. Everything but the grid is the same, so
#: either can continue the other's reproduction directory, reusing its dataset, π^s and shared runs.
#: Fewer steps than ``quick`` sets for these tasks, so that ``beyond`` fits in two hours on two
#: cores; evaluations every 50k steps show the dip when fine-tuning forgets π^s (``docs/budgets.md``).
_BEYOND_SETTINGS: dict[str, Any] = dict(
    seeds=3, obs="state", subtract_background=True,
    a3c_steps={"STG1": 300_000, "STG2": 400_000, "STG3": 500_000, "STG4": 500_000, "FULL": 500_000},
    eval_every=50_000, eval_episodes=20, checkpoint_every=50_000,
    dataset_task="FULL", dataset_episodes=80, dataset_workers=2, pretrain_eval_episodes=50)

#: The presets: ``quick``, the comparison on STG1 from state within half an hour on two cores;
#: ``paper``, the paper's grid (pixels, FULL/STG1/STG2, five seeds, 5M steps per A3C run), about a
#: day; ``pixels``, the paper's grid from pixels within two hours, with ``a3c+papernet`` beside the
#: improved network; ``beyond`` and ``ablation``, fine-tuning π^s without forgetting it on
#: STG2–FULL, and each fine-tuning method on its own on STG3 (:data:`_BEYOND_SETTINGS`). Why each has
#: the sizes it has, and what it measured: ``docs/budgets.md``.
BUDGETS: dict[str, Budget] = {
    "quick": Budget(
        name="quick", tasks=("STG1",), seeds=2, obs="state", subtract_background=True,
        a3c_steps={"STG1": 300_000, "STG2": 1_000_000, "STG3": 1_500_000, "STG4": 2_000_000, "FULL": 2_000_000},
        eval_every=100_000, eval_episodes=10, checkpoint_every=50_000,
        dataset_task="FULL", dataset_episodes=80, dataset_workers=2,
        pretrain_eval_episodes=50, dagger_iterations=4, dagger_episodes=6, dagger_epochs=10, dagger_eval_episodes=20),
    "paper": Budget(
        name="paper", tasks=PAPER_TASKS, seeds=5, obs="pixels", aux_heads=True, asymmetric_critic=False,
        precision="bf16",
        a3c_steps={t.value: 5_000_000 for t in Task},
        eval_every=250_000, eval_episodes=20, checkpoint_every=200_000,
        dataset_task="FULL", dataset_episodes=300, dataset_workers=2,
        pretrain_eval_episodes=50, dagger_iterations=10, dagger_episodes=20, dagger_epochs=10,
        dagger_eval_episodes=20),
    "pixels": Budget(
        name="pixels", tasks=PAPER_TASKS, algorithms=(*PAPER_ALGORITHMS, "a3c+papernet"), seeds=3, obs="pixels",
        aux_heads=True, asymmetric_critic=True, precision="bf16",
        a3c_steps={"STG1": 600_000, "STG2": 300_000, "FULL": 300_000, "STG3": 500_000, "STG4": 500_000},
        eval_every=0, eval_episodes=20, checkpoint_every=50_000,
        dataset_task="FULL", dataset_episodes=80, dataset_workers=2,
        pretrain_eval_episodes=20, dagger_iterations=3, dagger_episodes=6, dagger_epochs=5, dagger_eval_episodes=20),
    "beyond": Budget(
        name="beyond", tasks=("STG2", "STG3", "STG4", "FULL"), algorithms=("a3c", "pretrain+a3c", "pretrain+a3c+keep"),
        **_BEYOND_SETTINGS),
    "ablation": Budget(
        name="ablation", tasks=("STG3",), algorithms=("pretrain+a3c", "pretrain+a3c+warmup", "pretrain+a3c+kl",
                                                      "pretrain+a3c+norm", "pretrain+a3c+bc", "pretrain+a3c+demo",
                                                      "pretrain+a3c+keep", "a3c+reverse"),
        **_BEYOND_SETTINGS),
}


def budget_named(name: str) -> Budget:
    """A preset of :data:`BUDGETS` by name."""
    if name not in BUDGETS:
        raise ValueError(f"unknown budget {name!r}; allowed: {', '.join(BUDGETS)}")
    return BUDGETS[name]
