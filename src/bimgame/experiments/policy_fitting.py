"""A policy made to play the protocol's env: built-in policies planning in each episode's maze, and
bimgame networks given observations of the size they were trained on (with or without a maze's
encoding, with gate bearings). :func:`~bimgame.experiments.protocol.run_protocol` plays what
:func:`fitted_policy` returns and reports its notes."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.gate_bearings import gate_bearings_size
from bimgame.envs.mazes import maze_encoding, maze_encoding_size
from bimgame.experiments.policy_sources import EpisodePolicy, NetworkPolicy, _Scripted, builtin_policy
from bimgame.expert.policies import Policy, make_policy
from bimgame.sim.maze import MazeSpec

__all__ = ["MazeScriptedPolicy", "fitted_policy", "reads_gate_bearings"]


class MazeScriptedPolicy:
    """A built-in scripted policy (``random``, ``noop``, ``geodesic``, ``expert``) rebuilt for each
    episode, at its first step, for the maze the env shows then: the geodesic controller follows that
    maze's distances and the MPC expert plans in a model of that maze. Its generator is seeded with
    the episode's start seed, as the built-in policies of
    :func:`~bimgame.experiments.policy_sources.builtin_policy` (so on MERL's maze it acts the same)."""

    def __init__(self, name: str):
        builtin_policy(name)  # checks the name
        self.name = name
        self._seed: int | None = None
        self._policy: Policy | None = None

    def reset(self, seed: int) -> None:
        self._seed, self._policy = seed, None

    def act(self, env: Any, obs: np.ndarray, info: dict[str, Any]) -> int:
        if self._policy is None:
            if self._seed is None:
                raise RuntimeError("reset(seed) must be called before the policy acts")
            self._policy = make_policy(self.name, env.unwrapped.maze, np.random.default_rng(self._seed))
        return int(self._policy(env))

    def observe(self, reward: float) -> None:
        pass


class _ObservationsAdapted:
    """A policy acting on its observations changed by ``change`` (the protocol's env gives more or
    fewer values than the policy was trained on)."""

    def __init__(self, policy: EpisodePolicy, change: Callable[[np.ndarray], np.ndarray]):
        self.policy = policy
        self.change = change

    def reset(self, seed: int) -> None:
        self.policy.reset(seed)

    def act(self, env: Any, obs: np.ndarray, info: dict[str, Any]) -> int:
        return self.policy.act(env, self.change(obs), info)

    def observe(self, reward: float) -> None:
        self.policy.observe(reward)


def fitted_policy(policy: EpisodePolicy, env: BallInMazeEnv) -> tuple[EpisodePolicy, list[str]]:
    """``policy`` made to play in ``env``, and notes saying what changed.

    A built-in policy plans in each episode's maze (:class:`MazeScriptedPolicy`). A bimgame network on
    state observations gets what it was trained on: one trained on MERL's maze alone (no maze
    encoding) scored on mazes gets the observations without the encoding — the marble's and the
    board's state as in training, the maze unknown to it, as a pixel network trained on MERL's maze
    sees a new maze (scoring it so measures how a MERL-trained policy transfers to other mazes); one
    trained on many mazes scored on MERL's maze gets MERL's maze's encoding appended, as if MERL's maze
    were one of its mazes. Anything else (SB3 models, callables) gets the env's observations as they
    are."""
    if isinstance(policy, _Scripted):
        return (policy if env.mazes is None else MazeScriptedPolicy(policy.name)), []
    if not isinstance(policy, NetworkPolicy) or env.obs_mode != "state":
        return policy, []
    wanted = int(policy.net.config.obs_shape[0])
    given = int(env.observation_space.shape[0])  # type: ignore[index]  # a Box: its shape is set
    encoding = maze_encoding_size(env.maze)
    if wanted == given:
        return policy, []
    if env.mazes is not None and wanted == given - encoding:
        note = "the network was trained on MERL's maze (no maze encoding): its observations leave the encoding out"
        return _ObservationsAdapted(policy, lambda obs: obs[:-encoding]), [note]
    if env.mazes is None and wanted == given + encoding:
        merl = maze_encoding(env.maze)
        note = "the network was trained on many mazes: its observations end with MERL's maze's encoding"
        return _ObservationsAdapted(policy, lambda obs: np.concatenate([obs, merl])), [note]
    raise ValueError(
        f"the network reads {wanted} values per observation, but the protocol's state observations have {given}"
    )


def reads_gate_bearings(policy: EpisodePolicy) -> bool:
    """Whether ``policy`` is a bimgame network trained on mazes with gate bearings
    (``NetworkSettings.gate_bearings``): its maze inputs are the encoding and the bearings."""
    if not isinstance(policy, NetworkPolicy):
        return False
    board = MazeSpec.merl()
    return policy.net.config.maze_size == maze_encoding_size(board) + gate_bearings_size(board)
