"""One episode as a sequence model learns from it: the record that datasets produce
(:func:`bimgame.expert.datasets.iterate_sequences`), that DAgger collects and stores, and that
pre-training batches — with one definition of its fields — and its relabelling for another task.

A recurrent network sees an episode from its first step, with the previous action and reward as
inputs, so the record carries those inputs (``prev_actions``, ``prev_rewards``) next to the targets
(``actions``, ``returns``). Relabelling cuts a FULL episode at the step where an easier task's goal
was reached and recomputes its rewards from the recorded channels with the task rules of
:func:`bimgame.sim.tasks.rewards_from_channels`; a harder task than the episode's cannot be
labelled (its episodes stop too early) and is refused by the callers that know the dataset's task.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from bimgame.envs.env import NO_ACTION
from bimgame.sim.maze import MazeSpec
from bimgame.sim.tasks import Task, parse_task, rewards_from_channels

__all__ = ["Episode", "discounted_returns", "previous_values", "relabel"]


def previous_values(values: np.ndarray, first: Any) -> np.ndarray:
    """``values`` one step later: at each step, the value of the step before (``first`` at t=0) —
    the previous-action and previous-reward inputs of the recurrent networks."""
    out = np.empty_like(values)
    out[:1] = first
    out[1:] = values[:-1]
    return out


def discounted_returns(rewards: np.ndarray, gamma: float) -> np.ndarray:
    """Returns-to-go ``G_t = r_t + gamma * G_{t+1}``, ``G_T = 0`` (float64)."""
    returns = np.empty(len(rewards), dtype=np.float64)
    running = 0.0
    for t in range(len(rewards) - 1, -1, -1):
        running = float(rewards[t]) + gamma * running
        returns[t] = running
    return returns


@dataclasses.dataclass
class Episode:
    """An episode of T steps, every array indexed by step.

    Build one with :meth:`from_steps`, which derives the inputs and targets from what happened, so
    that they always agree."""

    obs: np.ndarray
    """(T, …) the observation each action was taken in: (T, 7·n…) float32 state or (T, 1, 84, 84)
    uint8 pixels."""
    actions: np.ndarray
    """The actions to learn — the expert's (for DAgger: the expert's labels, which may differ from
    what was executed): (T,) int64 discrete actions, or (T, 2) float32 continuous tilt changes (the
    labyrinth's expert, :mod:`bimgame.expert.labyrinth_datasets`)."""
    rewards: np.ndarray
    """(T,) float32: the task's reward after each step."""
    prev_actions: np.ndarray
    """The action executed before each step, as ``actions``: :data:`~bimgame.envs.env.NO_ACTION` at
    t=0 (discrete), zeros (continuous: what a continuous network is fed at an episode's first step,
    :class:`~bimgame.learn.policy_heads.ContinuousActions`)."""
    prev_rewards: np.ndarray
    """(T,) float32: the reward before each step, 0 at t=0."""
    returns: np.ndarray
    """(T,) float32: discounted returns-to-go ``G_t = r_t + γ G_{t+1}``, ``G_T = 0`` (for truncated
    episodes the tail beyond the time limit is taken as 0: check ``truncated``)."""
    tilt: np.ndarray
    """(T, 2) float32: the board tilt (rad) when each action was taken."""
    executed: np.ndarray
    """The actions executed, as ``actions`` (equal to them for expert data)."""
    channels: np.ndarray | None = None
    """(T+1, n) int64: each marble's channel before and after every step (what another task's rewards
    are computed from, see :func:`relabel`); None where not recorded."""
    terminated: bool = False
    truncated: bool = False
    id: int | None = None
    """The episode's index in its dataset."""
    state_obs: np.ndarray | None = None
    """(T, 7·n…) float32: the state observation at each step, whatever ``obs`` is — privileged
    information for auxiliary losses when learning from pixels; None where not recorded."""

    #: The per-step arrays, in the order they are stored (DAgger's ``.npz`` files).
    STEP_FIELDS = ("obs", "actions", "executed", "prev_actions", "prev_rewards", "tilt", "returns", "rewards")

    @classmethod
    def from_steps(
        cls,
        *,
        obs: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        tilt: np.ndarray,
        gamma: float,
        executed: np.ndarray | None = None,
        channels: np.ndarray | None = None,
        terminated: bool = False,
        truncated: bool = False,
        id: int | None = None,
        state_obs: np.ndarray | None = None,
    ) -> Episode:
        """The record of an episode from what happened at each step; ``executed`` defaults to
        ``actions``. Integer actions are discrete ((T,) int64); floating-point ones continuous
        ((T, 2) float32)."""
        continuous = np.issubdtype(np.asarray(actions).dtype, np.floating)
        dtype = np.float32 if continuous else np.int64
        actions = np.asarray(actions, dtype=dtype)
        executed = actions if executed is None else np.asarray(executed, dtype=dtype)
        rewards = np.asarray(rewards, dtype=np.float64)
        return cls(
            obs=np.asarray(obs),
            actions=actions,
            rewards=rewards.astype(np.float32),
            prev_actions=previous_values(executed, 0.0 if continuous else NO_ACTION),
            prev_rewards=previous_values(rewards.astype(np.float32), 0.0),
            returns=discounted_returns(rewards, gamma).astype(np.float32),
            tilt=np.asarray(tilt, dtype=np.float32),
            executed=executed,
            channels=None if channels is None else np.asarray(channels, dtype=np.int64),
            terminated=bool(terminated),
            truncated=bool(truncated),
            id=id,
            state_obs=None if state_obs is None else np.asarray(state_obs, dtype=np.float32),
        )

    def __len__(self) -> int:
        return len(self.actions)

    def window(self, start: int, stop: int) -> Episode:
        """Steps ``start`` to ``stop`` (exclusive) of the episode: its per-step arrays (and state
        observations, if recorded) sliced."""
        return Episode(
            **{name: getattr(self, name)[start:stop] for name in self.STEP_FIELDS},
            state_obs=None if self.state_obs is None else self.state_obs[start:stop],
        )

    def step_arrays(self) -> dict[str, np.ndarray]:
        """The per-step arrays by name (:data:`STEP_FIELDS`)."""
        return {name: getattr(self, name) for name in self.STEP_FIELDS}

    @staticmethod
    def concatenate(episodes: list[Episode]) -> dict[str, np.ndarray]:
        """Episodes as flat arrays plus ``lengths``, for one compressed file (:meth:`split`); their
        ``state_obs`` too when every episode has them."""
        arrays = {name: np.concatenate([getattr(e, name) for e in episodes]) for name in Episode.STEP_FIELDS}
        arrays["lengths"] = np.array([len(e) for e in episodes], dtype=np.int64)
        if episodes and all(e.state_obs is not None for e in episodes):
            arrays["state_obs"] = np.concatenate([e.state_obs for e in episodes])
        return arrays

    @staticmethod
    def split(arrays: dict[str, np.ndarray]) -> list[Episode]:
        """The episodes of :meth:`concatenate`'s arrays; a missing array raises ``KeyError``."""
        bounds = np.concatenate([[0], np.cumsum(arrays["lengths"])])
        episodes = []
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            fields: dict[str, Any] = {name: arrays[name][a:b] for name in Episode.STEP_FIELDS}
            if "state_obs" in arrays:
                fields["state_obs"] = arrays["state_obs"][a:b]
            episodes.append(Episode(**fields))
        return episodes


def relabel(episode: Episode, task: str | Task, gamma: float, spec: MazeSpec | None = None) -> Episode:
    """``episode`` with ``task``'s rewards, returns and end: cut after the step where the task's goal
    was reached, computed from the recorded channels (the rules of
    :func:`bimgame.sim.tasks.task_step`)."""
    spec = spec or MazeSpec.merl()
    task = parse_task(task, spec)
    if episode.channels is None:
        raise ValueError(f"episode {episode.id}: no recorded channels to relabel from")
    channels = np.asarray(episode.channels)
    steps = len(episode)
    if channels.shape[0] != steps + 1:
        raise ValueError(f"episode {episode.id}: channels must have {steps + 1} rows, got {channels.shape[0]}")
    rewards, done = rewards_from_channels(task, spec, channels)
    end = int(np.argmax(done)) + 1 if done.any() else steps
    terminated = bool(done.any())
    rewards = rewards[:end].astype(np.float32)
    return Episode(
        obs=episode.obs[:end],
        actions=episode.actions[:end],
        rewards=rewards,
        prev_actions=episode.prev_actions[:end],
        prev_rewards=previous_values(rewards, 0.0),
        returns=discounted_returns(rewards, gamma).astype(np.float32),
        tilt=episode.tilt[:end],
        executed=episode.executed[:end],
        channels=channels[: end + 1],
        terminated=terminated,
        truncated=not terminated,
        id=episode.id,
        state_obs=None if episode.state_obs is None else episode.state_obs[:end],
    )
