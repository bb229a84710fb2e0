"""Any policy, as the benchmark protocol runs it (:class:`EpisodePolicy`), from what a user names:

- a built-in name: ``random`` (uniform actions, seeded per episode), ``noop``, ``geodesic`` (the
  scripted controller), ``expert`` (the default MPC expert on the simulator state);
- a bimgame run directory or a checkpoint file in one (A3C, PPO, pre-trained π^s, DAgger): the network
  acts greedily (``sampled`` samples, with a generator seeded per episode);
- a Stable-Baselines3 model file (``.zip``), loaded with SB3 when it is installed;
- ``module:callable``: a function (or an object with ``reset()``) taking an observation and
  returning an action.
"""

from __future__ import annotations

import importlib
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar
from typing import Protocol as TypingProtocol

import numpy as np
import torch

from bimgame.expert.policies import POLICIES, Policy, make_policy
from bimgame.learn.actor import RecurrentActor, tilt_input
from bimgame.learn.common import load_run_network
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.policy_heads import require_discrete
from bimgame.sim.maze import MazeSpec

__all__ = ["EpisodePolicy", "load_policy", "builtin_policy", "NetworkPolicy", "CallablePolicy", "SB3Policy"]

#: What a policy builds for each episode in ``reset(seed)``.
_T = TypeVar("_T")

#: The algorithms tried, in order, to load a Stable-Baselines3 model (discrete actions).
_SB3_ALGORITHMS = (
    ("stable_baselines3", "PPO"),
    ("stable_baselines3", "A2C"),
    ("stable_baselines3", "DQN"),
    ("sb3_contrib", "RecurrentPPO"),
)


class EpisodePolicy(TypingProtocol):
    """A policy the protocol runs: ``reset(seed)`` at each episode's start, ``act(env, obs, info)`` for
    each step's action, ``observe(reward)`` after it."""

    def reset(self, seed: int) -> None: ...

    def act(self, env: Any, obs: np.ndarray, info: dict[str, Any]) -> int: ...

    def observe(self, reward: float) -> None: ...


def _started(per_episode: _T | None) -> _T:
    """What a policy builds in ``reset(seed)`` for the episode; acting before it is a usage error."""
    if per_episode is None:
        raise RuntimeError("reset(seed) must be called before the policy acts")
    return per_episode


class _Scripted:
    """A built-in policy of :mod:`bimgame.expert.policies`, rebuilt per episode from its seed."""

    def __init__(self, name: str):
        self.name = name
        self._policy: Policy | None = None

    def reset(self, seed: int) -> None:
        self._policy = make_policy(self.name, MazeSpec.merl(), np.random.default_rng(seed))

    def act(self, env: Any, obs: np.ndarray, info: dict[str, Any]) -> int:
        return int(_started(self._policy)(env))

    def observe(self, reward: float) -> None:
        pass


def builtin_policy(name: str) -> EpisodePolicy:
    """``random``, ``noop``, ``geodesic`` or ``expert``."""
    if name not in POLICIES:
        raise ValueError(f"unknown policy {name!r}; allowed: {', '.join(POLICIES)}")
    return _Scripted(name)


class NetworkPolicy:
    """A bimgame actor-critic acting on its own observations, previous action and reward."""

    def __init__(self, net: RecurrentActorCritic, *, greedy: bool = True):
        self.net = net.eval()
        self.greedy = greedy
        self.max_tilt = MazeSpec.merl().max_tilt
        self._actor: RecurrentActor | None = None

    def reset(self, seed: int) -> None:
        self._actor = RecurrentActor(
            self.net, 1, generator=torch.Generator().manual_seed(int(seed)), greedy=self.greedy
        )
        self._action = torch.zeros(1, dtype=torch.long)

    def act(self, env: Any, obs: np.ndarray, info: dict[str, Any]) -> int:
        tilt = self._tilt(info) if self.net.config.tilt_input else None
        self._action, _, _ = _started(self._actor).act(np.asarray(obs)[None], tilt)
        return int(self._action[0])

    def _tilt(self, info: dict[str, Any]) -> torch.Tensor:
        """The network's tilt input: the maze's current tilt from the step's ``info``."""
        return tilt_input({"tilt": np.asarray(info["tilt"])[None]}, self.max_tilt)

    def observe(self, reward: float) -> None:
        _started(self._actor).observe(self._action, np.array([reward]), np.array([False]))


class CallablePolicy:
    """``function(obs) -> action``; an object with ``reset()`` is reset at each episode's start."""

    def __init__(self, function: Callable[[np.ndarray], Any]):
        self.function = function

    def reset(self, seed: int) -> None:
        if hasattr(self.function, "reset"):
            self.function.reset()

    def act(self, env: Any, obs: np.ndarray, info: dict[str, Any]) -> int:
        return int(np.asarray(self.function(obs)).item())

    def observe(self, reward: float) -> None:
        pass


class SB3Policy:
    """A Stable-Baselines3 model predicting deterministically (recurrent ones keep their state)."""

    def __init__(self, model: Any):
        self.model = model

    def reset(self, seed: int) -> None:
        self._state = None
        self._start = np.ones((1,), dtype=bool)

    def act(self, env: Any, obs: np.ndarray, info: dict[str, Any]) -> int:
        action, self._state = self.model.predict(obs, state=self._state, episode_start=self._start, deterministic=True)
        self._start = np.zeros((1,), dtype=bool)
        return int(np.asarray(action).item())

    def observe(self, reward: float) -> None:
        pass


def _load_sb3(path: Path) -> SB3Policy:
    if not zipfile.is_zipfile(path):
        raise ValueError(f"{path} is not a Stable-Baselines3 model (not a zip file)")
    try:
        importlib.import_module("stable_baselines3")
    except ImportError:
        raise ValueError(
            f"{path} looks like a Stable-Baselines3 model, but stable-baselines3 is not installed; "
            f"install it with: pip install stable-baselines3"
        ) from None
    errors = []
    for module_name, class_name in _SB3_ALGORITHMS:
        try:
            algorithm = getattr(importlib.import_module(module_name), class_name)
        except (ImportError, AttributeError):
            continue
        try:
            return SB3Policy(algorithm.load(str(path), device="cpu"))
        except Exception as error:  # noqa: BLE001 - SB3 raises many kinds; the message lists them all
            errors.append(f"{class_name}: {type(error).__name__}")
    raise ValueError(f"{path}: no Stable-Baselines3 algorithm could load it (tried {', '.join(errors)})")


def _load_callable(spec: str) -> CallablePolicy:
    module_name, _, attribute = spec.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as error:
        raise ValueError(f"POLICY {spec!r}: cannot import module {module_name!r} ({error})") from None
    function = module
    for part in attribute.split("."):
        if not hasattr(function, part):
            raise ValueError(f"POLICY {spec!r}: module {module_name!r} has no {attribute!r}")
        function = getattr(function, part)
    if not callable(function):
        raise ValueError(f"POLICY {spec!r}: {attribute!r} is not callable")
    return CallablePolicy(function)


def load_policy(spec: str, *, obs: str, sampled: bool = False) -> EpisodePolicy:
    """The policy named by ``spec`` (see the module notes); ``obs`` is the protocol's observation mode,
    which a network must have been trained on. Raises ``ValueError`` saying what ``spec`` may be."""
    if spec in POLICIES:
        return builtin_policy(spec)
    path = Path(spec)
    if path.exists():
        if path.suffix == ".zip":
            return _load_sb3(path)
        net, run, _ = load_run_network(path)
        # The benchmark protocol's env takes the paper's discrete actions.
        require_discrete("the benchmark protocol", run.network.action_type, f"evaluate {spec} with bimgame evaluate")
        if run.network.obs != obs:
            raise ValueError(
                f"{spec}: the network was trained on {run.network.obs} observations; score it "
                f"with --obs {run.network.obs}"
            )
        return NetworkPolicy(net, greedy=not sampled)
    if ":" in spec and not spec.startswith(("/", ".")):
        return _load_callable(spec)
    raise ValueError(
        f"POLICY {spec!r} is none of: a built-in policy ({', '.join(POLICIES)}), a bimgame run "
        f"directory or checkpoint, a Stable-Baselines3 model (.zip), or module:callable"
    )
