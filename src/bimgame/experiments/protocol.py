"""The benchmark protocol: one fixed way to score any policy on a task, and normalised scores.

**Protocol** (:class:`Protocol`): ``episodes`` episodes (100 by default) of the task, episode i
starting from ``reset(seed=episode_seed(PROTOCOL_SEED, i))`` — the same derivation the expert's
datasets use, so the expert's reference episodes are the protocol's — each under the task's own time
limit. Reported: success rate, mean return, mean length of the solved episodes, each with a
percentile-bootstrap 95% interval over episodes (seeded, so the same policy always gets the same
numbers), and the normalised score.

**Normalised score** (as D4RL and Minari define it): ``100 · (R − R_random) / (R_expert − R_random)``
with R the mean return, R_random that of a uniformly random policy and R_expert that of the MPC
expert with default settings, both measured once with the protocol and stored with the package
(:mod:`bimgame.expert.references`; ``bimgame score --measure-references`` measures them anew). 0 is the
random policy, 100 the expert. Neither reference looks at observations, so one pair serves state
and pixel observations alike.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.observe import OBS_MODES
from bimgame.experiments.policy_sources import EpisodePolicy, builtin_policy, load_policy
from bimgame.experiments.statistics import mean_interval
from bimgame.expert.evaluation import evaluate_expert, summarise
from bimgame.expert.mpc import MPCConfig
from bimgame.expert.references import normalised_score, references_for
from bimgame.sim.tasks import Task, task_setting
from bimgame.util.progress import ProgressBar
from bimgame.util.seeding import episode_seed
from bimgame.util.settings import require_int

__all__ = ["Protocol", "Score", "PROTOCOL_SEED", "PROTOCOL_EPISODES", "score", "run_protocol", "measure_references"]

#: The run seed the protocol's start seeds derive from (fixed: changing it changes every score).
PROTOCOL_SEED = 20_181_105
PROTOCOL_EPISODES = 100
#: Seed of the bootstrap's generator (the intervals are the same for the same episodes).
_BOOTSTRAP_SEED = 0


@dataclasses.dataclass(frozen=True)
class Protocol:
    """Which episodes a policy is scored on."""

    task: str = "STG1"
    """FULL, STG1 … STG4."""
    obs: str = "state"
    """The observations the policy gets: ``state`` or ``pixels``."""
    episodes: int = PROTOCOL_EPISODES
    """Episodes, from the protocol's fixed start seeds (the first ``episodes`` of them)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "task", task_setting("Protocol", self.task))
        if self.obs not in OBS_MODES:
            raise ValueError(f"Protocol.obs must be one of {OBS_MODES}, got {self.obs!r}")
        require_int("Protocol", "episodes", self.episodes, 1)

    @property
    def time_limit(self) -> int:
        return Task(self.task).time_limit

    def start_seeds(self) -> list[int]:
        return [episode_seed(PROTOCOL_SEED, i) for i in range(self.episodes)]


@dataclasses.dataclass
class Score:
    """A policy's result under a :class:`Protocol`."""

    protocol: Protocol
    returns: list[float]
    lengths: list[int]
    successes: list[bool]
    seconds: float

    def summary(self) -> dict[str, Any]:
        """The protocol's numbers with 95% bootstrap intervals, and the normalised score."""
        returns = np.asarray(self.returns, dtype=np.float64)
        successes = np.asarray(self.successes, dtype=np.float64)
        solved = np.asarray([n for n, s in zip(self.lengths, self.successes, strict=True) if s], dtype=np.float64)
        rng = np.random.default_rng(_BOOTSTRAP_SEED)
        out: dict[str, Any] = {
            "task": self.protocol.task,
            "obs": self.protocol.obs,
            "episodes": len(returns),
            "seconds": self.seconds,
        }
        for name, values in (("success_rate", successes), ("mean_return", returns), ("mean_length_solved", solved)):
            out[name] = float(values.mean()) if len(values) else None
            out[f"{name}_ci"] = list(mean_interval(values, rng=rng)) if len(values) else None
        out["normalised_score"] = None
        out["normalised_score_ci"] = None
        if references_for(self.protocol.task) is not None:
            out["normalised_score"] = normalised_score(self.protocol.task, out["mean_return"])
            out["normalised_score_ci"] = [normalised_score(self.protocol.task, v) for v in out["mean_return_ci"]]
        return out


def score(
    policy: str,
    task: str = "STG1",
    *,
    obs: str = "state",
    episodes: int = PROTOCOL_EPISODES,
    sampled: bool = False,
    progress: bool = False,
) -> dict[str, Any]:
    """The protocol's numbers for the policy named by ``policy`` (see
    :func:`~bimgame.experiments.policy_sources.load_policy`): what ``bimgame score`` prints."""
    protocol = Protocol(task=task, obs=obs, episodes=episodes)
    return run_protocol(load_policy(policy, obs=obs, sampled=sampled), protocol, progress=progress).summary()


def run_protocol(policy: EpisodePolicy, protocol: Protocol, *, progress: bool = False) -> Score:
    """Score ``policy`` with ``protocol``: one episode per start seed, in order, on a fresh
    single env with the protocol's observations and the task's time limit."""
    env = BallInMazeEnv(protocol.task, obs_mode=protocol.obs)
    returns: list[float] = []
    lengths: list[int] = []
    successes: list[bool] = []
    started = time.perf_counter()
    try:
        with ProgressBar(
            f"score {protocol.task} {protocol.obs}", protocol.episodes, enabled=progress, transient=True
        ) as bar:
            for seed in protocol.start_seeds():
                total, length, success = _play_episode(env, policy, seed, protocol.time_limit)
                returns.append(total)
                lengths.append(length)
                successes.append(success)
                bar.update(advance=1, info=f"success {np.mean(successes):.0%}")
    finally:
        env.close()
    return Score(protocol, returns, lengths, successes, time.perf_counter() - started)


def _play_episode(env: BallInMazeEnv, policy: EpisodePolicy, seed: int, time_limit: int) -> tuple[float, int, bool]:
    """One episode of ``policy`` from start seed ``seed``, cut at ``time_limit`` steps: its return,
    its length in steps and whether it succeeded."""
    obs, info = env.reset(seed=seed)
    policy.reset(seed)
    total = 0.0
    for step in range(1, time_limit + 1):
        obs, reward, terminated, _, info = env.step(policy.act(env, obs, info))
        policy.observe(reward)
        total += float(reward)
        if terminated:
            return total, step, bool(info["is_success"])
    return total, time_limit, False


def measure_references(
    tasks: list[str], *, episodes: int = PROTOCOL_EPISODES, workers: int | None = None, progress: bool = True
) -> dict[str, Any]:
    """The reference returns measured with the protocol: a uniformly random policy (in process) and
    the default MPC expert (on worker processes, same start seeds), per task."""
    out: dict[str, Any] = {
        "protocol_seed": PROTOCOL_SEED,
        "episodes": episodes,
        "expert": MPCConfig().__dict__,
        "tasks": {},
    }
    for task in tasks:
        protocol = Protocol(task=task, obs="state", episodes=episodes)
        random = run_protocol(builtin_policy("random"), protocol, progress=progress).summary()
        expert = evaluate_expert(task, episodes, seed=PROTOCOL_SEED, workers=workers, progress=progress)
        expert_summary = summarise(expert)
        out["tasks"][protocol.task] = {
            "random": random["mean_return"],
            "expert": expert_summary["mean_return"],
            "random_success_rate": random["success_rate"],
            "expert_success_rate": expert_summary["success_rate"],
        }
    return out
