"""A trained policy playing one game step by step: an A3C run or a pre-trained policy
(:func:`~bimgame.learn.common.load_run_network`), acting greedily or by sampling.

The agent follows the whole episode, whoever controls it: at every step it sees the observation
and advances its LSTM, and it is told the action that was executed (a person's, while the person
plays) and the reward. So when control goes back to it mid-episode it acts from a memory of what
happened, with the inputs it was trained with (:class:`~bimgame.learn.actor.RecurrentActor`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from bimgame.envs.observe import Observer
from bimgame.learn.actor import RecurrentActor, tilt_input
from bimgame.learn.common import RunInfo, load_run_network
from bimgame.learn.policy_heads import require_discrete
from bimgame.sim.layout import StateLayout
from bimgame.sim.maze import MazeSpec

__all__ = ["AgentPlayer"]


class AgentPlayer:
    """Acts for one env with the policy of the run in ``source``.

    ``greedy``: take the most likely action (True) or sample from the policy (False); may be
    changed between steps. ``seed`` seeds the sampling."""

    def __init__(self, source: str | Path, maze: MazeSpec, layout: StateLayout, *, greedy: bool = True, seed: int = 0):
        net, run, _ = load_run_network(source)
        # A person plays the same game with the keyboard's discrete actions, and the agent is told them.
        require_discrete("bimgame play", net.config.action_type, f"evaluate {run.run_dir} with bimgame evaluate")
        net.eval()
        self.run: RunInfo = run
        self.obs_mode = run.network.obs
        self.max_tilt = maze.max_tilt
        self._pixels = Observer(maze, 1, "pixels", layout=layout) if self.obs_mode == "pixels" else None
        self._actor = RecurrentActor(net, 1, generator=torch.Generator().manual_seed(int(seed)), greedy=greedy)

    @property
    def greedy(self) -> bool:
        return self._actor.greedy

    @greedy.setter
    def greedy(self, value: bool) -> None:
        self._actor.greedy = bool(value)

    @property
    def description(self) -> str:
        """What plays, for the page: "pretrained-policy on STG1 (state observations)"."""
        return f"{self.run.kind} {self.run.run_dir.name} ({self.run.task}, {self.obs_mode} observations)"

    def start_episode(self) -> None:
        """A new episode: no previous action or reward, a fresh LSTM state."""
        self._actor.reset()

    def act(self, state_obs: np.ndarray, sim_state: np.ndarray, channel: np.ndarray, tilt: np.ndarray) -> int:
        """The agent's action in the current state (advances its memory: call once per step, then
        :meth:`observe` with what was executed)."""
        if self._pixels is not None:
            obs = self._pixels(np.asarray(sim_state, dtype=np.float64)[None], np.asarray(channel)[None])
        else:
            obs = np.asarray(state_obs, dtype=np.float32)[None]
        tilt_t = tilt_input({"tilt": np.asarray(tilt, dtype=np.float64)[None]}, self.max_tilt)
        actions, _, _ = self._actor.act(obs, tilt_t)
        return int(actions[0])

    def observe(self, executed: int, reward: float, done: bool) -> None:
        """The action that was executed this step (the agent's or a person's) and its reward."""
        self._actor.observe(torch.tensor([int(executed)]), np.array([reward], dtype=np.float32), np.array([done]))
