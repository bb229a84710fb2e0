"""The model-based learner's actor: the labyrinth's MPC planning through a
:class:`~bimgame.learn.model_based.marble_model.MarbleModel`, acting on the env's own ``state``
observation (not the simulator's state, which the expert reads), and one episode of it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.expert.labyrinth_mpc import LabyrinthMPC, LabyrinthMPCConfig
from bimgame.learn.model_based.contacts import WallContacts
from bimgame.learn.model_based.marble_law import MarbleLaw
from bimgame.learn.model_based.marble_model import MarbleModel
from bimgame.learn.model_based.transitions import Transitions, marble_state

__all__ = ["ModelBasedAgent", "play_episode", "playable_env"]


def playable_env(env: Any) -> LabyrinthEnv:
    """``env``'s :class:`LabyrinthEnv` if the learner can play it (continuous actions, ``state``
    observations); ``TypeError`` or ``ValueError`` naming what it has otherwise."""
    inner = env.unwrapped
    if not isinstance(inner, LabyrinthEnv):
        raise TypeError(f"env must be a LabyrinthEnv (possibly wrapped), got {type(inner).__name__}")
    if inner.action_type != "continuous" or inner.obs_mode != "state":
        raise ValueError(
            "the model-based learner plays action_type 'continuous' with obs_mode 'state'; the env has "
            f"action_type {inner.action_type!r} and obs_mode {inner.obs_mode!r}"
        )
    return inner


class ModelBasedAgent:
    """Plan each action with the MPC through ``law`` on ``env``'s board (:meth:`for_env`).

    Args:
        planner: the MPC, built on a :class:`MarbleModel` (:meth:`for_env` builds it).
        tilt_step: the env's tilt change (rad) of a full action, to remember the last command.
    """

    def __init__(self, planner: LabyrinthMPC, tilt_step: float):
        if not isinstance(planner.sim, MarbleModel):
            raise TypeError(f"the planner must plan through a MarbleModel, got {type(planner.sim).__name__}")
        self.planner, self.tilt_step = planner, float(tilt_step)
        #: The tilt change (rad, (2,)) of the last action, which the model reads as the servos' lag.
        self.last_change = np.zeros(2)

    @classmethod
    def for_env(
        cls, env: Any, law: MarbleLaw, config: LabyrinthMPCConfig | None = None, *, rng: np.random.Generator
    ) -> ModelBasedAgent:
        """An agent for ``env`` (a :class:`LabyrinthEnv` with continuous actions and ``state``
        observations, possibly wrapped); its planner's draws come from ``rng``."""
        inner = playable_env(env)
        planner = LabyrinthMPC(
            inner.board,
            config,
            rng=rng,
            control_hz=inner.control_hz,
            max_tilt_rate_deg=math.degrees(inner.max_tilt_rate),
            progress_scale=inner.progress_scale,
            goal_bonus=inner.goal_bonus,
            model=MarbleModel(law, WallContacts(inner.board)),
        )
        return cls(planner, inner.tilt_step)

    def reset(self) -> None:
        """A new episode: no last command, no remembered plan."""
        self.last_change = np.zeros(2)
        self.planner.reset()

    def act(self, observation: Any, segment: int) -> np.ndarray:
        """The action (2,) float32 for a ``state`` observation on path ``segment`` (``info["segment"]``)."""
        state = np.concatenate([marble_state(observation), self.last_change])
        action = np.asarray(self.planner.act(state, segment), dtype=np.float32)
        self.last_change = action.astype(np.float64) * self.tilt_step
        return action


def play_episode(
    env: Any, agent: ModelBasedAgent, *, seed: int, max_steps: int, transitions: Transitions | None = None
) -> dict[str, Any]:
    """One episode of ``agent`` on ``env`` from ``reset(seed=seed)``, at most ``max_steps`` steps, adding
    its steps to ``transitions`` if given. Returns ``success``, ``ending`` ("goal", "hole", "off_path" or
    "time"), ``steps``, ``return`` and ``progress_fraction``."""
    obs, info = env.reset(seed=seed)
    agent.reset()
    total, steps, done = 0.0, 0, False
    while steps < max_steps and not done:
        state, previous = marble_state(obs), agent.last_change
        action = agent.act(obs, int(info["segment"]))
        obs, reward, terminated, truncated, info = env.step(action)
        if transitions is not None:
            transitions.add(state, agent.last_change, previous, marble_state(obs))
        total += float(reward)
        steps += 1
        done = terminated or truncated
    success = bool(info["is_success"])
    ending = "goal" if success else "hole" if info["over_hole"] else "off_path" if info["off_path"] else "time"
    return {
        "success": success,
        "ending": ending,
        "steps": steps,
        "return": total,
        "progress_fraction": float(info["progress_fraction"]),
    }
