"""The game of ``bimgame play`` as a state machine, independent of the web: one env, the keys people
hold, an optional agent, the recording. The server calls :meth:`PlaySession.tick` :attr:`PlaySession.tick_hz`
times a second (30 on the maze, 55 on the labyrinth: each puzzle's action rate, so play runs in real
time) and draws :meth:`PlaySession.frame`; tests call the same methods directly.

**Puzzles.** MERL's circular maze (``FULL``, ``STG1`` … ``STG4``) or CyberRunner's labyrinth
(``LABYRINTH-EASY``, ``-MEDIUM``, ``-HARD``), behind one interface (:mod:`bimgame.play.boards`). A
labyrinth episode also ends when the marble falls into a hole or leaves the path (a failure), and
the page's state then carries the marble's progress along the path. Recording people's episodes is
the maze's alone (:func:`refuse_unsupported`).

**Phases.** An episode begins ``ready``: the marble at rest on its start, nothing moving, until a
person presses a key (so a page left open records nothing) — or at once when the agent plays.
``running``: every tick is one env step with the action of the latest held key, the no-op when none
is held, or the agent's action. ``over``: the episode ended (``success`` at the goal; on the
labyrinth a hole or leaving the path; the time limit); the final frame stays for :attr:`over_ticks`
ticks, then the next episode begins ``ready``. ``reset`` (R) ends the current episode at once.

**Control.** ``human`` or ``agent`` (only with an agent), switchable at any time, mid-episode too.
A trained agent follows the episode while the person plays (:mod:`bimgame.play.agent`); the MPC
expert (``agent="expert"``) plans only when it plays. People in several browser tabs share the one
game: the latest pressed key of anyone counts.

**Recording** (with a :class:`~bimgame.play.recording.HumanRecording`): only steps a person
controlled, see :mod:`bimgame.play.recording` for when an episode is written. Episode ``k`` of a
session starts from ``reset(seed=episode_seed(seed, k))``, ``k`` counted on from the number of
episodes already in the recording: a resumed recording does not start again with the starts of its
first episodes (another ``--seed`` gives entirely new ones).
"""

from __future__ import annotations

import logging
from collections.abc import Hashable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.envs.puzzles import puzzle
from bimgame.learn.common import read_run
from bimgame.play.agent import AgentPlayer, ExpertPlayer, Player, is_expert
from bimgame.play.boards import MAZE_TICK_HZ, Board, MazeBoard, open_board
from bimgame.play.controls import KEY_NAMES, HeldKeys, action_name
from bimgame.play.recording import EpisodeBuilder, HumanRecording
from bimgame.sim.tasks import Task
from bimgame.util.seeding import episode_seed

__all__ = ["PlaySession", "PHASES", "CONTROLLERS", "TICK_HZ", "refuse_unsupported"]

log = logging.getLogger("bimgame.play")

PHASES = ("ready", "running", "over")
CONTROLLERS = ("human", "agent")
#: Ticks per second on the maze: one env step per tick while running (the env's 30 Hz actions in real
#: time); the labyrinth's session ticks at its env's 55 Hz (:attr:`PlaySession.tick_hz`).
TICK_HZ = MAZE_TICK_HZ
#: Episodes kept in :attr:`PlaySession.history`.
HISTORY = 10


def refuse_unsupported(task: str | Task, *, recording: bool) -> None:
    """Refuse by name what ``bimgame play`` cannot do on ``task``'s puzzle (``ValueError``): recording
    people's episodes (``--record``) on the labyrinth — a recording is a dataset of the maze's layout
    (``bimgame generate``'s: the maze's state observations, physics states and channels)."""
    found = puzzle(task)
    if recording and not found.is_maze:
        maze_tasks = ", ".join(t.value for t in Task)
        raise ValueError(
            f"--record: recording your episodes works on the circular maze's tasks only ({maze_tasks}): the "
            f"dataset is the maze's (bimgame generate's layout); on {found.task} you can play with the keys, "
            "watch --agent expert (the labyrinth's MPC) or --agent RUN (a run trained on the labyrinth), "
            "without --record"
        )


class PlaySession:
    """One game: ``task`` (either puzzle's; default: the agent's task, else FULL) with ``max_steps`` per
    episode (default: the task's limit), starts seeded from ``seed``; ``agent``: a run directory or
    checkpoint to load an :class:`~bimgame.play.agent.AgentPlayer` from, or ``"expert"`` for the
    puzzle's MPC expert (it then starts in control); ``recording``: an open
    :class:`~bimgame.play.recording.HumanRecording` for the person's episodes (the maze's only)."""

    phase: str
    """"ready" (waiting for the first key), "running" or "over" (the end screen)."""
    _over_left: int  # ticks the end screen stays

    def __init__(
        self,
        task: str | Task | None = None,
        *,
        max_steps: int | None = None,
        seed: int = 0,
        agent: str | Path | None = None,
        greedy: bool = True,
        recording: HumanRecording | None = None,
        render_size: int = 480,
        over_ticks: int | None = None,
    ):
        if max_steps is not None and not (isinstance(max_steps, int) and max_steps >= 1):
            raise ValueError(f"max_steps must be a positive integer, got {max_steps!r}")
        if task is None:
            task = read_run(agent).task if agent is not None and not is_expert(agent) else "FULL"
        found = puzzle(task)
        refuse_unsupported(found.task, recording=recording is not None)
        if is_expert(agent) and not greedy:
            raise ValueError(
                "--sampled: the MPC expert plans its best action and has no sampled mode (for --agent RUN)"
            )
        #: The task's canonical name (``STG1``, ``LABYRINTH-HARD``).
        self.task = found.task
        self.agent: Player | None = None
        self.board = self._open(agent, greedy=greedy, seed=seed, render_size=render_size)
        #: The env stepped: a :class:`~bimgame.envs.env.BallInMazeEnv` or a
        #: :class:`~bimgame.envs.labyrinth_env.LabyrinthEnv`.
        self.env = self.board.env
        #: Ticks (env steps) per second: the puzzle's action rate.
        self.tick_hz = float(self.board.tick_hz)
        self.max_steps = int(max_steps or found.time_limit)
        self.seed = int(seed)
        self.recording = recording
        self.over_ticks = round(1.5 * self.tick_hz) if over_ticks is None else int(over_ticks)
        self.keys = HeldKeys()
        self.controller = "agent" if self.agent is not None else "human"
        self.history: list[dict[str, Any]] = []
        self.recording_error: str | None = None
        self.episode = (recording.episodes if recording is not None else 0) - 1
        self._builder: EpisodeBuilder | None = None
        self._closed = False
        self._new_episode()

    def _open(self, agent: str | Path | None, *, greedy: bool, seed: int, render_size: int) -> Board:
        """The board, and :attr:`agent`: on the labyrinth a trained agent is loaded first, since the
        env observes and acts as its network does; the expert is matched to the env."""
        is_maze = puzzle(self.task).is_maze
        run = None
        if agent is not None and not is_expert(agent) and not is_maze:
            run = AgentPlayer(agent, puzzle(self.task).spec, task=self.task, greedy=greedy, seed=seed)
        options: dict[str, Any] = {}
        if run is not None:
            options = {"obs_mode": run.env_obs_mode, "action_type": run.action_type, **run.env_options}
        elif is_expert(agent):
            options = {"action_type": "continuous"}  # the labyrinth expert's measured setting (the maze's is discrete)
        board = open_board(self.task, render_size=render_size, **options)
        try:
            if run is not None:
                self.agent = run
            elif is_expert(agent):
                self.agent = ExpertPlayer(board)
            elif agent is not None:
                assert isinstance(board, MazeBoard)
                self.agent = AgentPlayer(
                    agent, board.spec, board.env.sim.layout, task=self.task, greedy=greedy, seed=seed
                )
        except BaseException:
            board.close()
            raise
        return board

    # ----------------------------------------------------------------- inputs
    def set_keys(self, client: Hashable, names: Iterable[str]) -> None:
        """The keys ``client`` holds now (names of :data:`~bimgame.play.controls.KEY_NAMES`). A newly
        pressed key starts a ``ready`` episode when the person is in control."""
        names = list(names)
        unknown = [n for n in names if n not in KEY_NAMES]
        if unknown:
            raise ValueError(f"unknown keys {unknown}; allowed: {', '.join(KEY_NAMES)}")
        if self.keys.set(client, names) and self.phase == "ready" and self.controller == "human":
            self._start = True

    def drop_client(self, client: Hashable) -> None:
        """A client left: its keys are released."""
        self.keys.drop(client)

    def reset(self) -> None:
        """End the current episode (recording the person's steps, if any) and begin the next."""
        if self.phase == "running":
            self._end("reset", terminated=False, success=False)
        self._new_episode()

    def set_controller(self, who: str) -> None:
        """Give control to ``"human"`` or ``"agent"``, also mid-episode. Handing it to the agent ends
        the person's recorded episode (truncated) if it has a step."""
        if who not in CONTROLLERS:
            raise ValueError(f"unknown controller {who!r}; allowed: {', '.join(CONTROLLERS)}")
        if who == "agent" and self.agent is None:
            raise ValueError("no agent to hand control to: start bimgame play with --agent RUN or --agent expert")
        if who == self.controller:
            return
        if who == "agent":
            self._save_builder(terminated=False, reason="handed to the agent")
        self.controller = who

    def set_greedy(self, greedy: bool) -> None:
        if self.agent is None:
            raise ValueError("no agent playing: start bimgame play with --agent RUN")
        self.agent.set_greedy(bool(greedy))

    # ----------------------------------------------------------------- time
    def tick(self) -> bool:
        """Advance the game by one tick; returns whether the env stepped."""
        if self._closed:
            return False
        if self.phase == "over":
            self._over_left -= 1
            if self._over_left <= 0:
                self._new_episode()
            return False
        if self.phase == "ready":
            if self.controller == "human" and not self._start:
                return False
            self.phase = "running"
        self._step()
        return True

    def close(self) -> None:
        """Stop: the person's unfinished episode is recorded (truncated, if it has a step)."""
        if self._closed:
            return
        if self.phase == "running":
            self._save_builder(terminated=False, reason="server stopped")
        self._closed = True
        if self.agent is not None:
            self.agent.close()
        self.board.close()

    # ----------------------------------------------------------------- views
    def frame(self) -> np.ndarray:
        """The current colour frame (render_size² × 3 uint8): the maze with its tilt gauge, or the labyrinth."""
        return self.board.frame()

    @property
    def marble_xy(self) -> tuple[float, float]:
        """The marble's position on the board (m; +x right, +y up on the screen)."""
        return self.board.marble_xy

    def snapshot(self) -> dict[str, Any]:
        """What the page shows, as JSON-ready values (``progress``: the labyrinth's fraction of its
        path; None on the maze)."""
        recording = None
        if self.recording is not None:
            recording = {**self.recording.status, "session_error": self.recording_error}
        agent = None
        if self.agent is not None:
            agent = {"name": self.agent.description, "greedy": self.agent.greedy}
        return {
            "type": "state",
            "task": self.task,
            "puzzle": self.board.puzzle,
            "phase": self.phase,
            "episode": self.episode,
            "step": self.steps,
            "max_steps": self.max_steps,
            "score": self.score,
            "success": self.success,
            "controller": self.controller,
            "action": action_name(self.last_action),
            "key": self.keys.latest(),
            "marble": list(self.marble_xy),
            "tilt_deg": [float(v) for v in np.degrees(self.board.tilt)],
            **self.board.status(),
            "agent": agent,
            "recording": recording,
            "recorded_steps": 0 if self._builder is None else self._builder.steps,
            "last": self.history[-1] if self.history else None,
        }

    # ----------------------------------------------------------------- internals
    def _new_episode(self) -> None:
        self.episode += 1
        self.episode_seed = episode_seed(self.seed, self.episode)
        self.board.reset(self.episode_seed)
        self.steps, self.score, self.success = 0, 0.0, False
        self.last_action: Any = 0
        self.last_reward = 0.0
        self.phase = "ready"
        self._start = False
        self._builder = None
        if self.agent is not None:
            self.agent.start_episode(self.episode_seed)

    def _step(self) -> None:
        human = self.controller == "human"
        board = self.board
        agent_action = None
        if self.agent is not None and (self.agent.follows_every_step or not human):
            agent_action = self.agent.act(board.moment())  # a network follows every step, whoever plays
        action = board.key_action(self.keys.action()) if human else agent_action
        assert action is not None, "the agent has control only in a session that has one"
        recording = human and self.recording is not None and isinstance(board, MazeBoard)
        if recording and self._builder is None:
            assert isinstance(board, MazeBoard)
            self._builder = EpisodeBuilder(
                seed=self.episode_seed,
                start_step=self.steps,
                obs=board.obs,
                sim_state=board.sim_state,
                channel=board.channel,
            )
        result = board.step(action)
        self.steps += 1
        self.score += result.reward
        truncated = not result.terminated and self.steps >= self.max_steps
        self.last_action, self.last_reward = action, result.reward
        if self.agent is not None:
            self.agent.observe(action, result.reward, result.terminated or truncated)
        if recording and self._builder is not None:
            assert isinstance(board, MazeBoard)
            self._builder.add(action, result.reward, board.obs, board.sim_state, board.channel)
        if result.terminated or truncated:
            self.success = result.success
            reason = result.reason if result.terminated and result.reason else "time limit"
            self._end(reason, terminated=result.terminated, success=result.success)

    def _end(self, reason: str, *, terminated: bool, success: bool) -> None:
        recorded = self._save_builder(terminated=terminated, reason=reason)
        self.history = (
            self.history
            + [
                {
                    "episode": self.episode,
                    "reason": reason,
                    "success": success,
                    "steps": self.steps,
                    "score": self.score,
                    "recorded": recorded,
                }
            ]
        )[-HISTORY:]
        self.phase = "over"
        self._over_left = self.over_ticks

    def _save_builder(self, *, terminated: bool, reason: str) -> int | None:
        """Save the person's episode if it has a step; returns its index in the recording."""
        builder, self._builder = self._builder, None
        if builder is None or builder.steps == 0 or self.recording is None:
            return None
        try:
            index = self.recording.add(builder.finish(terminated=terminated, reason=reason))
        except OSError as error:  # e.g. a full disk: the game goes on, the page shows the error
            self.recording_error = f"episode not saved: {error}"
            log.error("recording: %s", self.recording_error)
            return None
        self.recording_error = None
        log.info("recorded episode %d (%d steps, %s)", index, builder.steps, reason)
        return index
