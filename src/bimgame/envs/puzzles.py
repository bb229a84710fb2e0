"""Which puzzle a task is of, and what a learner needs of it without knowing which one it is.

Two puzzles have tasks a learner trains on:

- MERL's circular maze (:mod:`bimgame.sim.tasks`, which stays the maze's own task module): ``FULL``,
  ``STG1`` … ``STG4``, on :class:`~bimgame.envs.vector.BallInMazeVectorEnv`;
- CyberRunner's labyrinth: ``LABYRINTH-EASY``, ``LABYRINTH-MEDIUM``, ``LABYRINTH-HARD``, the three
  BRIO layouts on :class:`~bimgame.envs.labyrinth_vector.LabyrinthVectorEnv` (CyberRunner's reward,
  episode end and 55 Hz actions; see :class:`~bimgame.envs.labyrinth_env.LabyrinthEnv`).

Task names are case-insensitive, as :func:`~bimgame.sim.tasks.parse_task`'s are: ``stg1`` and
``Labyrinth-Easy`` are ``STG1`` and ``LABYRINTH-EASY``; the hyphen is part of the name (no
``LABYRINTH_EASY``). :func:`puzzle` gives a task's :class:`Puzzle`: its canonical name, time limit,
spec (what the collector reads ``max_tilt`` from), the state observation's divisors (a state
network's ``obs_scale``) and its batched env (:meth:`Puzzle.vector_env`, what the learners step and
evaluate on).

A learner's network reads one of :data:`NETWORK_OBS`: the maze's ``pixels`` and ``state`` (the
labyrinth has both too), and ``cyberrunner``, CyberRunner's observation of the labyrinth (a 64×64
crop centred on the marble, its tilt and position, the path ahead), which :meth:`Puzzle.vector_env`
steps in its flat form (``obs_mode="cyberrunner_flat"``: one float32 vector per board, the crop then
the vector parts, :func:`~bimgame.envs.labyrinth_cyberrunner.flatten_cyberrunner`), since the learners move
one tensor per step; the network splits it again (:class:`~bimgame.learn.encoders.CyberRunnerEncoder`).
The maze has no such observation: it is refused there by name.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
from typing import Any

import numpy as np

from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.labyrinth_cyberrunner import GOAL_NORM
from bimgame.envs.labyrinth_env import OBSERVATION_EXTRAS, LabyrinthEnv, labyrinth_max_episode_steps
from bimgame.envs.labyrinth_vector import LabyrinthVectorEnv
from bimgame.envs.observe import OBS_MODES
from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.sim.maze import MazeSpec
from bimgame.sim.tasks import Task, parse_task

__all__ = [
    "MAZE",
    "LABYRINTH",
    "PUZZLES",
    "LABYRINTH_TASKS",
    "TASK_NAMES",
    "PuzzleSpec",
    "PuzzleVectorEnv",
    "Puzzle",
    "puzzle",
    "puzzle_task_setting",
    "maze_obs_scale",
    "state_obs_scale",
    "vector_env",
    "LABYRINTH_SPEED_SCALE",
    "NETWORK_OBS",
    "LABYRINTH_OBS",
    "check_obs",
]

#: The puzzles' names (:attr:`Puzzle.family`).
MAZE, LABYRINTH = "maze", "labyrinth"
PUZZLES = (MAZE, LABYRINTH)
#: The labyrinth's tasks and their layouts (:data:`~bimgame.sim.labyrinth_layouts.LAYOUT_NAMES`).
LABYRINTH_TASKS = {"LABYRINTH-EASY": "easy", "LABYRINTH-MEDIUM": "medium", "LABYRINTH-HARD": "hard"}
#: Every task a learner trains on: the maze's, then the labyrinth's.
TASK_NAMES = tuple(task.value for task in Task) + tuple(LABYRINTH_TASKS)
#: What :attr:`Puzzle.spec` is: the board the collector reads ``max_tilt`` from.
PuzzleSpec = MazeSpec | LabyrinthSpec
#: What :meth:`Puzzle.vector_env` builds.
PuzzleVectorEnv = BallInMazeVectorEnv | LabyrinthVectorEnv

#: The labyrinth's divisor of the marble's speed (m/s): the maze's 0.5 m/s. Measured on each layout
#: (32 boards × 3000 steps of full-rate random tilts held for 30 steps, the marble free to leave the
#: path): 99th percentiles of the speed 0.45 (easy), 0.42 (medium), 0.34 m/s (hard), maxima 0.57,
#: 0.52, 0.41 m/s; a marble rolling from rest down 10 cm at the full 10° tilt reaches ≈ 0.49 m/s.
LABYRINTH_SPEED_SCALE = 0.5
#: Observations only the labyrinth has, and what :meth:`Puzzle.vector_env` steps for each: a learner's
#: ``cyberrunner`` in its flat form; the env's own modes of it as they are.
LABYRINTH_OBS = {"cyberrunner": "cyberrunner_flat", "cyberrunner_flat": "cyberrunner_flat"}
#: The observations a learner's network reads (``NetworkSettings.obs``): the maze's, then CyberRunner's.
NETWORK_OBS = (*OBS_MODES, "cyberrunner")
#: The labyrinth's env arguments that :meth:`Puzzle.env` takes beside ``obs_mode`` and ``action_type``.
LABYRINTH_ENV_EXTRAS = (*OBSERVATION_EXTRAS, "off_path_rule", "fail_reward")
#: The keyword arguments a labyrinth vector env takes besides the ones every puzzle's takes: those of
#: :class:`LabyrinthEnv` and the start curriculum's sampler.
_LABYRINTH_OPTIONS = (frozenset(inspect.signature(LabyrinthEnv.__init__).parameters) - {"self", "layout"}) | {
    "start_sampler"
}


@functools.cache
def _layout_spec(layout: str) -> LabyrinthSpec:
    """The labyrinth's board of ``layout`` (built once: a spec is immutable)."""
    return LabyrinthSpec.layout(layout)


def _labyrinth_obs_scale(spec: LabyrinthSpec) -> np.ndarray:
    """Divisors that bring the labyrinth's 17 state values (:class:`LabyrinthEnv`'s ``obs_mode="state"``)
    to order 1, each from a fact of the board:

    - marble x, y (m, from the board's centre): the board's half-width and half-height (0.138,
      0.1155 m: the observation space's own bounds);
    - vx, vy (m/s): :data:`LABYRINTH_SPEED_SCALE` (0.5 m/s, about the fastest the marble rolls);
    - tilt about x and y (rad): ``max_tilt`` (10°), as the maze's;
    - progress along the path: 1 (already a fraction of the path's length);
    - the 5 path points ahead relative to the marble (x, y each, m): the k-th (k = 1 … 5) divided by
      k × 12 mm, CyberRunner's own normalisation of its relative path (its ``"goal"``; the k-th
      point lies (k − 1) × 12 mm along the path from the marble's projection on it, which is within
      ``path_tolerance`` (25 mm) of the marble while the episode lasts: the first pair measured within
      ±27 mm (99th percentile 22 mm, ≈ 1.8 after division), the fifth within ±67 mm (≈ 1.1)).
    """
    hx, hy = spec.board_size[0] / 2, spec.board_size[1] / 2
    speed = LABYRINTH_SPEED_SCALE
    return np.concatenate([[hx, hy, speed, speed, spec.max_tilt, spec.max_tilt, 1.0], GOAL_NORM]).astype(np.float32)


def maze_obs_scale(spec: MazeSpec, n_marbles: int = 1) -> np.ndarray:
    """The maze's divisors (:class:`~bimgame.envs.observe.Observer`'s state layout): positions by the
    rim radius, velocities by 0.5 m/s (about the fastest reachable), tilts by the maximum tilt,
    channels by the outermost channel."""
    per_marble = [spec.rim_radius, spec.rim_radius, 0.5, 0.5] * n_marbles
    return np.array(per_marble + [spec.max_tilt] * 2 + [max(1, spec.outermost_channel)] * n_marbles, dtype=np.float32)


def state_obs_scale(spec: PuzzleSpec) -> np.ndarray:
    """Divisors that bring ``spec``'s state observation to order 1: a state network's ``obs_scale``
    (and the privileged state's divisors): 7 for MERL's maze with one marble, 17 for the labyrinth."""
    if isinstance(spec, LabyrinthSpec):
        return _labyrinth_obs_scale(spec)
    return maze_obs_scale(spec)


@dataclasses.dataclass(frozen=True)
class Puzzle:
    """A task and the puzzle it is of (:func:`puzzle` builds it from a task's name)."""

    task: str
    """The task's canonical name (``STG1``, ``LABYRINTH-EASY``)."""
    family: str
    """:data:`MAZE` or :data:`LABYRINTH`."""

    @property
    def is_maze(self) -> bool:
        return self.family == MAZE

    @property
    def layout(self) -> str | None:
        """The labyrinth's layout (``easy``, ``medium``, ``hard``); None for the maze."""
        return LABYRINTH_TASKS.get(self.task)

    @property
    def time_limit(self) -> int:
        """The episode time limit in action steps: the maze task's (:data:`~bimgame.sim.tasks.MAX_EPISODE_STEPS`),
        or CyberRunner's 54.5 s at the labyrinth's 55 Hz (3000 steps)."""
        if self.is_maze:
            return Task(self.task).time_limit
        return labyrinth_max_episode_steps(55)

    @property
    def spec(self) -> PuzzleSpec:
        """The board (MERL's maze; the labyrinth's layout): what the collector reads ``max_tilt`` from,
        and what a network's fixed inputs are made from."""
        if self.is_maze:
            return MazeSpec.merl()
        assert self.layout is not None
        return _layout_spec(self.layout)

    def state_obs_scale(self) -> np.ndarray:
        """The state observation's divisors on this puzzle's board (:func:`state_obs_scale`)."""
        return state_obs_scale(self.spec)

    def env(self, *, obs_mode: str, action_type: str, **maze_options: Any) -> BallInMazeEnv | LabyrinthEnv:
        """One environment of the task, without a time limit (its user counts steps): what a loop that
        reads each board's physics state steps, such as DAgger's expert-labelled rollouts. ``obs_mode``
        ``cyberrunner`` is stepped as ``cyberrunner_flat``, as in :meth:`vector_env`. ``maze_options``:
        the circular maze's random-maze arguments (``num_mazes``, ``start_maze``), or the labyrinth's
        ``surroundings``, ``motion``, ``off_path_rule`` and ``fail_reward``."""
        check_obs("obs_mode", self.task, obs_mode)
        extras = {name: maze_options.pop(name) for name in LABYRINTH_ENV_EXTRAS if name in maze_options}
        if self.is_maze:
            asked = [name for name, on in extras.items() if on is not None and on is not False]
            if asked:
                verb = "is" if len(asked) == 1 else "are"
                raise ValueError(
                    f"{' and '.join(asked)} {verb} the labyrinth's (its observations' extras and rules), "
                    f"not {self.task}'s"
                )
            return BallInMazeEnv(self.task, obs_mode=obs_mode, action_type=action_type, **maze_options)
        if maze_options:
            raise ValueError(f"{', '.join(maze_options)}: random mazes are circular mazes, not {self.task}")
        assert self.layout is not None
        return LabyrinthEnv(
            self.layout,
            obs_mode=LABYRINTH_OBS.get(obs_mode, obs_mode),
            action_type=action_type,
            **extras,
        )

    def vector_env(
        self,
        num_envs: int,
        *,
        obs_mode: str,
        action_type: str,
        max_episode_steps: int | None = None,
        nthread: int = 1,
        autoreset_mode: str = "same_step",
        state_info: bool = False,
        **options: Any,
    ) -> PuzzleVectorEnv:
        """``num_envs`` environments of the task stepped as one batch. ``max_episode_steps`` None: the
        task's :attr:`time_limit`. ``options``: the env's other keyword arguments; on the labyrinth
        those of :class:`LabyrinthEnv` (``render_mode``, ``render_size``, ``start_noise`` …) and
        ``start_sampler``, while a maze-only option (``randomize``, ``maze``, ``num_mazes`` …) is refused by
        name unless it is None (``ValueError``). ``obs_mode`` ``cyberrunner`` (a learner's, the
        labyrinth's only) is stepped as ``cyberrunner_flat``: one float32 vector per board (the
        ``Dict`` form is :class:`LabyrinthVectorEnv`'s own ``obs_mode="cyberrunner"``)."""
        limit = self.time_limit if max_episode_steps is None else max_episode_steps
        check_obs("obs_mode", self.task, obs_mode)
        if self.is_maze:
            return BallInMazeVectorEnv(
                num_envs,
                task=self.task,
                obs_mode=obs_mode,
                action_type=action_type,
                max_episode_steps=limit,
                nthread=nthread,
                autoreset_mode=autoreset_mode,
                state_info=state_info,
                **options,
            )
        refused = sorted(
            name for name, value in options.items() if name not in _LABYRINTH_OPTIONS and value is not None
        )
        if refused:
            raise ValueError(
                f"{', '.join(refused)}: the circular maze's option{'s' if len(refused) > 1 else ''}, "
                f"not the labyrinth's (task {self.task})"
            )
        assert self.layout is not None
        return LabyrinthVectorEnv(
            num_envs,
            self.layout,
            obs_mode=LABYRINTH_OBS.get(obs_mode, obs_mode),
            action_type=action_type,
            max_episode_steps=limit,
            nthread=nthread,
            autoreset_mode=autoreset_mode,
            state_info=state_info,
            **{name: value for name, value in options.items() if name in _LABYRINTH_OPTIONS},
        )


def puzzle(task: str | Task) -> Puzzle:
    """The :class:`Puzzle` of ``task`` (a name in any case, or a :class:`~bimgame.sim.tasks.Task`);
    ``ValueError`` naming every allowed task for an unknown one."""
    if isinstance(task, Task):
        return Puzzle(task.value, MAZE)
    name = str(task).upper()
    if name in LABYRINTH_TASKS:
        return Puzzle(name, LABYRINTH)
    try:
        return Puzzle(parse_task(name).value, MAZE)
    except ValueError:
        raise ValueError(f"unknown task {task!r}; allowed: {', '.join(TASK_NAMES)}") from None


def puzzle_task_setting(owner: str, task: str | Task) -> str:
    """The canonical name of ``task`` (either puzzle's) as a learner's settings store it; a ``ValueError``
    names the setting (``owner.task``) and the allowed tasks."""
    try:
        return puzzle(task).task
    except ValueError as error:
        raise ValueError(f"{owner}.task: {error}") from None


def check_obs(owner: str, task: str | Task, obs: str) -> None:
    """Refuse, naming ``owner`` (a setting, ``PPOConfig.network.obs``), CyberRunner's observation on a
    task of the circular maze (``ValueError``); other observations are checked where they are used."""
    found = puzzle(task)
    if found.is_maze and obs in LABYRINTH_OBS:
        raise ValueError(
            f"{owner} {obs!r} is CyberRunner's observation of the labyrinth (a crop centred on the marble, the "
            f"path ahead); task {found.task} is the circular maze's, whose observations are {', '.join(OBS_MODES)}"
        )


def vector_env(task: str | Task, num_envs: int, **arguments: Any) -> PuzzleVectorEnv:
    """``puzzle(task).vector_env(num_envs, ...)`` (:meth:`Puzzle.vector_env`)."""
    return puzzle(task).vector_env(num_envs, **arguments)
