"""How a run's training reward is shaped, and the picklable env wrappers that do it.

Two shapings, which can be combined: the paper's *value function as a reward* (a frozen V̂ from
``bimgame pretrain --value-only`` as the potential of :class:`~bimgame.envs.shaping.PotentialShapedVectorEnv`)
and a dense *geodesic progress* reward (:class:`~bimgame.envs.shaping.GeodesicReward`). The settings
(:class:`RewardSettings`) are stored in the run's ``config.json`` under ``"reward"``, so a resumed run
keeps them; :func:`env_wrapper_for` turns them into the wrapper every learner's environments are
stepped through (A3C's workers, PPO's ranks); :func:`run_reward` does both for a run. The command line
and the reproduction both build their wrappers here. V̂ lives in the learn layer (it is a network of
a pre-training run), which is why this is not in :mod:`bimgame.envs.shaping`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from bimgame.envs.shaping import Chain, GeodesicReward, PotentialShapedVectorEnv, unit_interval
from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.learn.actor import tilt_input
from bimgame.learn.common import load_value_network
from bimgame.learn.learner_settings import refuse_maze_only
from bimgame.learn.nets import ValueNetwork
from bimgame.learn.runs import CONFIG, read_run_config
from bimgame.sim.maze import MazeSpec

__all__ = [
    "EnvWrapper",
    "RewardSettings",
    "ValueFunctionPotential",
    "ValueReward",
    "env_wrapper_for",
    "resolve_reward_settings",
    "run_reward",
    "shaped_env",
]

#: A callable that wraps a learner's vector env (reward shaping: :func:`env_wrapper_for`). It is sent
#: to spawned worker processes, so it must be picklable (a module-level function or an instance of a
#: module-level class).
EnvWrapper = Callable[[BallInMazeVectorEnv], Any]


@dataclasses.dataclass(frozen=True)
class RewardSettings:
    """How the training reward is shaped (both None: the task's own reward)."""

    value_reward: str | None = None
    """A value pre-training run (``bimgame pretrain --value-only``) whose frozen V̂ shapes the reward:
    r + γ V̂(s') − V̂(s)."""
    geodesic_coef: float | None = None
    """Add this many times the geodesic progress towards the centre (per metre) to the reward."""

    def __post_init__(self) -> None:
        if self.value_reward is not None:
            object.__setattr__(self, "value_reward", str(self.value_reward))
        coef = self.geodesic_coef
        if coef is not None and not (isinstance(coef, (int, float)) and math.isfinite(coef) and coef > 0):
            raise ValueError(f"RewardSettings.geodesic_coef must be None or a finite number > 0, got {coef!r}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def describe(self) -> str:
        """``value_reward=…, geodesic_coef=…`` for what is set ("" for the task's reward)."""
        return ", ".join(f"{k}={v}" for k, v in self.to_dict().items() if v is not None)


def resolve_reward_settings(given: RewardSettings, run_dir: str | Path, *, resume: bool) -> RewardSettings:
    """The reward settings of a run: ``given`` for a new run; a resumed run keeps its own, and refuses
    a different one given explicitly."""
    if not resume:
        return given
    stored = _stored_reward_settings(run_dir)
    changed = [k for k, v in given.to_dict().items() if v is not None and v != getattr(stored, k)]
    if changed:
        raise ValueError(f"--resume must keep the run's reward; it was {stored.to_dict()}, got {given.to_dict()}")
    return stored


def _stored_reward_settings(run_dir: str | Path) -> RewardSettings:
    """The ``"reward"`` block of a run's ``config.json`` (none: the task's reward); a malformed one
    raises ``ValueError`` naming the file and the allowed keys."""
    path = Path(run_dir)
    path = (path.parent if path.is_file() else path) / CONFIG
    block = read_run_config(path.parent).get("reward", {})
    allowed = [field.name for field in dataclasses.fields(RewardSettings)]
    refusal = f'{path}: its "reward" settings must be a JSON object with the keys {", ".join(allowed)}'
    if not isinstance(block, dict):
        raise ValueError(f"{refusal}; got {block!r}")
    unknown = sorted(set(block) - set(allowed), key=str)
    if unknown:
        raise ValueError(
            f"{refusal}; got unknown key{'s' if len(unknown) > 1 else ''} {', '.join(repr(key) for key in unknown)}"
        )
    if block.get("value_reward") is not None and not isinstance(block["value_reward"], str):
        raise ValueError(
            f"{refusal}; value_reward must be a run directory (a string) or null, got {block['value_reward']!r}"
        )
    try:
        return RewardSettings(**block)
    except (ValueError, TypeError) as error:
        raise ValueError(f"{refusal}; {error}") from None


class ValueFunctionPotential:
    """Φ(s) = V̂(s) from a value pre-training run (``bimgame pretrain --value-only``), frozen.

    Loaded lazily on first use, so that only the run's path travels to a spawned worker."""

    def __init__(self, run_dir: str):
        self._unloaded(run_dir)

    def _unloaded(self, run_dir: str) -> None:
        """Point at the run in ``run_dir``, nothing loaded yet."""
        self.run_dir = str(run_dir)
        self._net: ValueNetwork | None = None
        self._max_tilt = 1.0

    def load(self) -> ValueFunctionPotential:
        self._network()
        return self

    def _network(self) -> ValueNetwork:
        """V̂, loaded on the first call."""
        if self._net is None:
            self._net, _ = load_value_network(self.run_dir)
            self._max_tilt = MazeSpec.merl().max_tilt
        return self._net

    def __call__(self, obs: np.ndarray, tilt: np.ndarray) -> np.ndarray:
        net = self._network()
        with torch.no_grad():
            tilt_t = tilt_input({"tilt": tilt}, self._max_tilt) if net.config.tilt_input else None
            return net(torch.as_tensor(np.asarray(obs)), tilt_t).numpy()

    def __getstate__(self) -> dict:
        return {"run_dir": self.run_dir}

    def __setstate__(self, state: dict) -> None:
        self._unloaded(state["run_dir"])


@dataclasses.dataclass(frozen=True)
class ValueReward:
    """Picklable factory (an ``a3c.EnvWrapper``): the paper's value function as a reward,
    ``r + γ·V̂(s') − V̂(s)`` with the frozen V̂ of the run in ``run_dir``. V̂ is a network of its
    own, separate from the agent's critic."""

    run_dir: str
    gamma: float = 0.99

    def __post_init__(self) -> None:
        object.__setattr__(self, "run_dir", str(self.run_dir))
        object.__setattr__(self, "gamma", unit_interval("gamma", self.gamma))

    def __call__(self, vector_env: gym.vector.VectorEnv) -> PotentialShapedVectorEnv:
        return PotentialShapedVectorEnv(vector_env, ValueFunctionPotential(self.run_dir), gamma=self.gamma)


def shaped_env(env: Any, wrapper: EnvWrapper | None) -> Any:
    """What a learner steps: ``env`` through its reward shaping ``wrapper`` (None: ``env`` itself).
    Shaping is the circular maze's (:func:`run_reward` refuses it on the labyrinth)."""
    if wrapper is None:
        return env
    assert isinstance(env, BallInMazeVectorEnv)  # refused before any env was made
    return wrapper(env)


def env_wrapper_for(settings: RewardSettings, *, obs: str, gamma: float) -> Chain | None:
    """The picklable env wrapper for ``settings`` (None: the task's reward), checking that V̂ was
    trained on the run's observations."""
    wrappers: list = []
    if settings.geodesic_coef is not None:
        wrappers.append(GeodesicReward(settings.geodesic_coef))
    if settings.value_reward is not None:
        _, value_run = load_value_network(settings.value_reward)
        if value_run.network.obs != obs:
            raise ValueError(
                f"--value-reward {settings.value_reward}: V̂ was trained on {value_run.network.obs} "
                f"observations, this run uses {obs}"
            )
        wrappers.append(ValueReward(settings.value_reward, gamma=gamma))
    return Chain(tuple(wrappers)) if wrappers else None


def run_reward(
    given: RewardSettings, run_dir: str | Path, *, resume: bool, task: str, obs: str, gamma: float
) -> tuple[RewardSettings, Chain | None]:
    """A run's reward settings (``given`` for a new run, its own for a resumed one: see
    :func:`resolve_reward_settings`) and their env wrapper; refuses shaping on a task that is not the
    circular maze's (both shapings read the maze's geodesic distance or a maze V̂)."""
    reward = resolve_reward_settings(given, run_dir, resume=resume)
    refuse_maze_only("RewardSettings", task, {name: value is not None for name, value in reward.to_dict().items()})
    return reward, env_wrapper_for(reward, obs=obs, gamma=gamma)
