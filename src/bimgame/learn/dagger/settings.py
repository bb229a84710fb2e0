"""The settings of a DAgger run (:mod:`bimgame.learn.dagger`): its learner, iterations, β schedule,
expert and evaluation, checked when made; and the settings a new or resumed run goes with.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from bimgame.envs.puzzles import puzzle
from bimgame.expert.labyrinth_mpc import LabyrinthMPCConfig
from bimgame.expert.mpc import MPCConfig
from bimgame.learn.maze_runs import check_off_path_rule, maze_network, network_env_options, run_rules
from bimgame.learn.policy_heads import require_discrete
from bimgame.learn.run_dir import stored_run_config
from bimgame.learn.runs import KIND_DAGGER, read_run_settings
from bimgame.learn.supervised import PretrainConfig
from bimgame.util.settings import from_dict, is_real, require_int

__all__ = ["DAggerConfig", "resolve_dagger_config"]

#: Typo guards on what runs side by side (each rollout has its own simulator and expert).
_LARGEST = {
    "episodes_per_iteration": (10_000, "rollouts run side by side"),
    "eval_episodes": (10_000, "episodes run side by side"),
    "max_episode_steps": (10**9, "steps"),
}


def _expert_type(task: str) -> type[MPCConfig] | type[LabyrinthMPCConfig]:
    """The settings class of ``task``'s puzzle's expert."""
    return MPCConfig if puzzle(task).is_maze else LabyrinthMPCConfig


@dataclasses.dataclass(frozen=True)
class DAggerConfig:
    """Settings of a DAgger run; the network and its loss are ``learner``'s (a
    :class:`~bimgame.learn.supervised.PretrainConfig`: task, observations, sizes, lr, L2, γ). On the
    labyrinth the learner may have auxiliary heads or an asymmetric critic: its rollouts then record
    each step's state observation, which they learn from; on the circular maze it has neither.

    Either puzzle: on the circular maze the expert is :class:`~bimgame.expert.mpc.RandomShootingMPC`
    (``expert`` an :class:`~bimgame.expert.mpc.MPCConfig`, discrete actions only); on the labyrinth
    :class:`~bimgame.expert.labyrinth_mpc.LabyrinthMPC` (``expert`` a
    :class:`~bimgame.expert.labyrinth_mpc.LabyrinthMPCConfig``), labelling in the learner's kind of
    action, continuous or discrete. ``expert`` None: the puzzle's default expert — on random mazes
    (``num_mazes``) the maze expert planning with the geodesic reward, which solves 98–99% of held-out
    mazes where the radial one solves 86–97% (``benchmarks/results/expert_mazes.json``)."""

    learner: PretrainConfig = dataclasses.field(
        default_factory=lambda: PretrainConfig(task="STG1", aux_heads=False, asymmetric_critic=False)
    )
    iterations: int = 10
    """Iterations to run (roll out, label, aggregate, retrain)."""
    episodes_per_iteration: int = 20
    """Learner rollouts per iteration, run side by side."""
    beta0: float = 1.0
    """Probability of executing the expert's action in iteration 0 (1: behaviour cloning data)."""
    beta_decay: float = 0.5
    """β_i = beta0 · beta_decay^i."""
    epochs_per_iteration: int = 10
    """Passes over the aggregated dataset after each iteration."""
    expert: MPCConfig | LabyrinthMPCConfig | None = None
    """The expert's settings; None: the task's puzzle's defaults (filled in when made)."""
    expert_data: str | None = None
    """An expert dataset directory (``bimgame generate``) of the task whose episodes start the
    aggregated dataset D, before the first rollout: DAgger from the demonstrations π^s learned from."""
    demo_start_share: float = 0.0
    """On the labyrinth, the share of each iteration's rollouts that start in a physics state of the
    expert's successful episodes in ``expert_data`` (drawn uniformly over all their states,
    :mod:`bimgame.learn.dagger.starts`) instead of at the layout's start: the expert then labels the
    learner's own states along the whole path, not only as far as its runs from the start get."""
    demo_start_window: tuple[float, float] = (0.0, 1.0)
    """The part of the path, from and to as fractions of its length, whose expert states the
    ``demo_start_share`` rollouts start from (default: the whole path). A window just before where the
    learner loses the marble has the expert label the learner's own states there: on the hard layout
    the best policies lose it at a few passages beside holes (22–24% and 30% of the path), which
    rollouts from the layout's start reach only as often as the learner gets that far."""
    max_episode_steps: int | None = None
    """Time limit of the rollouts; None: the task's."""
    stall_steps: int | None = None
    """On the labyrinth, end a rollout once its progress along the path has not passed its best by
    :data:`~bimgame.learn.dagger.rollouts.STALL_PROGRESS_M` for this many steps (None: run to the time
    limit). A learner that has learned to hold the marble still otherwise has the expert label the
    same few states up to the time limit: on the hard layout one such iteration of 10 rollouts took
    18,049 labels (67 min of planning), against 0.9–3.7k for each iteration before it."""
    teacher: str | None = None
    """On the labyrinth, a trained policy (its run directory or a checkpoint in one, of the learner's
    layout and kind of action) that labels the rollouts with its greedy actions instead of the MPC
    expert (:mod:`bimgame.learn.dagger.teacher`): a state policy teaching a pixel learner. ``expert``
    then goes unused; ``expert_data`` still starts D with the MPC expert's episodes."""
    eval_episodes: int = 20
    """Greedy and sampled evaluation episodes after every iteration (0: none)."""
    num_mazes: int | None = None
    """Roll out (and evaluate) on random mazes (:mod:`bimgame.sim.maze_sets`), as a learner's
    ``num_mazes``: this many training mazes from ``start_maze`` on, one drawn per episode; 0: unlimited.
    The expert plans on each episode's maze; a state learner reads the maze encoding. None: MERL's maze."""
    start_maze: int = 0
    """The first training maze's number (with ``num_mazes``)."""
    off_path_rule: str | None = None
    """The labyrinth only: when its rollouts and evaluations end off the path, as a learner's
    ``off_path_rule`` (``tolerance`` or ``cyberrunner``; None: the env's default, ``tolerance``)."""

    def __post_init__(self) -> None:
        """Refuse settings DAgger cannot run with, naming the setting."""
        if self.learner.target != "policy":
            raise ValueError("DAggerConfig.learner must train a policy (target='policy')")
        maze = puzzle(self.learner.task).is_maze
        self._check_mazes()
        check_off_path_rule("DAggerConfig", self.learner.task, self.off_path_rule)
        expert_type = _expert_type(self.learner.task)
        if self.expert is None:
            default = MPCConfig(reward="geodesic") if self.num_mazes is not None else expert_type()
            object.__setattr__(self, "expert", default)
        elif not isinstance(self.expert, expert_type):
            raise ValueError(
                f"DAggerConfig.expert on task {self.learner.task} must be {expert_type.__name__} (the "
                f"{'circular maze' if maze else 'labyrinth'}'s expert settings) or None, "
                f"got {type(self.expert).__name__}"
            )
        if maze:
            require_discrete("DAgger", self.learner.action_type, "the maze expert's labels are discrete actions")
        if self.expert_data is not None and not (isinstance(self.expert_data, str) and self.expert_data):
            raise ValueError(f"DAggerConfig.expert_data must be a dataset directory or None, got {self.expert_data!r}")
        if maze and (self.learner.aux_heads or self.learner.asymmetric_critic):
            raise ValueError(
                "DAggerConfig.learner must have aux_heads=False and asymmetric_critic=False on the circular "
                "maze: its rollouts record no state observations (the labyrinth's do)"
            )
        for name in ("iterations", "episodes_per_iteration", "epochs_per_iteration"):
            require_int("DAggerConfig", name, getattr(self, name), 1)
        for name in ("beta0", "beta_decay"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0.0 <= value <= 1.0):
                raise ValueError(f"DAggerConfig.{name} must be in [0, 1], got {value!r}")
        self._check_demo_starts(maze)
        require_int("DAggerConfig", "stall_steps", self.stall_steps, 1, optional=True)
        if self.stall_steps is not None and maze:
            raise ValueError(
                "DAggerConfig.stall_steps: ending rollouts that stop progressing along the path is the "
                f"labyrinth's (tasks LABYRINTH-EASY/-MEDIUM/-HARD), not {self.learner.task}'s; leave it unset"
            )
        self._check_teacher(maze)
        require_int("DAggerConfig", "eval_episodes", self.eval_episodes, 0)
        require_int("DAggerConfig", "max_episode_steps", self.max_episode_steps, 1, optional=True)
        for name, (largest, unit) in _LARGEST.items():
            value = getattr(self, name)
            if value is not None and value > largest:
                raise ValueError(f"DAggerConfig.{name} must be at most {largest:,} ({unit}), got {value!r}")

    def _check_demo_starts(self, maze: bool) -> None:
        """Refuse a ``demo_start_share`` outside [0, 1], on the circular maze, or without the dataset
        whose states it starts from."""
        share = self.demo_start_share
        if not (is_real(share) and 0.0 <= share <= 1.0):
            raise ValueError(f"DAggerConfig.demo_start_share must be a number in [0, 1], got {share!r}")
        window = self.demo_start_window
        if not (
            isinstance(window, (tuple, list))
            and len(window) == 2
            and all(is_real(end) for end in window)
            and 0.0 <= window[0] < window[1] <= 1.0
        ):
            raise ValueError(
                "DAggerConfig.demo_start_window must be two fractions of the path's length, from and to, "
                f"with 0 <= from < to <= 1 (e.g. 0.2 0.32), got {window!r}"
            )
        object.__setattr__(self, "demo_start_window", (float(window[0]), float(window[1])))
        if not share and self.demo_start_window != (0.0, 1.0):
            raise ValueError(
                "DAggerConfig.demo_start_window chooses where the demo_start_share rollouts start; with "
                "demo_start_share 0 no rollout does: set --demo-start-share too, or leave the window unset"
            )
        if share and maze:
            raise ValueError(
                "DAggerConfig.demo_start_share: starts from the expert's states are the labyrinth's "
                f"(tasks LABYRINTH-EASY/-MEDIUM/-HARD), not {self.learner.task}'s; set it to 0"
            )
        if share and self.expert_data is None:
            raise ValueError(
                "DAggerConfig.demo_start_share needs expert_data (--expert-data), the expert dataset whose "
                "states the rollouts start from"
            )

    def _check_teacher(self, maze: bool) -> None:
        """Refuse a ``teacher`` that is no path, or on the circular maze (the run checks the policy
        itself when it loads it: :class:`~bimgame.learn.dagger.teacher.PolicyTeacher`)."""
        if self.teacher is None:
            return
        if not (isinstance(self.teacher, str) and self.teacher):
            raise ValueError(
                f"DAggerConfig.teacher must be a trained policy's run directory or None, got {self.teacher!r}"
            )
        if maze:
            raise ValueError(
                "DAggerConfig.teacher: a learned teacher labels the labyrinth's rollouts (tasks "
                f"LABYRINTH-EASY/-MEDIUM/-HARD), not {self.learner.task}'s; leave it unset for the MPC expert"
            )
        if not Path(self.teacher).exists():
            raise ValueError(
                f"DAggerConfig.teacher {self.teacher} does not exist (a run directory or a checkpoint in one)"
            )

    def _check_mazes(self) -> None:
        """Refuse maze settings DAgger cannot run with; a state learner on mazes reads their encoding
        (:func:`~bimgame.learn.common.maze_network`, as every learner's settings)."""
        learner = maze_network(
            "DAggerConfig", self.learner.task, self.learner, num_mazes=self.num_mazes, start_maze=self.start_maze
        )
        object.__setattr__(self, "learner", learner)

    @property
    def maze_options(self) -> dict[str, Any]:
        """The env arguments of the run's mazes (empty on MERL's maze alone), or on the labyrinth of its
        learner's observation extras and the off-path rule."""
        return network_env_options(self.learner, self.num_mazes, self.start_maze, run_rules(self))

    #: What a resumed run may change.
    RESUMABLE_CHANGES = ("iterations", "eval_episodes")
    #: What a resumed run keeps.
    FIXED_ON_RESUME = (
        "learner",
        "episodes_per_iteration",
        "beta0",
        "beta_decay",
        "epochs_per_iteration",
        "expert",
        "expert_data",
        "demo_start_share",
        "demo_start_window",
        "max_episode_steps",
        "stall_steps",
        "teacher",
        "off_path_rule",
    )

    def require_resumable_from(self, stored: DAggerConfig) -> None:
        """Refuse to resume a run stored with ``stored`` under these settings if they differ in more
        than :attr:`RESUMABLE_CHANGES`, naming the changed settings."""
        changed = [name for name in self.FIXED_ON_RESUME if getattr(stored, name) != getattr(self, name)]
        if "learner" in changed:  # name the learner's own settings that changed
            before, after = dataclasses.asdict(stored.learner), dataclasses.asdict(self.learner)
            changed.remove("learner")
            changed += [f"learner.{name}" for name in after if after[name] != before[name]]
        if changed:
            raise ValueError(
                f"--resume must keep the run's settings; changed: {', '.join(changed)}. "
                f"Allowed to change: {', '.join(self.RESUMABLE_CHANGES)}"
            )

    @property
    def planner(self) -> MPCConfig | LabyrinthMPCConfig:
        """The expert's settings (``expert``, filled in with the puzzle's defaults when None)."""
        assert self.expert is not None
        return self.expert

    def beta(self, iteration: int) -> float:
        """β of ``iteration``: the probability that a rollout executes the expert's action."""
        return self.beta0 * self.beta_decay**iteration

    @property
    def time_limit(self) -> int:
        """The rollouts' time limit: ``max_episode_steps`` if set, else the task's."""
        return self.max_episode_steps or self.learner.time_limit

    def to_dict(self) -> dict[str, Any]:
        """The settings as nested plain values (``config.json``'s ``dagger`` block)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> DAggerConfig:
        """The settings :meth:`to_dict` wrote; unknown or invalid names are refused."""
        values = dict(values)
        if "learner" in values:
            values["learner"] = PretrainConfig.from_dict(values["learner"])
        if values.get("expert") is not None:
            task = values.get("learner", cls().learner).task
            values["expert"] = from_dict(_expert_type(task), values["expert"], "MPC settings")
        return from_dict(cls, values, "DAgger settings")


def resolve_dagger_config(
    learner: PretrainConfig,
    given: dict[str, Any],
    run_dir: str | Path,
    *,
    resume: bool,
    learner_given: dict[str, Any] | None = None,
) -> DAggerConfig:
    """A run's DAgger settings: ``learner`` and ``given`` (the DAggerConfig fields a user gave) for a new
    run. A resumed run's are its stored settings overridden by ``given`` and, in its learner, by
    ``learner_given`` (the learner's fields a user gave): a setting given with the run's own value is
    accepted, one that changes anything but :attr:`DAggerConfig.RESUMABLE_CHANGES` is refused, named."""
    if not resume:
        return DAggerConfig(learner=learner, **given)
    stored = _stored_config(run_dir)
    if learner_given:
        given = {**given, "learner": dataclasses.replace(stored.learner, **learner_given)}
    return dataclasses.replace(stored, **given)  # dagger() refuses it if it changes a fixed setting


def _stored_config(run_dir: str | Path) -> DAggerConfig:
    """The settings of the DAgger run in ``run_dir`` that ``--resume`` would continue (refusing a
    directory that holds none)."""
    stored_run_config(run_dir, KIND_DAGGER)
    return read_run_settings(run_dir, "dagger", DAggerConfig.from_dict)
