"""The algorithms a reproduction compares: one :class:`Algorithm` record each — its name, its label
in figures and tables, what its runs need (π^s, V̂, the expert's dataset), which learner runs it and
the settings that make it what it is — kept in one registry, in the order of the report.

Everything else of the reproduction asks a record instead of reading meaning from a name: the grid
(:mod:`bimgame.experiments.grid`) which pieces a run needs, the runners
(:mod:`bimgame.experiments.runners`) which settings, initial weights and reward it gets, the report
(:mod:`bimgame.experiments.report`) which comparisons and sections it has.

**Adding an algorithm** is one :func:`register` call with its record (and, for a new kind of
learner, a :class:`~bimgame.experiments.kinds.RunKind` for its pieces); the budget, the grid, the
runs, the figures and the report then take it. The built-in records below are registered when this
module is imported, in the order of the paper's figures, then the fine-tuning methods beyond it,
then PPO's (last, so that the other algorithms keep their colours in figures).

**PPO.** ``ppo`` and ``pretrain+ppo`` are the paper's comparison of a start from random weights
with a start from π^s, run by PPO (:mod:`bimgame.learn.ppo`) instead of A3C: the same budget of
environment steps per task, the same evaluations, and ``pretrain+ppo`` starts from the very π^s
piece ``pretrain+a3c`` starts from (one per task and seed, pre-trained once). Their runs are
pieces of their own kind (``ppo``); their settings are the budget's ``ppo`` group.

**A3C settings.** The paper's A3C algorithms differ only in their initial weights and reward; the
methods beyond it differ in their fine-tuning settings (:mod:`bimgame.learn.finetune`). Every
method is the ``paper`` preset (plain fine-tuning, every method off) with the one method it tests
turned on, taking its values from the ``keep`` preset — so an ablation measures exactly the method
the ``keep`` combination uses. The values are read from
:data:`~bimgame.learn.finetune.FINETUNE_PRESETS` each time a run is planned, never copied: a change
of a preset changes the runs planned after it. ``pretrain+a3c`` records the ``paper`` preset
(``finetune="paper"``), whose settings are A3C's defaults: its runs compute what they did before
the presets existed.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Callable, Iterator, Mapping
from typing import Any

from bimgame.learn.learner_settings import DEMONSTRATION_STARTS, FINETUNE_PRESETS

__all__ = [
    "Learner",
    "LEARNER_CAPABILITIES",
    "Algorithm",
    "reads_expert_data",
    "register",
    "unregister",
    "algorithm_named",
    "registered",
    "algorithm_names",
    "LABELS",
    "BC_COEF",
    "KEEPFADE_FRACTION",
    "BASELINE",
    "A3C",
    "PRETRAIN_A3C",
    "A3C_VALUE",
    "PRETRAIN_A3C_VALUE",
    "DAGGER",
    "PPO",
    "PRETRAIN_PPO",
]


class Learner(enum.Enum):
    """The learner that runs an algorithm; its value is the kind of the algorithm's run pieces
    (:mod:`bimgame.experiments.kinds`)."""

    A3C = "a3c"
    """:func:`bimgame.learn.a3c.train`: runs of a budgeted number of environment steps."""
    DAGGER = "dagger"
    """:func:`bimgame.learn.dagger.dagger` with the MPC expert: runs of a budgeted number of iterations."""
    PPO = "ppo"
    """:func:`bimgame.learn.ppo.train_ppo`: runs of the same budgeted number of environment steps as A3C's."""


#: What a record may ask of each learner's runs: ``settings`` (the learner's flat settings beyond
#: the budget's), ``starts_from_policy`` (initial weights from π^s) and ``value_reward`` (V̂'s reward,
#: an environment wrapper only A3C's runs take). A DAgger run is its budget group and nothing else.
LEARNER_CAPABILITIES: dict[Learner, frozenset[str]] = {
    Learner.A3C: frozenset({"settings", "starts_from_policy", "value_reward"}),
    Learner.PPO: frozenset({"settings", "starts_from_policy"}),
    Learner.DAGGER: frozenset(),
}
#: The learners whose runs take the budget's environment steps per task (``a3c.steps``).
_BY_STEPS = frozenset({Learner.A3C, Learner.PPO})

#: A learner's settings (flat name → value) of a run, as a function of the run's environment steps.
Settings = Callable[[int], dict[str, Any]]


def _none(steps: int) -> dict[str, Any]:
    """No settings beyond the budget's."""
    return {}


@dataclasses.dataclass(frozen=True)
class Algorithm:
    """One compared algorithm: what it is called, what its runs need and how they are run."""

    name: str
    """Its name in budgets, on the command line and in ``plan.json`` (``+`` joins the parts)."""
    label: str
    """Its name in figures and tables."""
    learner: Learner = Learner.A3C
    """The learner that runs it (and so the kind of its run pieces)."""
    starts_from_policy: bool = False
    """Its runs start from the π^s pre-trained on the expert's dataset (the grid pre-trains it)."""
    value_reward: bool = False
    """Its runs are rewarded with r + γV̂(s') − V̂(s), V̂ pre-trained on the dataset (the grid pre-trains it)."""
    settings: Settings = _none
    """A3C and PPO: the settings (its learner's flat names) its runs set beyond the budget's, for a run
    of the given steps (read at planning time, so that they follow the presets of
    :mod:`bimgame.learn.finetune`)."""
    paper: bool = False
    """One of the paper's compared methods (the presets' default grid)."""
    finetuning: bool = False
    """A method of fine-tuning π^s beyond the paper: a grid with one has the report's section on
    keeping π^s."""
    without_value_reward: str | None = None
    """For a value-reward algorithm: the algorithm with the same start and no value reward, which the
    report compares it with."""

    def __post_init__(self) -> None:
        if not (isinstance(self.name, str) and self.name and self.name.strip() == self.name):
            raise ValueError(f"Algorithm.name must be a non-empty name without surrounding spaces, got {self.name!r}")
        if not isinstance(self.learner, Learner):
            raise ValueError(
                f"Algorithm.learner must be one of {', '.join(str(m) for m in Learner)}, got {self.learner!r}"
            )
        asked = [
            name
            for name, given in (
                ("settings", self.settings is not _none),
                ("starts_from_policy", self.starts_from_policy),
                ("value_reward", self.value_reward),
            )
            if given and name not in LEARNER_CAPABILITIES[self.learner]
        ]
        if asked:
            allowed = "; ".join(
                f"{learner.value}: {', '.join(sorted(can)) or 'none'}" for learner, can in LEARNER_CAPABILITIES.items()
            )
            raise ValueError(
                f"{self.name}: {self.learner.value} runs take no {', '.join(asked)}; what each learner's runs "
                f"take — {allowed}"
            )

    @property
    def slug(self) -> str:
        """Its directory name (``pretrain+a3c+value`` → ``pretrain-a3c-value``)."""
        return self.name.replace("+", "-")

    @property
    def trains_by_steps(self) -> bool:
        """Whether its runs take the budget's environment steps per task (``a3c.steps``: A3C's and
        PPO's runs, the same budget for both)."""
        return self.learner in _BY_STEPS

    def run_settings(self, steps: int) -> dict[str, Any]:
        """The settings (its learner's flat names) its runs of ``steps`` environment steps set beyond
        the budget's; {} for a learner that takes none."""
        return dict(self.settings(steps))

    def a3c_settings(self, steps: int) -> dict[str, Any]:
        """The A3C settings its runs of ``steps`` environment steps set beyond the budget's."""
        if self.learner is not Learner.A3C:
            raise ValueError(f"{self.name} is not an A3C run (its learner is {self.learner.value})")
        return self.run_settings(steps)

    @property
    def needs_expert_data(self) -> bool:
        """Whether its runs read the expert's dataset (a behaviour-cloning term or demonstration
        starts), so they need the dataset piece; DAgger's data come from the expert it queries."""
        return reads_expert_data(self.run_settings(1))

    @property
    def start_curriculum(self) -> bool:
        """Whether its training episodes start elsewhere than the task's own starts: their training
        success is then not the task's, only their evaluations are."""
        return self.run_settings(1).get("start_curriculum", "none") != "none"


def reads_expert_data(settings: Mapping[str, Any]) -> bool:
    """Whether a learner's settings read an expert dataset (a behaviour-cloning term or demonstration starts)."""
    return settings.get("bc_coef", 0.0) > 0 or settings.get("start_curriculum", "none") in DEMONSTRATION_STARTS


_REGISTRY: dict[str, Algorithm] = {}


def register(algorithm: Algorithm) -> Algorithm:
    """Add ``algorithm`` to the registry (after the ones there); returns it. A name already taken,
    or a comparison with an unregistered algorithm, is a ValueError."""
    if not isinstance(algorithm, Algorithm):
        raise TypeError(f"register takes an Algorithm, got {type(algorithm).__name__}")
    if algorithm.name in _REGISTRY:
        raise ValueError(
            f"an algorithm named {algorithm.name!r} is registered already; registered: {', '.join(_REGISTRY)}"
        )
    if algorithm.without_value_reward is not None and algorithm.without_value_reward not in _REGISTRY:
        raise ValueError(
            f"{algorithm.name}: without_value_reward {algorithm.without_value_reward!r} is not "
            f"registered; registered: {', '.join(_REGISTRY)}"
        )
    _REGISTRY[algorithm.name] = algorithm
    return algorithm


def unregister(name: str) -> None:
    """Remove the algorithm ``name`` (for algorithms registered for a while, as by a test)."""
    algorithm_named(name)
    del _REGISTRY[name]


def algorithm_named(name: str) -> Algorithm:
    """The registered algorithm ``name``; a ValueError listing the registered ones otherwise."""
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown algorithm {name!r}; registered: {', '.join(_REGISTRY)}") from None


def registered() -> tuple[Algorithm, ...]:
    """Every registered algorithm, in registration order (the order of grids, figures and tables)."""
    return tuple(_REGISTRY.values())


def algorithm_names() -> tuple[str, ...]:
    """The names of :func:`registered`."""
    return tuple(_REGISTRY)


class _Labels(Mapping[str, str]):
    """Algorithm name → label, read from the registry each time (so it holds registered algorithms)."""

    def __getitem__(self, name: str) -> str:
        if name not in _REGISTRY:
            raise KeyError(name)
        return _REGISTRY[name].label

    def __iter__(self) -> Iterator[str]:
        return iter(tuple(_REGISTRY))

    def __len__(self) -> int:
        return len(_REGISTRY)


#: The algorithms' names in figures and tables (a live view of the registry).
LABELS: Mapping[str, str] = _Labels()


# ------------------------------------------------------------------------------- the settings
#: ``pretrain+a3c+bc``: initial weight of the behaviour-cloning term (it decays to zero over the run).
BC_COEF = 0.1
#: ``pretrain+a3c+keepfade``: the ``keep`` preset with its KL weight fading to zero over the first
#: 1/KEEPFADE_FRACTION of the run, for π^s that are weak on the task (as from pixels), which a
#: constant KL would hold the policy near; ``keep`` itself keeps it constant, since once a fading KL
#: reaches zero π^s can be forgotten (measurements: ``docs/budgets.md``).
KEEPFADE_FRACTION = 3


def _preset(name: str, **changes: Any) -> dict[str, Any]:
    """The settings of fine-tuning preset ``name`` (its name recorded), with ``changes``."""
    return {**FINETUNE_PRESETS[name], "finetune": name, **changes}


def _paper_with_keep(*fields: str) -> dict[str, Any]:
    """Plain fine-tuning with the ``keep`` preset's values of ``fields`` (one method turned on)."""
    return _preset("paper", **{field: FINETUNE_PRESETS["keep"][field] for field in fields})


# ------------------------------------------------------------------------------- the built-in records
A3C = register(Algorithm("a3c", "A3C", paper=True))
"""A3C from random weights."""
BASELINE = A3C
"""The algorithm the report's speed-ups are over (``speedup_vs_<name>``)."""
PRETRAIN_A3C = register(
    Algorithm(
        "pretrain+a3c", "pre-train + A3C", starts_from_policy=True, paper=True, settings=lambda steps: _preset("paper")
    )
)
"""A3C starting from π^s, pre-trained on the expert's dataset (plain fine-tuning)."""
A3C_VALUE = register(
    Algorithm("a3c+value", "A3C + value reward", value_reward=True, paper=True, without_value_reward=A3C.name)
)
"""A3C from random weights on r + γV̂(s') − V̂(s)."""
PRETRAIN_A3C_VALUE = register(
    Algorithm(
        "pretrain+a3c+value",
        "pre-train + A3C + value reward",
        starts_from_policy=True,
        value_reward=True,
        paper=True,
        without_value_reward=PRETRAIN_A3C.name,
    )
)
"""Both: A3C from π^s on the value reward."""
DAGGER = register(Algorithm("dagger", "DAgger", learner=Learner.DAGGER, paper=True))
"""DAgger with the MPC expert, from random weights."""
register(
    Algorithm(
        "pretrain+a3c+warmup",
        "pre-train + A3C + critic warm-up",
        starts_from_policy=True,
        finetuning=True,
        settings=lambda steps: _paper_with_keep("critic_warmup_steps", "actor_ramp_steps"),
    )
)
"""Critic warm-up, then the actor's learning rate ramped up."""
register(
    Algorithm(
        "pretrain+a3c+kl",
        "pre-train + A3C + KL",
        starts_from_policy=True,
        finetuning=True,
        settings=lambda steps: _paper_with_keep("kl_coef", "kl_decay_steps", "kl_temperature"),
    )
)
"""Kickstarting: an annealed KL(π^s ‖ π)."""
register(
    Algorithm(
        "pretrain+a3c+norm",
        "pre-train + A3C + advantage norm.",
        starts_from_policy=True,
        finetuning=True,
        settings=lambda steps: _preset("paper", advantage_norm=True),
    )
)
"""Advantages divided by their running RMS."""
register(
    Algorithm(
        "pretrain+a3c+bc",
        "pre-train + A3C + BC (DAPG)",
        starts_from_policy=True,
        finetuning=True,
        settings=lambda steps: _preset("paper", bc_coef=BC_COEF, bc_decay_steps=steps),
    )
)
"""A behaviour-cloning term on the expert's dataset, decaying over the run (DAPG)."""
register(
    Algorithm(
        "pretrain+a3c+demo",
        "pre-train + A3C + demo starts",
        starts_from_policy=True,
        finetuning=True,
        settings=lambda steps: _preset("paper", start_curriculum="demo"),
    )
)
"""Episodes start from the expert's states, moving back from the goal."""
register(
    Algorithm(
        "pretrain+a3c+keep",
        "pre-train + A3C, keep preset",
        starts_from_policy=True,
        finetuning=True,
        settings=lambda steps: _preset("keep"),
    )
)
"""The ``keep`` preset (the combination ``bimgame train --init`` uses)."""
register(
    Algorithm(
        "pretrain+a3c+keepfade",
        "pre-train + A3C, keep, fading KL",
        starts_from_policy=True,
        finetuning=True,
        settings=lambda steps: _preset("keep", kl_decay_steps=max(1, steps // KEEPFADE_FRACTION)),
    )
)
"""The ``keep`` preset with the KL weight fading to zero over the first third of the run."""
register(
    Algorithm(
        "a3c+reverse",
        "A3C + reverse curriculum",
        finetuning=True,
        settings=lambda steps: {"start_curriculum": "reverse"},
    )
)
"""From random weights, a reverse start curriculum (no expert, no π^s)."""
register(
    Algorithm(
        "a3c+papernet",
        "A3C, the paper's network",
        settings=lambda steps: {"aux_heads": False, "asymmetric_critic": False, "augment_shift": 0},
    )
)
"""A3C with the paper's exact network whatever the budget's levers (no auxiliary heads or privileged
critic, no augmentation), shown beside the improved one when the levers are on."""
PPO = register(Algorithm("ppo", "PPO", learner=Learner.PPO))
"""PPO from random weights, on the same steps per task as A3C."""
PRETRAIN_PPO = register(Algorithm("pretrain+ppo", "pre-train + PPO", learner=Learner.PPO, starts_from_policy=True))
"""PPO starting from π^s — the same π^s piece ``pretrain+a3c`` starts from — with PPO's own settings
(plain fine-tuning)."""
#: The ``keep`` preset's settings PPO takes: its KL to π^s (PPO has no critic warm-up or actor ramp,
#: and normalises every minibatch's advantages already).
PPO_KEEP_FIELDS = ("kl_coef", "kl_decay_steps", "kl_temperature")
register(
    Algorithm(
        "pretrain+ppo+keep",
        "pre-train + PPO, keep's KL",
        learner=Learner.PPO,
        starts_from_policy=True,
        finetuning=True,
        settings=lambda steps: {field: FINETUNE_PRESETS["keep"][field] for field in PPO_KEEP_FIELDS},
    )
)
"""PPO from π^s with the ``keep`` preset's KL(π^s ‖ π) (weight and temperature read from the preset)."""
