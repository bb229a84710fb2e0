"""Reward shaping wrappers: potential-based shaping (a value function as a reward) and a dense
geodesic-progress reward, for vector envs and the single env.

Design notes:

* **Potential-based shaping keeps the optimal policies.** Adding ``F = γ·Φ(s') − Φ(s)`` to every
  reward changes each discounted return from a state ``s`` by exactly ``−Φ(s)`` (the sum
  telescopes), whatever the actions, so every policy's Q-values shift by the same function of the
  state and the ordering of actions — hence the optimal policies — is unchanged (Ng, Harada &
  Russell, "Policy invariance under reward transformations", ICML 1999). With ``Φ`` a learned
  value function (the paper's "value function as a reward"), the agent gets the value's
  step-to-step change as an immediate reward instead of waiting for sparse gate crossings.
* **Terminal states have Φ = 0; truncated ones keep Φ(s').** The invariance argument needs the
  potential of an absorbing terminal state to be 0 (its value is 0: nothing follows it).
  A time limit is not part of the task: the state where the clock ran out still has a future, so
  its true potential ``Φ(final_obs)`` is used, exactly as the learners bootstrap ``V(final_obs)``
  at truncations.
* **Why SAME_STEP autoreset.** ``Φ(s')`` at an episode's end needs the episode's last observation.
  With SAME_STEP autoreset every step is a real transition and that observation is in
  ``infos["final_obs"]`` (its info in ``infos["final_info"]``); NEXT_STEP mode would need a
  special reset step with no transition. The vector wrappers reject other modes.
* **``task_reward`` is kept.** Shaped rewards are not the task's score, and a learning curve of
  them cannot be compared between shaping variants or with the unshaped baseline. Every wrapper
  here puts the task's own reward in ``info["task_reward"]`` unless a wrapper below it already
  did, so stacked wrappers keep the innermost, true task reward. ``info["shaping"]`` holds the
  total added by all shaping wrappers, so ``reward == task_reward + shaping`` always.
* **Geodesic progress is a reward for progress, not a potential.** ``coef·(d(s) − d(s'))`` with
  ``d`` the geodesic distance to the task's goal is potential shaping with ``Φ = −coef·d`` and ``γ = 1``
  except at termination: there ``d(s')`` is the real final distance rather than a zeroed
  potential, so the reward for an episode is always ``coef·(d_start − d_end)``, the distance
  actually travelled towards the goal.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode

from bimgame.util.settings import is_real

__all__ = [
    "Potential",
    "PotentialShapedVectorEnv",
    "GeodesicProgressVectorEnv",
    "GeodesicProgressReward",
    "GeodesicReward",
    "Chain",
    "DEFAULT_GEODESIC_COEF",
    "unit_interval",
]

#: The info the geodesic reward reads: each marble's geodesic distance to the task's goal (m).
DISTANCE_KEY = "goal_distance"
#: Reward per metre of geodesic progress towards the centre. The trip from the outer channel to the
#: centre is about 0.3–0.5 m, so it is worth a few units, like FULL's four gate crossings.
DEFAULT_GEODESIC_COEF = 10.0

#: ``potential(obs_batch, tilt_batch)`` → (B,) float: Φ of each observation, given the board's tilt
#: (rad, shape (B, 2)) from ``infos["tilt"]``.
Potential = Callable[[np.ndarray, np.ndarray], np.ndarray]


class PotentialShapedVectorEnv(gym.vector.VectorWrapper):
    """Potential-based reward shaping: ``r̄ = r + γ·Φ(s') − Φ(s)`` (Ng et al. 1999).

    ``Φ(s')`` is 0 where the episode terminated and ``Φ(final_obs)`` where it was truncated (see
    the module notes). Infos gain ``task_reward`` (the unshaped reward, unless already present)
    and ``shaping`` (the total shaping term), both (B,) float64.

    Args:
        env: a vector env in SAME_STEP autoreset mode.
        potential: ``potential(obs_batch, tilt_batch_radians)`` → (B,) finite floats. Called at most
            twice per step: on the returned observations and on the final observations of the
            episodes that ended.
        gamma: the learner's discount factor, in [0, 1].
    """

    def __init__(self, env: gym.vector.VectorEnv, potential: Potential, gamma: float):
        super().__init__(env)
        _require_same_step(env, type(self).__name__, "Φ(s') at an episode's end is computed from infos['final_obs']")
        if not callable(potential):
            raise TypeError(
                f"potential must be callable as potential(obs_batch, tilt_batch), got {type(potential).__name__}"
            )
        self.potential = potential
        self.gamma = unit_interval("gamma", gamma)
        self._phi: np.ndarray | None = None

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        # VectorEnv.reset is annotated with one seed; Gymnasium's vector envs and ours take a list too.
        obs, infos = self.env.reset(seed=seed, options=options)  # type: ignore[arg-type]
        self._phi = self._evaluate(obs, infos["tilt"], "the reset observations")
        return obs, infos

    def step(self, actions):
        if self._phi is None:
            raise RuntimeError("call reset() before step()")
        obs, reward, terminated, truncated, infos = self.env.step(actions)
        terminated = np.asarray(terminated, dtype=bool)
        phi_now = self._evaluate(obs, infos["tilt"], "the returned observations")
        phi_next = phi_now.copy()
        ended = _ended(terminated, truncated, infos)
        if ended.size:
            final_obs = _rows(infos["final_obs"], ended)
            final_tilt = _rows(infos["final_info"]["tilt"], ended)
            phi_next[ended] = self._evaluate(final_obs, final_tilt, "the final observations", len(ended))
        phi_next[terminated] = 0.0
        shaping = self.gamma * phi_next - self._phi
        self._phi = phi_now  # for ended envs: the new episode's first observation
        return obs, _add_shaping(reward, shaping, infos), terminated, truncated, infos

    def _evaluate(self, obs: Any, tilt: Any, what: str, count: int | None = None) -> np.ndarray:
        count = self.num_envs if count is None else count
        values = np.asarray(self.potential(obs, np.asarray(tilt, dtype=np.float64)), dtype=np.float64)
        if values.shape != (count,):
            raise ValueError(
                f"potential returned shape {values.shape} for {what}; expected ({count},), one value per observation"
            )
        if not np.all(np.isfinite(values)):
            raise ValueError(f"potential returned non-finite values for {what}: {values.tolist()}")
        return values


class GeodesicProgressVectorEnv(gym.vector.VectorWrapper):
    """Dense geodesic-progress reward: ``r̄ = r + coef·(d(s) − d(s'))``.

    ``d`` is ``infos["goal_distance"]`` summed over marbles (m, the shortest path through the gates
    until the task's goal wall is passed: to the centre for FULL, into the next channel for STG1).
    Progress is measured to the task's goal, not the centre: the outer wall's gate on the centre's
    shortest path is often not the one nearest the marble (on 16% of the outer channel of a random
    maze the two point opposite ways), and an STG task ends at its last wall. At an episode's end
    ``d(s')`` comes from ``infos["final_info"]`` — also at termination, where it is the real final
    distance, not zeroed (a reward for progress, not a potential; see the module notes). Infos gain
    ``task_reward`` and ``shaping`` as :class:`PotentialShapedVectorEnv`'s.

    Args:
        env: a vector env in SAME_STEP autoreset mode whose infos have ``goal_distance``.
        coef: reward per metre of progress, finite and > 0.
    """

    def __init__(self, env: gym.vector.VectorEnv, coef: float = DEFAULT_GEODESIC_COEF):
        super().__init__(env)
        _require_same_step(env, type(self).__name__, "d(s') at an episode's end is read from infos['final_info']")
        self.coef = _positive_finite("coef", coef)
        self._distance: np.ndarray | None = None

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        # VectorEnv.reset is annotated with one seed; Gymnasium's vector envs and ours take a list too.
        obs, infos = self.env.reset(seed=seed, options=options)  # type: ignore[arg-type]
        self._distance = _total_distance(infos)
        return obs, infos

    def step(self, actions):
        if self._distance is None:
            raise RuntimeError("call reset() before step()")
        obs, reward, terminated, truncated, infos = self.env.step(actions)
        distance_now = _total_distance(infos)
        distance_next = distance_now.copy()
        ended = _ended(terminated, truncated, infos)
        if ended.size:
            distance_next[ended] = _total_distance(infos["final_info"], ended)
        shaping = self.coef * (self._distance - distance_next)
        self._distance = distance_now  # for ended envs: the new episode's start
        return obs, _add_shaping(reward, shaping, infos), terminated, truncated, infos


class GeodesicProgressReward(gym.Wrapper):
    """:class:`GeodesicProgressVectorEnv`'s reward for the single env:
    ``r̄ = r + coef·(d(s) − d(s'))`` from ``info["goal_distance"]``; ``info`` gains
    ``task_reward`` (unless present) and ``shaping`` (floats).

    Args:
        env: an env whose infos have ``goal_distance`` ((n_marbles,) metres).
        coef: reward per metre of progress, finite and > 0.
    """

    def __init__(self, env: gym.Env, coef: float = DEFAULT_GEODESIC_COEF):
        super().__init__(env)
        self.coef = _positive_finite("coef", coef)
        self._distance: float | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._distance = float(np.sum(info[DISTANCE_KEY]))
        return obs, info

    def step(self, action):
        if self._distance is None:
            raise RuntimeError("call reset() before step()")
        obs, reward, terminated, truncated, info = self.env.step(action)
        distance = float(np.sum(info[DISTANCE_KEY]))
        shaping = self.coef * (self._distance - distance)
        self._distance = distance
        info.setdefault("task_reward", float(reward))
        info["shaping"] = float(info.get("shaping", 0.0)) + shaping
        return obs, float(reward) + shaping, terminated, truncated, info


@dataclasses.dataclass(frozen=True)
class GeodesicReward:
    """Picklable factory (an ``a3c.EnvWrapper``, sent to spawned workers) that wraps a SAME_STEP
    vector env in :class:`GeodesicProgressVectorEnv` with ``coef`` reward per metre."""

    coef: float = DEFAULT_GEODESIC_COEF

    def __post_init__(self) -> None:
        object.__setattr__(self, "coef", _positive_finite("coef", self.coef))

    def __call__(self, vector_env: gym.vector.VectorEnv) -> GeodesicProgressVectorEnv:
        return GeodesicProgressVectorEnv(vector_env, coef=self.coef)


@dataclasses.dataclass(frozen=True)
class Chain:
    """Picklable composition of env wrappers, applied left (innermost) to right."""

    wrappers: tuple

    def __call__(self, vector_env: gym.vector.VectorEnv) -> gym.vector.VectorEnv:
        for wrapper in self.wrappers:
            vector_env = wrapper(vector_env)
        return vector_env


# ---------------------------------------------------------------------- helpers
def _require_same_step(env: gym.vector.VectorEnv, wrapper: str, why: str) -> None:
    """Raise ``ValueError`` unless ``env`` autoresets in SAME_STEP mode (as ``metadata`` says)."""
    mode = env.metadata.get("autoreset_mode", getattr(env.unwrapped, "autoreset_mode", None))
    if isinstance(mode, str):
        try:
            mode = AutoresetMode(mode)
        except ValueError:
            pass
    if mode != AutoresetMode.SAME_STEP:
        shown = mode.name if isinstance(mode, AutoresetMode) else repr(mode)
        raise ValueError(
            f"{wrapper} needs a vector env with autoreset_mode SAME_STEP, got {shown}: {why}, which "
            "only SAME_STEP autoreset provides. Create the env with autoreset_mode='same_step' "
            "(allowed: SAME_STEP only)."
        )


def _ended(terminated: Any, truncated: Any, infos: dict[str, Any]) -> np.ndarray:
    """Indices of the envs whose episode ended this step; checks the final observations are there."""
    ended = np.flatnonzero(np.asarray(terminated, dtype=bool) | np.asarray(truncated, dtype=bool))
    if ended.size:
        mask = infos.get("_final_obs")
        if mask is None or "final_info" not in infos or not np.all(np.asarray(mask)[ended]):
            raise RuntimeError(
                f"envs {ended.tolist()} ended but infos lack their final_obs/final_info; "
                "the wrapped env does not autoreset in SAME_STEP mode"
            )
    return ended


def _rows(values: Any, index: np.ndarray) -> np.ndarray:
    """``values[index]`` as one array: Gymnasium's Sync/AsyncVectorEnv give ``final_obs`` as an
    object array of per-env observations, BallInMazeVectorEnv as a batched array."""
    values = np.asarray(values)
    if values.dtype == object:
        return np.stack([np.asarray(v) for v in values[index]])
    return values[index]


def _total_distance(infos: dict[str, Any], index: np.ndarray | None = None) -> np.ndarray:
    """Geodesic distance to the task's goal (m) summed over marbles, per env (only ``index``'s envs
    if given)."""
    if DISTANCE_KEY not in infos:
        raise KeyError(
            f"infos have no {DISTANCE_KEY!r} (B, n_marbles); the geodesic reward needs BallInMazeVectorEnv's infos"
        )
    distance = infos[DISTANCE_KEY]
    distance = _rows(distance, index) if index is not None else np.asarray(distance)
    return np.asarray(distance, dtype=np.float64).reshape(len(distance), -1).sum(axis=1)


def _add_shaping(reward: Any, shaping: np.ndarray, infos: dict[str, Any]) -> np.ndarray:
    """Shaped reward; records the task reward (innermost wins) and the total shaping in ``infos``."""
    reward = np.asarray(reward, dtype=np.float64)
    every_env = np.ones(len(reward), dtype=bool)  # Gymnasium's per-key "_key" masks
    if "task_reward" not in infos:
        infos["task_reward"], infos["_task_reward"] = reward.copy(), every_env
    infos["shaping"] = np.asarray(infos.get("shaping", 0.0), dtype=np.float64) + shaping
    infos["_shaping"] = every_env.copy()
    return reward + shaping


def unit_interval(name: str, value: SupportsFloat) -> float:
    if not (is_real(value) and 0.0 <= float(value) <= 1.0):
        raise ValueError(f"{name} must be a number in [0, 1], got {value!r}")
    return float(value)


def _positive_finite(name: str, value: SupportsFloat) -> float:
    if not (is_real(value) and math.isfinite(float(value)) and float(value) > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return float(value)
