"""The two puzzles behind one interface for ``bimgame play``: what :class:`~bimgame.play.session.PlaySession`
needs of a game's env, whichever puzzle it is (:mod:`bimgame.envs.puzzles`).

- :class:`MazeBoard`: MERL's circular maze (``FULL``, ``STG1`` … ``STG4``) on a
  :class:`~bimgame.envs.env.BallInMazeEnv` with state observations, 30 actions a second; a success
  is the goal, the only way an episode terminates.
- :class:`LabyrinthBoard`: CyberRunner's labyrinth (``LABYRINTH-EASY``, ``-MEDIUM``, ``-HARD``) on a
  :class:`~bimgame.envs.labyrinth_env.LabyrinthEnv` at CyberRunner's 55 actions a second (the rate the
  learners train at), so a played second is a simulated second; an episode terminates at the goal
  (success), over a hole or off the path (failures). Its observation is the agent's (state, pixels or
  CyberRunner's flat crop), so a network reads what it was trained on; its action type is the
  agent's (a continuous-action network drives a continuous env) or discrete for people alone.

Both take the keyboard's discrete actions (:data:`~bimgame.play.controls.KEY_ACTIONS`): both envs turn
action ``i`` into the tilt change ``DISCRETE_TILTS[i]`` × their tilt step
(:func:`~bimgame.envs.actions.action_to_tilt_delta`), so in a continuous env :meth:`key_action` sends
that same vector and the board moves exactly as with the discrete action.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from bimgame.envs.actions import DISCRETE_TILTS
from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.envs.puzzles import puzzle

__all__ = ["Moment", "StepResult", "MazeBoard", "LabyrinthBoard", "Board", "open_board", "MAZE_TICK_HZ"]

#: Actions per second on the maze: the env's 30 Hz actions in real time.
MAZE_TICK_HZ = 30


@dataclasses.dataclass(frozen=True)
class Moment:
    """What a player (:mod:`bimgame.play.agent`) sees of the current step, before acting."""

    obs: Any
    """The env's observation (the maze's state vector; the labyrinth's in the agent's mode)."""
    sim_state: np.ndarray
    """The physics state (``env.sim.get_state()``): what the MPC experts plan from."""
    tilt: np.ndarray
    """The board's tilt (rad) about x and y."""
    channel: np.ndarray | None = None
    """The maze: the marble's channel (``info["channel"]``); None on the labyrinth."""
    segment: int | None = None
    """The labyrinth: the marble's path segment (``info["segment"]``); None on the maze."""


@dataclasses.dataclass(frozen=True)
class StepResult:
    """One env step as the session needs it."""

    reward: float
    terminated: bool
    success: bool
    reason: str | None
    """Why the episode terminated: "goal", "hole", "off the path"; None while it goes on."""


class _EnvBoard:
    """What both boards do the same way with their env (``self.env``: its sim's tilt, its render)."""

    env: BallInMazeEnv | LabyrinthEnv

    @property
    def tilt(self) -> np.ndarray:
        return self.env.sim.tilt

    def frame(self) -> np.ndarray:
        """The env's colour frame (the maze's with its tilt gauge; the labyrinth's from above, north up,
        without one: the page shows the tilt)."""
        frame: np.ndarray = self.env.render()
        return frame

    def close(self) -> None:
        self.env.close()


class MazeBoard(_EnvBoard):
    """MERL's maze ``task`` (its canonical name) in a state-observation env rendering ``render_size``² frames."""

    puzzle = "maze"
    env: BallInMazeEnv
    tick_hz = MAZE_TICK_HZ
    action_type = "discrete"

    def __init__(self, task: str, *, render_size: int = 480):
        self.task = task
        self.env = BallInMazeEnv(task, obs_mode="state", render_mode="rgb_array", render_size=render_size)
        self.spec = self.env.maze
        self.obs: np.ndarray = np.zeros(0, dtype=np.float32)
        self.channel: np.ndarray = np.zeros(1, dtype=np.int64)

    def reset(self, seed: int) -> None:
        self.obs, info = self.env.reset(seed=seed)
        self.channel = np.asarray(info["channel"])

    def step(self, action: Any) -> StepResult:
        self.obs, reward, terminated, _, info = self.env.step(action)
        self.channel = np.asarray(info["channel"])
        return StepResult(float(reward), bool(terminated), bool(terminated), "goal" if terminated else None)

    def key_action(self, action: int) -> Any:
        """The env action of the keyboard's discrete ``action``: itself."""
        return action

    def moment(self) -> Moment:
        return Moment(self.obs, self.sim_state, self.env.sim.tilt, channel=self.channel)

    @property
    def sim_state(self) -> np.ndarray:
        """The physics state now (read when an agent plans or a recording stores it, not every step)."""
        return self.env.sim.get_state()

    @property
    def marble_xy(self) -> tuple[float, float]:
        return float(self.obs[0]), float(self.obs[1])

    def status(self) -> dict[str, Any]:
        """Puzzle-specific fields of the page's state: none on the maze."""
        return {"progress": None}


class LabyrinthBoard(_EnvBoard):
    """The labyrinth of ``task`` (its canonical name), observed in ``obs_mode`` (with the marble's
    ``surroundings`` or ``motion``, :data:`~bimgame.envs.labyrinth_env.OBSERVATION_EXTRAS`, for an
    agent that reads them) and acted on with ``action_type`` actions at 55 Hz, rendering
    ``render_size``² frames."""

    puzzle = "labyrinth"
    env: LabyrinthEnv

    def __init__(
        self,
        task: str,
        *,
        obs_mode: str = "state",
        action_type: str = "discrete",
        render_size: int = 480,
        **extras: Any,
    ):
        layout = puzzle(task).layout
        assert layout is not None, f"{task} is no labyrinth task"
        self.task = task
        self.env = LabyrinthEnv(
            layout,
            action_type=action_type,
            obs_mode=obs_mode,
            render_mode="rgb_array",
            render_size=render_size,
            **extras,
        )
        self.spec = self.env.board
        self.action_type = action_type
        self.tick_hz = self.env.control_hz
        self.obs: Any = None
        self.info: dict[str, Any] = {}

    def reset(self, seed: int) -> None:
        self.obs, self.info = self.env.reset(seed=seed)

    def step(self, action: Any) -> StepResult:
        self.obs, reward, terminated, _, self.info = self.env.step(action)
        success = bool(self.info["is_success"])
        reason = None
        if terminated:
            reason = "goal" if success else "hole" if self.info["over_hole"] else "off the path"
        return StepResult(float(reward), bool(terminated), success, reason)

    def key_action(self, action: int) -> Any:
        """The env action of the keyboard's discrete ``action``: itself in a discrete env, the same
        tilt change as a continuous vector (``DISCRETE_TILTS[action]``) in a continuous one."""
        if self.action_type == "discrete":
            return action
        return DISCRETE_TILTS[action].astype(np.float32)

    def moment(self) -> Moment:
        return Moment(self.obs, self.env.sim.get_state(), self.env.sim.tilt, segment=int(self.info["segment"]))

    @property
    def marble_xy(self) -> tuple[float, float]:
        x, y = self.env.sim.marble_xy()
        return float(x), float(y)

    def status(self) -> dict[str, Any]:
        """The marble's progress along the printed path, as a fraction of its length."""
        return {"progress": float(self.info["progress_fraction"])}


Board = MazeBoard | LabyrinthBoard


def open_board(
    task: str,
    *,
    obs_mode: str = "state",
    action_type: str = "discrete",
    render_size: int = 480,
    **extras: Any,
) -> Board:
    """The board of ``task`` (a canonical name: :func:`~bimgame.envs.puzzles.puzzle`); ``obs_mode``,
    ``action_type`` and the observation ``extras`` (``surroundings``, ``motion``) apply to the
    labyrinth (the maze's play is state-observed and discrete)."""
    if puzzle(task).is_maze:
        return MazeBoard(task, render_size=render_size)
    return LabyrinthBoard(task, obs_mode=obs_mode, action_type=action_type, render_size=render_size, **extras)
