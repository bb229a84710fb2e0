"""The parts an on-policy learner's settings are composed of, beside the network
(:class:`~bimgame.learn.common.NetworkSettings`) and the learner's own optimisation settings:

- :class:`ScheduleSettings`: how long a run goes, on how many processes and environments, and how
  often it checkpoints, evaluates and logs;
- :class:`FinetuneSettings` (optional): the terms that keep a pre-trained π^s while fine-tuning it
  (:mod:`bimgame.learn.finetune`);
- :class:`CurriculumSettings` (optional): where training episodes start (:mod:`bimgame.learn.starts`).

Each part validates its own fields, so a learner that composes it (A3C, and every later one) gets the
same checks and messages. :class:`FlatSettings` is what a composed settings class shares: every
setting has one *flat name* across its parts (``lr``, ``hidden``, ``kl_coef``), the name of its
command-line flag (``--kl-coef``) and of its key in a run's ``config.json``; the settings are built
from flat names and written as flat names, so that every ``config.json`` any version wrote still loads.

A learner's task is the circular maze's or CyberRunner's labyrinth's (:mod:`bimgame.envs.puzzles`):
:func:`check_puzzle` and :func:`refuse_maze_only` refuse, by name, what only the maze has (random
mazes, start curricula, domain randomisation, expert data, reward shaping) and the network parts
made for the maze's state layout (off by default on the labyrinth: :func:`puzzle_defaults`);
:func:`policy_network` builds a run's network for its task's board and
:func:`check_init_puzzle` refuses ``--init`` from the other puzzle's network.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, ClassVar, Literal, Self, get_args

from bimgame.envs.labyrinth_env import OBSERVATION_EXTRAS
from bimgame.envs.puzzles import check_obs, puzzle
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.runs import CONFIG, read_run_config
from bimgame.util.settings import require_int

__all__ = [
    "MAX_STEPS",
    "FINETUNE_PRESETS",
    "DEFAULT_FINETUNE",
    "FINETUNE_FIELDS",
    "StartCurriculum",
    "START_CURRICULA",
    "check_choice",
    "check_number",
    "check_at_most",
    "ScheduleSettings",
    "FinetuneSettings",
    "CurriculumSettings",
    "FlatSettings",
    "MAZE_ONLY",
    "refuse_maze_only",
    "check_expert_data",
    "check_start_curriculum",
    "check_puzzle",
    "puzzle_defaults",
    "policy_network",
    "check_init_puzzle",
]

#: The most environment steps a run (or a checkpoint or evaluation interval) may count: 10¹², about
#: 30 years at this machine's 1,000 steps/s. More is a typo (``--steps 1e30``), found before any work.
MAX_STEPS = 10**12

#: The A3C settings each fine-tuning preset sets (any of them can still be given explicitly).
FINETUNE_PRESETS: dict[str, dict[str, Any]] = {
    "paper": {
        "critic_warmup_steps": 0,
        "actor_ramp_steps": 0,
        "kl_coef": 0.0,
        "kl_decay_steps": 0,
        "kl_temperature": 1.0,
        "bc_coef": 0.0,
        "bc_decay_steps": 0,
        "advantage_norm": False,
        "start_curriculum": "none",
    },
    "keep": {
        "critic_warmup_steps": 50_000,
        "actor_ramp_steps": 100_000,
        "kl_coef": 0.2,
        "kl_decay_steps": 0,
        "kl_temperature": 0.3,
        "bc_coef": 0.0,
        "bc_decay_steps": 0,
        "advantage_norm": True,
        "start_curriculum": "none",
    },
}
#: The preset ``bimgame train --init`` uses unless told otherwise (the one that measured best).
DEFAULT_FINETUNE = "keep"
#: The settings the presets decide.
FINETUNE_FIELDS = tuple(FINETUNE_PRESETS["paper"])


StartCurriculum = Literal["demo", "demo-uniform", "reverse"]
#: Where training episodes start: ``none`` (the task's own starts: no curriculum part), ``demo``
#: (demonstration starts, from ``expert_data``, moving back from the goal), ``demo-uniform`` (the same
#: starts, all of them from the first episode) or ``reverse`` (reverse curriculum, no expert).
START_CURRICULA: tuple[str, ...] = ("none", *get_args(StartCurriculum))
#: The start curricula that start episodes from the expert's states, read from ``expert_data``.
DEMONSTRATION_STARTS: tuple[str, ...] = ("demo", "demo-uniform")


#: Why each maze-only setting (flat names, and the reward-shaping flags' destinations) does not apply
#: to the labyrinth's tasks (:func:`refuse_maze_only`).
MAZE_ONLY = {
    "num_mazes": "random mazes are circular mazes (bimgame.sim.maze_sets)",
    "start_maze": "random mazes are circular mazes (bimgame.sim.maze_sets)",
    "randomize": "domain randomisation varies the maze's physics and camera (bimgame.envs.randomization)",
    "expert_data": "on the labyrinth only demonstration starts (start_curriculum 'demo' or 'demo-uniform') read "
    "the expert's datasets",
    "bc_coef": "behaviour cloning reads windows of the maze expert's datasets (on the labyrinth pre-train π^s "
    "with bimgame pretrain and start from it with --init)",
    "value_reward": "V̂ is a value function of the maze's observations",
    "geodesic_coef": "geodesic shaping follows the maze's distance to its centre",
}


#: Why each of the labyrinth's observation extras (:data:`~bimgame.envs.labyrinth_env.OBSERVATION_EXTRAS`)
#: does not apply to the circular maze's tasks (:func:`check_puzzle`).
LABYRINTH_ONLY = {
    "surroundings": "they are the labyrinth's holes and walls around the marble; the circular maze's state has its "
    "own (num_mazes with gate_bearings)",
    "motion": "it is part of the labyrinth's observations (CyberRunner's velocity, two pixel frames); the circular "
    "maze's state holds the marble's velocity and its pixel networks read one frame",
}


def refuse_maze_only(owner: str, task: str, settings: Mapping[str, bool]) -> None:
    """Raise ``ValueError`` naming the first of ``settings`` (flat name → whether it is set) that is set
    when ``task`` is not the circular maze's, and why it applies to the maze only (:data:`MAZE_ONLY`)."""
    if puzzle(task).is_maze:
        return
    for name, on in settings.items():
        if on:
            raise ValueError(f"{owner}.{name} applies to the circular maze's tasks only, not {task}: {MAZE_ONLY[name]}")


def check_expert_data(owner: str, expert_data: str | None, readers: Mapping[str, bool]) -> None:
    """Raise ``ValueError`` naming the first of ``readers`` (what reads the expert's dataset → whether
    it is on) that is on without ``expert_data``."""
    needed = [name for name, on in readers.items() if on]
    if needed and expert_data is None:
        raise ValueError(f"{owner}.{needed[0]} needs expert_data (an expert dataset directory)")


def check_start_curriculum(
    owner: str, task: str, curriculum: CurriculumSettings | None, expert_data: str | None
) -> None:
    """A start curriculum the task can run: demonstration starts read ``expert_data`` (on the labyrinth
    nothing else does); both curricula run on both puzzles (the labyrinth's along its printed path)."""
    demo = curriculum is not None and curriculum.reads_demonstrations
    refuse_maze_only(owner, task, {"expert_data": expert_data is not None and not demo})
    if curriculum is not None:
        check_expert_data(owner, expert_data, {f"start_curriculum={curriculum.start_curriculum!r}": demo})


def check_puzzle(owner: str, task: str, network: Any, *, num_mazes: int | None, start_maze: int) -> None:
    """Refuse CyberRunner's observation on the maze's ``task`` (:func:`~bimgame.envs.puzzles.check_obs`),
    and what the labyrinth's ``task`` cannot train with: the maze's random mazes (:func:`refuse_maze_only`)
    and the maze's encoding (a part of a network, :class:`~bimgame.learn.common.NetworkSettings`, made for
    the circular maze). Every observation runs on the labyrinth: ``state``, ``pixels`` (its own 84×84
    frames and empty-board background: :mod:`bimgame.learn.pixel_network`; an asymmetric critic reads its
    17 state values, auxiliary heads predict them: :mod:`bimgame.learn.privileged_state`; off by default
    there, :func:`puzzle_defaults`) and ``cyberrunner``."""
    if puzzle(task).is_maze:
        check_obs(f"{owner}.network.obs", task, getattr(network, "obs", ""))
        for name in OBSERVATION_EXTRAS:
            if getattr(network, name, False):
                raise ValueError(f"{owner}.{name} on {task}: {LABYRINTH_ONLY[name]}")
        return
    refuse_maze_only(owner, task, {"num_mazes": num_mazes is not None, "start_maze": bool(start_maze)})
    if getattr(network, "maze_encoding", False):
        raise ValueError(
            f"{owner}.maze_encoding on {task}: the encoding is of a circular maze's walls; leave it off "
            f"(maze_encoding=False)"
        )


def puzzle_defaults(values: Mapping[str, Any], default_task: str) -> dict[str, Any]:
    """The flat settings ``values`` with the defaults that depend on the task's puzzle filled in (the task
    is ``values["task"]``, else ``default_task``): on the labyrinth, ``aux_heads`` not given (None) is
    False — :class:`~bimgame.learn.common.NetworkSettings` turns them on for pixels, where the circular
    maze learns with them; on the labyrinth they are asked for (``--aux-heads``), so that its pixel runs
    keep the network they were measured with and its datasets need no recorded states. An unknown task
    is left for the settings' own check to name."""
    filled = dict(values)
    try:
        labyrinth = not puzzle(filled.get("task", default_task)).is_maze
    except ValueError:
        return filled
    if labyrinth and filled.get("aux_heads") is None:
        filled["aux_heads"] = False
    return filled


def policy_network(config: Any) -> RecurrentActorCritic:
    """A learner's fresh network, initialised from its settings' ``seed``, of its ``network`` settings
    for its ``task``'s board (:attr:`~bimgame.envs.puzzles.Puzzle.spec`: the labyrinth's state has 17
    values, the maze's 7)."""
    network: RecurrentActorCritic = config.network.build_policy(config.seed, puzzle(config.task).spec)
    return network


def check_init_puzzle(init: str | Path | None, task: str) -> None:
    """Refuse ``--init`` from a run on the other puzzle than ``task``'s: its network reads the other's
    observations (a bare checkpoint file names no task: its weights' shapes are checked when loaded)."""
    source = Path(init) if init is not None else None
    run_dir = None if source is None else source.parent if source.is_file() else source
    if run_dir is None or not (run_dir / CONFIG).is_file():
        return
    stored = read_run_config(run_dir)
    block = stored.get("a3c")
    try:
        theirs = puzzle((block if isinstance(block, dict) else stored).get("task", ""))
    except ValueError:
        return  # no task, or an unknown one: reading the run (read_run) says so
    ours = puzzle(task)
    if theirs.family != ours.family:
        raise ValueError(
            f"--init: the network of {init} was trained on {theirs.task} (the {theirs.family}) and reads its "
            f"observations; this run's task {ours.task} is the {ours.family}'s: start it from scratch"
        )


def check_choice(owner: str, name: str, value: Any, allowed: tuple[str, ...], *, optional: bool = False) -> None:
    """Raise unless ``value`` is one of ``allowed`` (or, if ``optional``, None)."""
    if value not in allowed and not (optional and value is None):
        prefix = "None or " if optional else ""
        raise ValueError(f"{owner}.{name} must be {prefix}one of {allowed}, got {value!r}")


def check_number(owner: str, name: str, value: Any, low: float, high: float, *, low_open: bool = False) -> None:
    """Raise unless ``value`` is a real number in [low, high] (finite and above ``low`` if
    ``low_open``; finite if ``high`` is infinite)."""
    ok = isinstance(value, (int, float)) and (math.isfinite(value) or math.isfinite(high))
    ok = ok and (value > low if low_open else value >= low) and value <= high
    if ok:
        return
    if math.isfinite(high):
        raise ValueError(f"{owner}.{name} must be in [{low}, {high}], got {value!r}")
    relation = ">" if low_open else ">="
    raise ValueError(f"{owner}.{name} must be a finite number {relation} {low:g}, got {value!r}")


def check_at_most(owner: str, name: str, value: Any, largest: int, unit: str) -> None:
    """Raise if ``value`` (an already checked integer or None) exceeds ``largest``: settings that size
    what is allocated at once, where a far larger value is a typo that would otherwise fail only when
    memory runs out."""
    if value is not None and value > largest:
        raise ValueError(f"{owner}.{name} must be at most {largest:,} ({unit}), got {value!r}")


@dataclasses.dataclass(frozen=True)
class ScheduleSettings:
    """How long a run goes and on how many processes and environments, and how often it checkpoints,
    evaluates and logs."""

    steps: int = 5_000_000
    """Environment steps to train for (all workers together)."""
    workers: int = 2
    """Worker processes (one thread each)."""
    envs_per_worker: int = 16
    """Environments per worker, stepped as one batch (one forward pass acts for all); 1 is exactly
    the paper's A3C. Batching is what makes the network affordable on a CPU: one LSTM step costs
    about the same for 1 environment as for 16."""
    checkpoint_every: int = 100_000
    """Environment steps between checkpoints (``--resume`` loses at most this many)."""
    eval_every: int = 100_000
    """Environment steps between evaluations; 0 disables the evaluator process."""
    eval_episodes: int = 10
    """Episodes per evaluation, each greedy and sampled."""
    log_every: int = 2_000
    """Environment steps (per worker) between loss reports."""

    def __post_init__(self) -> None:
        owner = type(self).__name__
        for name in ("steps", "workers", "envs_per_worker", "checkpoint_every", "eval_episodes", "log_every"):
            require_int(owner, name, getattr(self, name), 1)
        if not (isinstance(self.eval_every, int) and self.eval_every >= 0):
            raise ValueError(f"{owner}.eval_every must be an integer >= 0 (0: no evaluator), got {self.eval_every!r}")
        for name in ("steps", "checkpoint_every", "eval_every", "log_every"):
            check_at_most(owner, name, getattr(self, name), MAX_STEPS, "1e12 environment steps")
        check_at_most(owner, "workers", self.workers, 256, "processes")
        check_at_most(owner, "envs_per_worker", self.envs_per_worker, 4096, "environments in one process")
        check_at_most(owner, "eval_episodes", self.eval_episodes, 10_000, "episodes run side by side")


@dataclasses.dataclass(frozen=True)
class FinetuneSettings:
    """Fine-tuning a pre-trained π^s without forgetting it: each term addresses one cause of the
    forgetting measured in ``docs/finetune/README.md`` (see :mod:`bimgame.learn.finetune`)."""

    finetune: str | None = None
    """Fine-tuning preset these settings started from (``paper``: plain fine-tuning, which forgets;
    ``keep``: the default with ``--init``); None: none (a run from scratch). See
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
    bc_coef: float = 0.0
    """Fine-tuning (DAPG): initial weight of the cross-entropy to the expert's actions on windows of
    ``expert_data``."""
    bc_decay_steps: int = 0
    """Steps over which the behaviour-cloning weight decays linearly to zero (0: constant)."""

    def __post_init__(self) -> None:
        owner = type(self).__name__
        check_choice(owner, "finetune", self.finetune, tuple(FINETUNE_PRESETS), optional=True)
        for name in ("critic_warmup_steps", "actor_ramp_steps", "kl_decay_steps", "bc_decay_steps"):
            require_int(owner, name, getattr(self, name), 0)
        check_number(owner, "kl_temperature", self.kl_temperature, 0.0, math.inf, low_open=True)
        for name in ("kl_coef", "bc_coef"):
            check_number(owner, name, getattr(self, name), 0.0, math.inf)
        if not isinstance(self.advantage_norm, bool):
            raise ValueError(f"{owner}.advantage_norm must be True or False, got {self.advantage_norm!r}")

    @property
    def changes_nothing(self) -> bool:
        """Whether these settings are a run from scratch's (no preset, every term off): such a run has
        no fine-tuning part."""
        return self == FinetuneSettings()

    @property
    def schedules_actor(self) -> bool:
        """Whether the actor's learning rate follows a schedule (critic warm-up or actor ramp): the
        policy head then has its own optimiser parameter group."""
        return self.critic_warmup_steps > 0 or self.actor_ramp_steps > 0


@dataclasses.dataclass(frozen=True)
class CurriculumSettings:
    """A start curriculum: training episodes start closer to the goal, moving back as success grows.
    Evaluations always use the task's own starts."""

    start_curriculum: StartCurriculum = "demo"
    """Where training episodes start: ``none`` (the task's own starts), ``demo`` (states of the
    expert's episodes, moving back from the goal as success grows), ``demo-uniform`` (every state of
    the expert's episodes from the first episode on, drawn uniformly: reference state initialisation,
    Peng et al. 2018, DeepMimic) or ``reverse`` (grown backwards from the goal by random exploration,
    no expert). Evaluations always use the task's own starts."""
    curriculum_threshold: float = 0.8
    """Start curricula: success on the current starts that moves them further from the goal (with
    ``demo-uniform``: that ends the curriculum, every episode then starting from the task's own start)."""

    def __post_init__(self) -> None:
        owner = type(self).__name__
        check_choice(owner, "start_curriculum", self.start_curriculum, get_args(StartCurriculum))
        threshold = self.curriculum_threshold
        if not (isinstance(threshold, (int, float)) and not isinstance(threshold, bool) and 0 < threshold <= 1):
            raise ValueError(f"{owner}.curriculum_threshold must be in (0, 1], got {threshold!r}")

    @property
    def reads_demonstrations(self) -> bool:
        """Whether training episodes start from the expert's states (read from ``expert_data``)."""
        return self.start_curriculum in DEMONSTRATION_STARTS


class FlatSettings:
    """What a settings class composed of parts shares: its flat names, and building it from them and
    writing it as them. A subclass is a frozen dataclass whose fields are its own settings and its
    parts; :attr:`PARTS` names each part's field and class, :attr:`OPTIONAL_PARTS` those that may be
    None, with the flat value that stands for None (``start_curriculum="none"``) in
    :attr:`NONE_VALUES`. Flat names are unique across the parts."""

    PARTS: ClassVar[dict[str, type]] = {}
    OPTIONAL_PARTS: ClassVar[frozenset[str]] = frozenset()
    NONE_VALUES: ClassVar[dict[str, Any]] = {}
    #: The flat settings a resumed run may change without changing what is being learned.
    RESUMABLE_CHANGES: ClassVar[tuple[str, ...]] = ()
    #: What a settings dict of this class is called in errors ("unknown A3C settings [...]").
    SETTINGS_NAME: ClassVar[str] = "settings"

    @classmethod
    def own_names(cls) -> tuple[str, ...]:
        """The flat names of the settings the class holds itself (not in a part)."""
        return tuple(f.name for f in dataclasses.fields(cls) if f.name not in cls.PARTS)  # type: ignore[arg-type]

    @classmethod
    def name_groups(cls) -> Iterator[tuple[type, tuple[str, ...]]]:
        """(class, flat names) of the class's own settings, then of each part, in field order."""
        yield cls, cls.own_names()
        for part in cls.PARTS.values():
            yield part, tuple(f.name for f in dataclasses.fields(part))

    @classmethod
    def flat_names(cls) -> tuple[str, ...]:
        """Every flat name, the class's own first, then each part's."""
        return tuple(name for _, names in cls.name_groups() for name in names)

    @classmethod
    def from_flat(cls, values: Mapping[str, Any] | None = None, /, **more: Any) -> Self:
        """The settings from flat names (``{"lr": 1e-3, "obs": "state", …}``: the command line's flags,
        a reproduction's overrides, the ``config.json`` of every version); unknown names are an error
        naming them and the allowed ones. An optional part whose settings are all at their "none"
        values is None."""
        given = {**(values or {}), **more}
        unknown = sorted(set(given) - set(cls.flat_names()))
        if unknown:
            raise ValueError(f"unknown {cls.SETTINGS_NAME} {unknown}; allowed: {sorted(cls.flat_names())}")
        if {"task", "aux_heads"} <= set(cls.flat_names()):
            given = puzzle_defaults(given, getattr(cls, "task", ""))  # a dataclass's class attribute: its default
        arguments: dict[str, Any] = {name: given[name] for name in cls.own_names() if name in given}
        for field, part in cls.PARTS.items():
            names = [f.name for f in dataclasses.fields(part)]
            part_values = {name: given[name] for name in names if name in given}
            if field in cls.OPTIONAL_PARTS and cls._means_none(part, part_values):
                part(**{k: v for k, v in part_values.items() if k not in cls.NONE_VALUES})  # checked all the same
                arguments[field] = None
            else:
                arguments[field] = cls._part_from(field, part, part_values)
        return cls(**arguments)

    @classmethod
    def _part_from(cls, field: str, part: type, values: dict[str, Any]) -> Any:
        """The part ``field`` with the flat ``values`` given; the others take this class's default for
        the part when it declares one other than the part class's own (PPO's one-process schedule)."""
        factory = {f.name: f for f in dataclasses.fields(cls)}[field].default_factory  # type: ignore[arg-type]
        if factory is dataclasses.MISSING or factory is part:
            return part(**values)
        return dataclasses.replace(factory(), **values)

    @classmethod
    def _means_none(cls, part: type, values: Mapping[str, Any]) -> bool:
        """Whether an optional part's flat values stand for no part. A part with a "none" value (a
        curriculum: ``start_curriculum="none"``) is absent unless another value is given for that
        setting (its other settings, still checked, then mean nothing and are dropped); a part without one (fine-tuning)
        is absent when every value is at its default."""
        markers = [name for name in cls.NONE_VALUES if name in {f.name for f in dataclasses.fields(part)}]
        if markers:
            return all(values.get(name, cls.NONE_VALUES[name]) == cls.NONE_VALUES[name] for name in markers)
        defaults = part()
        return all(getattr(defaults, name) == value for name, value in values.items())

    def to_dict(self) -> dict[str, Any]:
        """Every setting by its flat name (what ``config.json`` stores); an absent optional part is
        written as its defaults, with its "none" values."""
        flat = {name: getattr(self, name) for name in self.own_names()}
        for field, part in self.PARTS.items():
            value = getattr(self, field)
            if value is not None:
                flat.update(dataclasses.asdict(value))
                continue
            for f in dataclasses.fields(part):
                flat[f.name] = self.NONE_VALUES.get(f.name, f.default)
        return flat

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> Self:
        """The settings of :meth:`to_dict`'s values (see :meth:`from_flat`)."""
        return cls.from_flat(values)

    def with_flat(self, **changes: Any) -> Self:
        """These settings with the given flat settings changed."""
        return self.from_flat({**self.to_dict(), **changes})

    def check_parts(self) -> None:
        """Raise unless each part is an instance of its class (or None, where it is optional)."""
        owner = type(self).__name__
        for name, part in self.PARTS.items():
            value = getattr(self, name)
            if not (isinstance(value, part) or (value is None and name in self.OPTIONAL_PARTS)):
                allowed = f"None or a {part.__name__}" if name in self.OPTIONAL_PARTS else f"a {part.__name__}"
                raise ValueError(f"{owner}.{name} must be {allowed}, got {value!r}")

    def check_resumable_from(self, previous: FlatSettings) -> None:
        """Refuse to resume a run stored with ``previous`` settings with these, unless only
        :attr:`RESUMABLE_CHANGES` differ; the message names each change."""
        before, now = previous.to_dict(), self.to_dict()
        changed = [name for name in now if before[name] != now[name] and name not in self.RESUMABLE_CHANGES]
        if changed:
            raise ValueError(
                "--resume must keep the run's settings; changed: "
                + ", ".join(f"{k} ({before[k]!r} -> {now[k]!r})" for k in changed)
                + f". Allowed to change: {', '.join(self.RESUMABLE_CHANGES)}"
            )
