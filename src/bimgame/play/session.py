"""The game of ``bimgame play`` as a state machine, independent of the web: one env, the keys people
hold, an optional agent, the recording. The server calls :meth:`PlaySession.tick` 30 times a second
and draws :meth:`PlaySession.frame`; tests call the same methods directly.

**Phases.** An episode begins ``ready``: the marble at rest on its start, nothing moving, until a
person presses a key (so a page left open records nothing) — or at once when the agent plays.
``running``: every tick is one env step (1/30 s of simulated time) with the action of the latest
held key, the no-op when none is held, or the agent's action. ``over``: the goal was reached
(``success``) or the time limit hit; the final frame stays for :attr:`over_ticks` ticks (1.5 s),
then the next episode begins ``ready``. ``reset`` (R) ends the current episode at once.

**Control.** ``human`` or ``agent`` (only with an agent), switchable at any time, mid-episode too.
The agent follows the episode while the person plays (:mod:`bimgame.play.agent`). People in
several browser tabs share the one game: the latest pressed key of anyone counts.

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

from bimgame.envs.env import BallInMazeEnv
from bimgame.learn.common import read_run
from bimgame.play.agent import AgentPlayer
from bimgame.play.controls import KEY_NAMES, HeldKeys, action_name
from bimgame.play.recording import EpisodeBuilder, HumanRecording
from bimgame.sim.tasks import Task, parse_task
from bimgame.util.seeding import episode_seed

__all__ = ["PlaySession", "PHASES", "CONTROLLERS", "TICK_HZ"]

log = logging.getLogger("bimgame.play")

PHASES = ("ready", "running", "over")
CONTROLLERS = ("human", "agent")
#: Ticks per second: one env step per tick while running (the env's 30 Hz actions in real time).
TICK_HZ = 30
#: Episodes kept in :attr:`PlaySession.history`.
HISTORY = 10


class PlaySession:
    """One game: ``task`` (default: the agent's task, else FULL) with ``max_steps`` per episode (default:
    the task's limit), starts seeded from ``seed``; ``agent``: a run directory or checkpoint to load
    an :class:`~bimgame.play.agent.AgentPlayer` from (it then starts in control); ``recording``: an
    open :class:`~bimgame.play.recording.HumanRecording` for the person's episodes."""

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
        over_ticks: int = 45,
    ):
        if max_steps is not None and not (isinstance(max_steps, int) and max_steps >= 1):
            raise ValueError(f"max_steps must be a positive integer, got {max_steps!r}")
        if task is None:
            task = read_run(agent).task if agent is not None else "FULL"
        self.task = parse_task(task)
        self.env = BallInMazeEnv(self.task, obs_mode="state", render_mode="rgb_array", render_size=render_size)
        try:
            self.agent = (
                AgentPlayer(agent, self.env.maze, self.env.sim.layout, greedy=greedy, seed=seed)
                if agent is not None
                else None
            )
        except BaseException:
            self.env.close()
            raise
        self.max_steps = int(max_steps or self.task.time_limit)
        self.seed = int(seed)
        self.recording = recording
        self.over_ticks = int(over_ticks)
        self.keys = HeldKeys()
        self.controller = "agent" if self.agent is not None else "human"
        self.history: list[dict[str, Any]] = []
        self.recording_error: str | None = None
        self.episode = (recording.episodes if recording is not None else 0) - 1
        self._builder: EpisodeBuilder | None = None
        self._closed = False
        self._new_episode()

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
            self._end("reset", terminated=False)
        self._new_episode()

    def set_controller(self, who: str) -> None:
        """Give control to ``"human"`` or ``"agent"``, also mid-episode. Handing it to the agent ends
        the person's recorded episode (truncated) if it has a step."""
        if who not in CONTROLLERS:
            raise ValueError(f"unknown controller {who!r}; allowed: {', '.join(CONTROLLERS)}")
        if who == "agent" and self.agent is None:
            raise ValueError("no agent to hand control to: start bimgame play with --agent RUN")
        if who == self.controller:
            return
        if who == "agent":
            self._save_builder(terminated=False, reason="handed to the agent")
        self.controller = who

    def set_greedy(self, greedy: bool) -> None:
        if self.agent is None:
            raise ValueError("no agent playing: start bimgame play with --agent RUN")
        self.agent.greedy = bool(greedy)

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
        self.env.close()

    # ----------------------------------------------------------------- views
    def frame(self) -> np.ndarray:
        """The current colour frame (render_size² × 3 uint8) with the tilt gauge."""
        return self.env.render()

    @property
    def marble_xy(self) -> tuple[float, float]:
        """The marble's position on the board (m; +x right, +y up on the screen)."""
        return float(self._obs[0]), float(self._obs[1])

    def snapshot(self) -> dict[str, Any]:
        """What the page shows, as JSON-ready values."""
        recording = None
        if self.recording is not None:
            recording = {**self.recording.status, "session_error": self.recording_error}
        return {
            "type": "state",
            "task": self.task.value,
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
            "tilt_deg": [float(v) for v in np.degrees(self.env.sim.tilt)],
            "agent": None if self.agent is None else {"name": self.agent.description, "greedy": self.agent.greedy},
            "recording": recording,
            "recorded_steps": 0 if self._builder is None else self._builder.steps,
            "last": self.history[-1] if self.history else None,
        }

    # ----------------------------------------------------------------- internals
    def _new_episode(self) -> None:
        self.episode += 1
        self.episode_seed = episode_seed(self.seed, self.episode)
        self._obs, info = self.env.reset(seed=self.episode_seed)
        self._sim_state = self.env.sim.get_state()
        self._channel = np.asarray(info["channel"])
        self.steps, self.score, self.success = 0, 0.0, False
        self.last_action = 0
        self.phase = "ready"
        self._start = False
        self._builder = None
        if self.agent is not None:
            self.agent.start_episode()

    def _step(self) -> None:
        human = self.controller == "human"
        agent_action = None
        if self.agent is not None:  # the agent follows every step, whoever plays
            agent_action = self.agent.act(self._obs, self._sim_state, self._channel, self.env.sim.tilt)
        action = self.keys.action() if human else agent_action
        assert action is not None, "the agent has control only in a session that has one"
        if human and self.recording is not None and self._builder is None:
            self._builder = EpisodeBuilder(
                seed=self.episode_seed,
                start_step=self.steps,
                obs=self._obs,
                sim_state=self._sim_state,
                channel=self._channel,
            )
        obs, reward, terminated, _, info = self.env.step(action)
        self.steps += 1
        self.score += float(reward)
        truncated = not terminated and self.steps >= self.max_steps
        self._obs, self._sim_state, self._channel = obs, self.env.sim.get_state(), np.asarray(info["channel"])
        self.last_action = action
        if self.agent is not None:
            self.agent.observe(action, float(reward), terminated or truncated)
        if human and self._builder is not None:
            self._builder.add(action, reward, obs, self._sim_state, self._channel)
        if terminated or truncated:
            self.success = bool(terminated)
            self._end("goal" if terminated else "time limit", terminated=bool(terminated))

    def _end(self, reason: str, *, terminated: bool) -> None:
        recorded = self._save_builder(terminated=terminated, reason=reason)
        self.history = (
            self.history
            + [
                {
                    "episode": self.episode,
                    "reason": reason,
                    "success": terminated,
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
