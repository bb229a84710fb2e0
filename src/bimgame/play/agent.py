"""What plays for the person in ``bimgame play``: a trained policy (:class:`AgentPlayer`: an A3C run,
a pre-trained or DAgger policy, :func:`~bimgame.learn.common.load_run_network`) or the puzzle's MPC
expert (:class:`ExpertPlayer`, ``--agent expert``), one step at a time.

A trained policy follows the whole episode, whoever controls it: at every step it sees the
observation and advances its LSTM, and it is told the action that was executed (a person's, while
the person plays) and the reward. So when control goes back to it mid-episode it acts from a memory
of what happened, with the inputs it was trained with (:class:`~bimgame.learn.actor.RecurrentActor`).
On the maze it must take discrete actions (the keyboard's, which a recording stores); on the
labyrinth either kind: a continuous-action network drives a continuous env, and the person's keys
reach it as the same tilt changes in continuous form (:mod:`bimgame.play.boards`).

The expert plans from the physics state alone, so it acts only when it has control (its planning is
the costly part: tens of milliseconds a step, so it plays slower than real time on the labyrinth).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch

from bimgame.envs.observe import Observer
from bimgame.envs.puzzles import LABYRINTH_OBS, PuzzleSpec, puzzle
from bimgame.expert.labyrinth_mpc import LabyrinthMPC
from bimgame.expert.mpc import RandomShootingMPC
from bimgame.learn.actor import RecurrentActor, tilt_input
from bimgame.learn.common import RunInfo, load_run_network
from bimgame.learn.maze_runs import network_env_options, stored_off_path_rule
from bimgame.learn.policy_heads import require_discrete
from bimgame.play.boards import Board, LabyrinthBoard, Moment
from bimgame.sim.layout import StateLayout
from bimgame.sim.maze import MazeSpec

__all__ = ["EXPERT", "Player", "AgentPlayer", "ExpertPlayer", "is_expert"]

#: ``--agent expert``: the puzzle's MPC expert instead of a run directory (a directory named so: ``./expert``).
EXPERT = "expert"


def is_expert(source: object) -> bool:
    """Whether ``--agent`` names the expert: the string ``"expert"`` (a ``Path`` is always a run)."""
    return isinstance(source, str) and source == EXPERT


class Player(Protocol):
    """What the session asks of whoever plays for the person."""

    follows_every_step: bool
    """Whether it must see every step (a network's memory), or only those it plays."""
    action_type: str
    """The env actions it takes ("discrete" or "continuous"): the session's env takes these."""

    @property
    def description(self) -> str: ...
    @property
    def greedy(self) -> bool | None: ...
    def set_greedy(self, value: bool) -> None: ...
    def start_episode(self, seed: int) -> None: ...
    def act(self, moment: Moment) -> Any: ...
    def observe(self, executed: Any, reward: float, done: bool) -> None: ...
    def close(self) -> None: ...


class AgentPlayer:
    """Acts with the policy of the run in ``source`` on ``spec``'s board (the session's task's board;
    ``layout``: the maze's physics state layout, which a pixel network's frames are drawn from).

    ``task`` is the session's task: a run of the other puzzle is refused (``ValueError`` naming both).
    ``greedy``: take the most likely action (True) or sample from the policy (False); may be changed
    between steps. ``seed`` seeds the sampling."""

    follows_every_step = True

    def __init__(
        self,
        source: str | Path,
        spec: PuzzleSpec,
        layout: StateLayout | None = None,
        *,
        task: str | None = None,
        greedy: bool = True,
        seed: int = 0,
    ):
        net, run, _ = load_run_network(source)
        played = puzzle(task) if task is not None else puzzle(run.task)
        if puzzle(run.task).family != played.family:
            raise ValueError(
                f"--agent {run.run_dir} was trained on {run.task} ({puzzle(run.task).family}); task {played.task} "
                f"is the {played.family}'s: pass --task with one of the {puzzle(run.task).family}'s tasks, or "
                f"--agent expert or a run trained on the {played.family}"
            )
        self.maze = played.is_maze
        if self.maze:
            # A person plays the maze with the keyboard's discrete actions, a recording stores them, and
            # the agent is told them.
            require_discrete(
                "bimgame play on the maze", net.config.action_type, f"evaluate {run.run_dir} with bimgame evaluate"
            )
        net.eval()
        self.run: RunInfo = run
        self.obs_mode = run.network.obs
        self.action_type = net.config.action_type
        #: The labyrinth env's observation mode that is this network's input (the maze's env is state-observed).
        self.env_obs_mode = "state" if self.maze else LABYRINTH_OBS.get(self.obs_mode, self.obs_mode)
        #: The labyrinth env's other arguments its observations need (the marble's surroundings or motion),
        #: and the off-path rule the run trained under.
        self.env_options = network_env_options(run.network, rules={"off_path_rule": stored_off_path_rule(run.config)})
        self.max_tilt = spec.max_tilt
        self._pixels = None
        if self.maze and self.obs_mode == "pixels":
            assert isinstance(spec, MazeSpec) and layout is not None, "a maze pixel agent needs the maze and its layout"
            self._pixels = Observer(spec, 1, "pixels", layout=layout)
        self._actor = RecurrentActor(net, 1, generator=torch.Generator().manual_seed(int(seed)), greedy=greedy)

    @property
    def greedy(self) -> bool:
        return self._actor.greedy

    @greedy.setter
    def greedy(self, value: bool) -> None:
        self._actor.greedy = bool(value)

    def set_greedy(self, value: bool) -> None:
        self.greedy = value

    @property
    def description(self) -> str:
        """What plays, for the page: "pretrained-policy run (STG1, state observations)"."""
        kind = "" if self.action_type == "discrete" else ", continuous actions"
        return f"{self.run.kind} {self.run.run_dir.name} ({self.run.task}, {self.obs_mode} observations{kind})"

    def start_episode(self, seed: int = 0) -> None:
        """A new episode: no previous action or reward, a fresh LSTM state (the sampling generator
        goes on: ``seed`` is not used)."""
        self._actor.reset()

    def act(self, moment: Moment) -> Any:
        """The agent's action in the current state: an int (discrete) or a float32 (2,) in [-1, 1]
        (continuous). Advances its memory: call once per step, then :meth:`observe` what was executed."""
        if self._pixels is not None:
            assert moment.channel is not None
            state = np.asarray(moment.sim_state, dtype=np.float64)[None]
            obs = self._pixels(state, np.asarray(moment.channel)[None])
        else:
            obs = np.asarray(moment.obs, dtype=np.float32)[None]
        tilt_t = tilt_input({"tilt": np.asarray(moment.tilt, dtype=np.float64)[None]}, self.max_tilt)
        actions, _, _ = self._actor.act(obs, tilt_t)
        if self.action_type == "discrete":
            return int(actions[0])
        return self._actor.executed(actions)[0].numpy().astype(np.float32)

    def observe(self, executed: Any, reward: float, done: bool) -> None:
        """The action that was executed this step (the agent's or a person's) and its reward."""
        if self.action_type == "discrete":
            action = torch.tensor([int(executed)])
        else:
            action = torch.as_tensor(np.asarray(executed, dtype=np.float32)).reshape(1, -1)
        self._actor.observe(action, np.array([reward], dtype=np.float32), np.array([done]))

    def close(self) -> None:
        """Nothing to release (the network is garbage-collected)."""


class ExpertPlayer:
    """The MPC expert of ``board``'s puzzle: :class:`~bimgame.expert.mpc.RandomShootingMPC` on the
    maze (its default settings, those of ``bimgame generate``), :class:`~bimgame.expert.labyrinth_mpc.LabyrinthMPC`
    on the labyrinth (its defaults, solving 19/20 hard boards in ``benchmarks/bench_expert_labyrinth.py``),
    matched to the board's env. Its random draws restart from each episode's seed
    (:meth:`start_episode`): an episode it plays alone is the same for the same seed."""

    follows_every_step = False

    def __init__(self, board: Board):
        self._rng = np.random.default_rng(0)
        self._labyrinth: LabyrinthMPC | None = None
        self._maze: RandomShootingMPC | None = None
        if isinstance(board, LabyrinthBoard):
            self._labyrinth = LabyrinthMPC.for_env(board.env, rng=self._rng)
            config: Any = self._labyrinth.config
        else:
            self._maze = RandomShootingMPC(board.env.maze, rng=self._rng, task=board.task)
            config = self._maze.config
        self.action_type = board.action_type
        self._settings = f"K={config.n_samples}, H={config.horizon}"

    @property
    def description(self) -> str:
        return f"the MPC expert (random shooting, {self._settings})"

    @property
    def greedy(self) -> None:
        """The expert has no sampled mode: None (the page hides the switch)."""
        return None

    def set_greedy(self, value: bool) -> None:
        raise ValueError(
            "the MPC expert plans a best action every step and has no greedy/sampled switch; it exists for "
            "trained runs (--agent RUN)"
        )

    def start_episode(self, seed: int = 0) -> None:
        """A new episode: the random draws restart from ``seed``, the plan is forgotten."""
        self._rng = np.random.default_rng(int(seed))
        if self._labyrinth is not None:
            self._labyrinth.rng = self._rng
            self._labyrinth.reset()
        if self._maze is not None:
            self._maze.rng = self._rng

    def act(self, moment: Moment) -> Any:
        """The expert's action from the physics state (and, on the labyrinth, the env's path segment)."""
        if self._labyrinth is not None:
            return self._labyrinth.act(moment.sim_state, moment.segment)
        assert self._maze is not None
        return self._maze.act(moment.sim_state)

    def observe(self, executed: Any, reward: float, done: bool) -> None:
        """Nothing: the expert plans from the physics state alone."""

    def close(self) -> None:
        if self._labyrinth is not None:
            self._labyrinth.close()
        if self._maze is not None:
            self._maze.close()
