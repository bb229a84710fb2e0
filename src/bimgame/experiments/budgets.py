"""What a reproduction computes: the :class:`Budget` — the grid (tasks × algorithms × seeds) and
every piece's settings — with its presets: ``quick`` and ``paper`` for the paper's comparison,
``pixels`` for the paper's grid from pixels, ``beyond`` and ``ablation`` for fine-tuning beyond it.

The budget is the one input of a reproduction: it is stored in ``plan.json``
(:mod:`bimgame.experiments.plan`) and decides every piece (:mod:`bimgame.experiments.grid`) and
every piece's settings (:mod:`bimgame.experiments.runners`). It is validated here, when it is
made, so that a bad value fails before anything runs, naming the field and what is allowed.

The grid (tasks, algorithms, seeds, observations) is the budget's own; the pieces' settings come in
groups (:mod:`bimgame.experiments.budget_groups`): ``network``, ``a3c``, ``dataset``, ``pretrain``,
``value``, ``dagger`` and ``ppo``, each named by its path (``dagger.episodes``) in errors, reports
and ``plan.json``. A ``plan.json`` written when every setting was a field of the budget itself
(``dagger_episodes``) still loads as the same budget (:data:`FLAT_FIELDS`); one written before the
``ppo`` group (PPO was not in the reproduction then) loads with PPO's defaults, which every preset
keeps, so such a directory continues with its preset.

The compared algorithms are the records of :mod:`bimgame.experiments.algorithms` (each says what it
is); a budget names them. Why the presets have the sizes they have, and what they measured, is in
``docs/budgets.md``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from bimgame.envs.observe import OBS_MODES
from bimgame.experiments.algorithms import LABELS, Learner, algorithm_named, algorithm_names, registered
from bimgame.experiments.budget_groups import (
    A3CBudget,
    DaggerBudget,
    DatasetBudget,
    NetworkBudget,
    PPOBudget,
    PretrainBudget,
    ValueBudget,
    allowed_tasks,
    task_named,
)
from bimgame.sim.maze import MazeSpec
from bimgame.sim.tasks import Task, parse_task
from bimgame.util.settings import from_dict, require_int

__all__ = [
    "PAPER_ALGORITHMS",
    "ALGORITHMS",
    "ALGORITHM_LABELS",
    "PAPER_TASKS",
    "GRID_FIELDS",
    "GROUPS",
    "FLAT_FIELDS",
    "Budget",
    "NetworkBudget",
    "A3CBudget",
    "DatasetBudget",
    "PretrainBudget",
    "ValueBudget",
    "DaggerBudget",
    "PPOBudget",
    "BUDGETS",
    "budget_named",
]

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

#: The budget's groups of settings, by field name.
GROUPS: dict[str, type] = {
    "network": NetworkBudget,
    "a3c": A3CBudget,
    "dataset": DatasetBudget,
    "pretrain": PretrainBudget,
    "value": ValueBudget,
    "dagger": DaggerBudget,
    "ppo": PPOBudget,
}

#: Where each setting of a flat budget — the ``plan.json`` of a reproduction started before the budget
#: had groups — is now: its group and field there. The other flat names are the budget's own fields.
FLAT_FIELDS: dict[str, tuple[str, str]] = {
    "hidden": ("network", "hidden"),
    "features": ("network", "features"),
    "subtract_background": ("network", "subtract_background"),
    "aux_heads": ("network", "aux_heads"),
    "asymmetric_critic": ("network", "asymmetric_critic"),
    "precision": ("network", "precision"),
    "a3c_steps": ("a3c", "steps"),
    "workers": ("a3c", "workers"),
    "envs_per_worker": ("a3c", "envs_per_worker"),
    "augment_shift": ("a3c", "augment_shift"),
    "eval_every": ("a3c", "eval_every"),
    "eval_episodes": ("a3c", "eval_episodes"),
    "checkpoint_every": ("a3c", "checkpoint_every"),
    "dataset_task": ("dataset", "task"),
    "dataset_episodes": ("dataset", "episodes"),
    "dataset_seed": ("dataset", "seed"),
    "dataset_max_steps": ("dataset", "max_steps"),
    "dataset_workers": ("dataset", "workers"),
    "pretrain_epochs": ("pretrain", "epochs"),
    "pretrain_patience": ("pretrain", "patience"),
    "pretrain_eval_episodes": ("pretrain", "eval_episodes"),
    "value_epochs": ("value", "epochs"),
    "value_patience": ("value", "patience"),
    "value_batch_frames": ("value", "batch_frames"),
    "dagger_iterations": ("dagger", "iterations"),
    "dagger_episodes": ("dagger", "episodes"),
    "dagger_epochs": ("dagger", "epochs"),
    "dagger_eval_episodes": ("dagger", "eval_episodes"),
}


@dataclasses.dataclass(frozen=True)
class Budget:
    """Everything that decides what a reproduction computes: the grid and every piece's settings,
    the latter in groups (:mod:`bimgame.experiments.budget_groups`).

    The presets are :data:`BUDGETS` (``quick``, ``paper``, ``beyond``, ``ablation``); any field can
    be changed with :meth:`replace` (or :func:`dataclasses.replace`). Invalid values raise
    ``ValueError`` naming the field by its path (``Budget.seeds``, ``Budget.dagger.episodes``)."""

    name: str = "custom"
    """A label for reports (``quick``, ``paper`` or anything else)."""
    tasks: tuple[str, ...] = ("STG1",)
    """Tasks of the grid (FULL, STG1 … STG4)."""
    algorithms: tuple[str, ...] = PAPER_ALGORITHMS
    """Methods of the grid, by the names of their records in :mod:`bimgame.experiments.algorithms`:
    the paper's a3c, pretrain+a3c, a3c+value, pretrain+a3c+value, dagger (the default), the
    fine-tuning methods beyond it, and ppo and pretrain+ppo (PPO from random weights and from the
    same π^s); kept in the registry's order."""
    seeds: int = 2
    """Runs per task and algorithm (seeds 0 … seeds−1)."""
    obs: str = "state"
    """``state`` or ``pixels`` (the paper's), for every network of the grid."""
    network: NetworkBudget = dataclasses.field(default_factory=NetworkBudget)
    """Every network's sizes, inputs and precision."""
    a3c: A3CBudget = dataclasses.field(default_factory=A3CBudget)
    """Every A3C run's steps per task, processes, evaluations and checkpoints."""
    dataset: DatasetBudget = dataclasses.field(default_factory=DatasetBudget)
    """The expert dataset."""
    pretrain: PretrainBudget = dataclasses.field(default_factory=PretrainBudget)
    """Pre-training π^s."""
    value: ValueBudget = dataclasses.field(default_factory=ValueBudget)
    """Pre-training V̂."""
    dagger: DaggerBudget = dataclasses.field(default_factory=DaggerBudget)
    """Every DAgger run."""
    ppo: PPOBudget = dataclasses.field(default_factory=PPOBudget)
    """Every PPO run's environments and optimisation (its steps, evaluations and checkpoints are ``a3c``'s)."""
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
        for name, group in GROUPS.items():
            if not isinstance(getattr(self, name), group):
                raise ValueError(f"Budget.{name} must be a {group.__name__}, got {getattr(self, name)!r}")
        for name in ("seeds", "torch_threads"):
            require_int("Budget", name, getattr(self, name), 1)
        fraction = self.threshold_fraction
        if not (isinstance(fraction, (int, float)) and not isinstance(fraction, bool) and 0.0 < fraction <= 1.0):
            raise ValueError(f"Budget.threshold_fraction must be in (0, 1], got {self.threshold_fraction!r}")
        self._check_across_groups()

    def _check_across_groups(self) -> None:
        """What the groups cannot check alone: every task of the grid has A3C steps when an algorithm
        trains by steps, pixel shifts only for pixels and not beside PPO (which has none, so its runs
        would not be comparable), and a dataset that labels every task."""
        missing = [t for t in self.tasks if t not in self.a3c.steps]
        if missing and any(algorithm_named(a).trains_by_steps for a in self.algorithms):
            raise ValueError(f"Budget.a3c.steps has no entry for {missing}; give steps for every task of the grid")
        if self.a3c.augment_shift and self.obs != "pixels":
            raise ValueError(self.a3c.shift_message())
        ppo = [a for a in self.algorithms if algorithm_named(a).learner is Learner.PPO]
        if self.a3c.augment_shift and ppo:
            raise ValueError(
                f"Budget.a3c.augment_shift {self.a3c.augment_shift} with {', '.join(ppo)} in the grid: PPO's runs "
                f"have no random shifts, so they would not be compared with A3C's on equal terms; use "
                f"augment_shift=0, or leave {', '.join(ppo)} out of Budget.algorithms"
            )
        spec = MazeSpec.merl()
        data_task = Task(self.dataset.task)
        too_deep = [t for t in self.tasks if Task(t).walls_to_pass(spec) > data_task.walls_to_pass(spec)]
        if too_deep:
            raise ValueError(
                f"Budget.dataset.task {data_task.value} cannot label {too_deep}: its episodes end "
                f"before theirs would; use dataset.task='FULL' (it labels every task)"
            )

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready values, each group a dict of its own (what ``plan.json`` stores)."""
        values = dataclasses.asdict(self)
        values["tasks"] = list(self.tasks)
        values["algorithms"] = list(self.algorithms)
        return values

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> Budget:
        """The budget of :meth:`to_dict`'s values, or of a flat budget's (the ``plan.json`` of a
        reproduction started before the budget had groups; :data:`FLAT_FIELDS` says where each flat
        name is now). Unknown keys are an error naming them and the allowed ones."""
        nested = _nested(values)
        groups = {name: _group_from(name, nested[name]) for name in GROUPS if name in nested}
        return from_dict(cls, {**nested, **groups}, "budget settings")

    def replace(self, **changes: Any) -> Budget:
        """This budget with ``changes``: a field's new value, or for a group a mapping of the fields
        it changes (``budget.replace(seeds=1, dagger={"episodes": 3})``)."""
        for name, change in changes.items():
            if name in GROUPS and isinstance(change, Mapping):
                changes[name] = dataclasses.replace(getattr(self, name), **change)
        return dataclasses.replace(self, **changes)

    def with_grid(
        self,
        *,
        tasks: tuple[str, ...] | list[str] | None = None,
        algorithms: tuple[str, ...] | list[str] | None = None,
        seeds: int | None = None,
        obs: str | None = None,
        torch_threads: int | None = None,
    ) -> Budget:
        """This budget with the given grid (and observation) overrides; None keeps the value."""
        given = (("tasks", tasks), ("algorithms", algorithms), ("seeds", seeds), ("obs", obs))
        changes: dict[str, Any] = {k: v for k, v in (*given, ("torch_threads", torch_threads)) if v is not None}
        return dataclasses.replace(self, **changes)

    def settings_by_path(self) -> dict[str, Any]:
        """:meth:`to_dict`'s values with each group's fields by their paths (``a3c.steps``,
        ``dataset.episodes``, …): one line each in the report's settings table."""
        values: dict[str, Any] = {}
        for key, value in self.to_dict().items():
            values.update({f"{key}.{k}": v for k, v in value.items()} if key in GROUPS else {key: value})
        return values

    def compared_settings(self) -> dict[str, Any]:
        """:meth:`settings_by_path` as the pieces get them, which two budgets must share for one to
        continue the other's reproduction (with :data:`GRID_FIELDS` and the name free to differ): a
        pixel-only setting changes nothing with state observations."""
        return {**self.settings_by_path(), "network.subtract_background": self.network_subtract_background}

    def steps_for(self, task: str) -> int:
        """Environment steps of an A3C or PPO run on ``task``."""
        return int(self.a3c.steps[parse_task(task).value])

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
        """``network.subtract_background`` as the networks get it: a pixel-only setting, off for state."""
        return bool(self.network.settings_for(self.obs)["subtract_background"])


def _nested(values: Mapping[str, Any]) -> dict[str, Any]:
    """``values`` with every flat name (:data:`FLAT_FIELDS`) moved into its group's mapping."""
    nested = {k: v for k, v in values.items() if k not in FLAT_FIELDS}
    for key in [k for k in values if k in FLAT_FIELDS]:
        group, field = FLAT_FIELDS[key]
        given = nested.get(group, {})
        if not isinstance(given, Mapping):
            continue  # refused by _group_from, naming the group
        if field in given:
            raise ValueError(f"budget settings give Budget.{group}.{field} twice: as {key!r} and in {group!r}")
        nested[group] = {**given, field: values[key]}
    return nested


def _group_from(name: str, values: Any) -> Any:
    """The group ``name`` of a budget's stored values; unknown keys are an error naming them."""
    if not isinstance(values, Mapping):
        raise ValueError(f"Budget.{name} must be a mapping of its settings, got {values!r}")
    return from_dict(GROUPS[name], dict(values), f"budget settings of Budget.{name}")


def _checked_tasks(given: Any) -> tuple[str, ...]:
    """The grid's tasks by their canonical names, each once."""
    tasks = tuple(task_named("Budget.tasks", t).value for t in tuple(given))
    if not tasks:
        raise ValueError(f"Budget.tasks must name at least one task; allowed: {allowed_tasks()}")
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
    seeds=3,
    obs="state",
    network=NetworkBudget(subtract_background=True),
    a3c=A3CBudget(
        steps={"STG1": 300_000, "STG2": 400_000, "STG3": 500_000, "STG4": 500_000, "FULL": 500_000},
        eval_every=50_000,
        eval_episodes=20,
        checkpoint_every=50_000,
    ),
    dataset=DatasetBudget(task="FULL", episodes=80, workers=2),
    pretrain=PretrainBudget(eval_episodes=50),
)

#: The presets: ``quick``, the comparison on STG1 from state within half an hour on two cores;
#: ``paper``, the paper's grid (pixels, FULL/STG1/STG2, five seeds, 5M steps per A3C run), about a
#: day; ``pixels``, the paper's grid from pixels within two hours, with ``a3c+papernet`` beside the
#: improved network; ``beyond`` and ``ablation``, fine-tuning π^s without forgetting it on
#: STG2–FULL, and each fine-tuning method on its own on STG3 (:data:`_BEYOND_SETTINGS`). Why each has
#: the sizes it has, and what it measured: ``docs/budgets.md``. ``smoke`` checks the whole pipeline
#: (dataset, π^s, V̂, A3C, DAgger, report) end to end in a few minutes; its numbers mean nothing.
BUDGETS: dict[str, Budget] = {
    "quick": Budget(
        name="quick",
        tasks=("STG1",),
        seeds=2,
        obs="state",
        network=NetworkBudget(subtract_background=True),
        a3c=A3CBudget(
            steps={"STG1": 300_000, "STG2": 1_000_000, "STG3": 1_500_000, "STG4": 2_000_000, "FULL": 2_000_000},
            eval_every=100_000,
            eval_episodes=10,
            checkpoint_every=50_000,
        ),
        dataset=DatasetBudget(task="FULL", episodes=80, workers=2),
        pretrain=PretrainBudget(eval_episodes=50),
        dagger=DaggerBudget(iterations=4, episodes=6, epochs=10, eval_episodes=20),
    ),
    "paper": Budget(
        name="paper",
        tasks=PAPER_TASKS,
        seeds=5,
        obs="pixels",
        network=NetworkBudget(aux_heads=True, asymmetric_critic=False, precision="bf16"),
        a3c=A3CBudget(
            steps={t.value: 5_000_000 for t in Task}, eval_every=250_000, eval_episodes=20, checkpoint_every=200_000
        ),
        dataset=DatasetBudget(task="FULL", episodes=300, workers=2),
        pretrain=PretrainBudget(eval_episodes=50),
        dagger=DaggerBudget(iterations=10, episodes=20, epochs=10, eval_episodes=20),
    ),
    "pixels": Budget(
        name="pixels",
        tasks=PAPER_TASKS,
        algorithms=(*PAPER_ALGORITHMS, "a3c+papernet"),
        seeds=3,
        obs="pixels",
        network=NetworkBudget(aux_heads=True, asymmetric_critic=True, precision="bf16"),
        a3c=A3CBudget(
            steps={"STG1": 600_000, "STG2": 300_000, "FULL": 300_000, "STG3": 500_000, "STG4": 500_000},
            eval_every=0,
            eval_episodes=20,
            checkpoint_every=50_000,
        ),
        dataset=DatasetBudget(task="FULL", episodes=80, workers=2),
        pretrain=PretrainBudget(eval_episodes=20),
        dagger=DaggerBudget(iterations=3, episodes=6, epochs=5, eval_episodes=20),
    ),
    "beyond": Budget(
        name="beyond",
        tasks=("STG2", "STG3", "STG4", "FULL"),
        algorithms=("a3c", "pretrain+a3c", "pretrain+a3c+keep"),
        **_BEYOND_SETTINGS,
    ),
    "ablation": Budget(
        name="ablation",
        tasks=("STG3",),
        algorithms=(
            "pretrain+a3c",
            "pretrain+a3c+warmup",
            "pretrain+a3c+kl",
            "pretrain+a3c+norm",
            "pretrain+a3c+bc",
            "pretrain+a3c+demo",
            "pretrain+a3c+keep",
            "a3c+reverse",
        ),
        **_BEYOND_SETTINGS,
    ),
    "smoke": Budget(
        name="smoke",
        tasks=("STG1",),
        seeds=2,
        obs="state",
        network=NetworkBudget(hidden=16, features=16),
        a3c=A3CBudget(
            steps={t.value: 2_000 for t in Task},
            workers=1,
            envs_per_worker=4,
            eval_every=0,
            eval_episodes=2,
            checkpoint_every=500,
        ),
        dataset=DatasetBudget(task="FULL", episodes=4, workers=2),
        pretrain=PretrainBudget(epochs=2, patience=1, eval_episodes=2),
        value=ValueBudget(epochs=2, patience=1),
        dagger=DaggerBudget(iterations=1, episodes=2, epochs=1, eval_episodes=2),
    ),
}


def budget_named(name: str) -> Budget:
    """A preset of :data:`BUDGETS` by name."""
    if name not in BUDGETS:
        raise ValueError(f"unknown budget {name!r}; allowed: {', '.join(BUDGETS)}")
    return BUDGETS[name]
