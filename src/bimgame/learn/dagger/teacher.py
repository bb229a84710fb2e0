"""A learned policy as DAgger's expert (:mod:`bimgame.learn.dagger`): a privileged teacher.

A policy trained on the labyrinth's state (e.g. PPO from state, which completes the easy layout in
≈ 80% of episodes) labels a pixel learner's states with its own greedy action, read from the same
simulator state in the teacher's observation (Chen et al., "Learning by Cheating", CoRL 2019: a
privileged agent that sees the state teaches a sensorimotor one). Two things set it apart from the
MPC expert: its labels are one smooth function of the state, where the random-shooting planner's
scatter from plan to plan (the easy layout's cloned policies match ≈ 51–61% of its tilt changes
within 0.25), and it costs one batched forward pass per step instead of K·H simulator steps.

The teacher acts through a :class:`~bimgame.learn.actor.RecurrentActor` of its own, batched over the
iteration's rollouts, so its LSTM, previous action and previous reward follow each rollout's
executed actions exactly as when it acts alone. Its observation comes from
:meth:`~bimgame.envs.labyrinth_env.LabyrinthEnv.observe_state` of a view env in the teacher's own
observation mode, so any labyrinth policy (state, with surroundings, CyberRunner's) can teach any
learner of the same layout and kind of action.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.envs.puzzles import puzzle
from bimgame.learn.actor import RecurrentActor, env_action
from bimgame.learn.maze_runs import network_env_options
from bimgame.learn.teachers import load_labyrinth_teacher

__all__ = ["PolicyTeacher"]


class PolicyTeacher:
    """The greedy actions of a trained labyrinth policy (``source``: its run directory or a checkpoint
    in one) for ``count`` rollouts of ``task`` run side by side with ``action_type`` actions: a
    :class:`~bimgame.learn.dagger.rollouts.Labeller`."""

    #: A policy plans nothing: one forward pass labels every rollout.
    sim_steps_per_label = 0

    def __init__(self, source: str | Path, task: str, action_type: str, count: int):
        net, run = load_labyrinth_teacher(source, task, action_type, "DAggerConfig.teacher")
        teacher_puzzle = puzzle(run.task)
        net.eval()
        self.actor = RecurrentActor(net, count, greedy=True)
        view = teacher_puzzle.env(obs_mode=run.network.obs, action_type=action_type, **network_env_options(run.network))
        assert isinstance(view, LabyrinthEnv)
        view.reset(seed=0)  # observe_state reads only the board and path, never the view's episode
        self.view = view
        self.previous: list[np.ndarray | None] = [None] * count

    @torch.no_grad()
    def labels(
        self,
        envs: Sequence[BallInMazeEnv | LabyrinthEnv],
        infos: list[dict[str, Any]],
        tilt: torch.Tensor,
        active: np.ndarray,
    ) -> list[Any]:
        """The teacher's greedy action (as executed: clipped to [-1, 1]) in each running rollout's
        physics state (``tilt``: the board tilts as the learner reads them, the teacher's input too);
        None where ``active`` is False. One batched pass: rollouts that ended are read in their last
        state, keeping the batch whole."""
        states = [env.sim.get_state() for env in envs]
        observations = [
            self.view.observe_state(state, float(info["progress"]), previous)
            for state, info, previous in zip(states, infos, self.previous, strict=True)
        ]
        self.previous = list(states)
        actions, _, _ = self.actor.act(np.stack(observations), tilt)
        executed = self.actor.executed(actions)
        return [env_action(action) if running else None for action, running in zip(executed, active, strict=True)]

    def observe(self, executed: torch.Tensor, rewards: np.ndarray, done: np.ndarray) -> None:
        """The step's executed actions and rewards: the teacher's inputs at the next step, as if it
        had acted; rollouts that ended start afresh."""
        self.actor.observe(executed, rewards, done)
        for i in map(int, np.flatnonzero(done)):
            self.previous[i] = None

    def close(self) -> None:
        """Close the view env."""
        self.view.close()
