"""Episodes of a named scripted policy (:mod:`bimgame.expert.policies`) through the registered
Gymnasium env, with a progress bar: what ``bimgame rollout`` and ``bimgame demo`` run."""

from __future__ import annotations

import time
from typing import Any

import gymnasium as gym
import numpy as np

from bimgame.envs.env import BallInMazeEnv
from bimgame.expert.policies import make_policy
from bimgame.expert.pool import episode_progress

__all__ = ["run_episodes"]


def run_episodes(
    task: str,
    policy_name: str,
    episodes: int,
    *,
    seed: int = 0,
    max_steps: int | None = None,
    n_marbles: int = 1,
    record_first: bool = False,
) -> tuple[list[dict], list[np.ndarray]]:
    """Run ``episodes`` episodes of a named policy (episode i from ``reset(seed=seed + i)``) with a
    progress bar; returns per-episode results (return, length, success, seconds) and the first
    episode's RGB frames if asked."""
    kwargs: dict[str, Any] = {"obs_mode": "state", "n_marbles": n_marbles}
    if record_first:
        kwargs["render_mode"] = "rgb_array"
    if max_steps is not None:
        kwargs["max_episode_steps"] = max_steps
    env = gym.make(f"BiMGame/{task}-v0", **kwargs)
    rng = np.random.default_rng(seed)
    base = env.unwrapped
    if not isinstance(base, BallInMazeEnv):
        raise TypeError(f"BiMGame/{task}-v0 is not a BallInMazeEnv: {type(base).__name__}")
    policy = make_policy(policy_name, base.maze, rng)
    results: list[dict] = []
    frames: list[np.ndarray] = []
    with episode_progress(True, f"{policy_name} on {task}", episodes, transient=True) as update:
        for episode in range(episodes):
            env.reset(seed=seed + episode)
            record = record_first and episode == 0
            if record:
                frames.append(_frame(env))
            total, length, start = 0.0, 0, time.perf_counter()
            while True:
                _, reward, terminated, truncated, info = env.step(policy(env))
                total += float(reward)
                length += 1
                if record:
                    frames.append(_frame(env))
                if terminated or truncated:
                    break
            results.append(
                {
                    "return": total,
                    "length": length,
                    "success": bool(info["is_success"]),
                    "seconds": time.perf_counter() - start,
                }
            )
            update(results[-1]["success"])
    env.close()
    return results, frames


def _frame(env: gym.Env) -> np.ndarray:
    frame = env.render()
    if not isinstance(frame, np.ndarray):
        raise TypeError(f"render() returned {type(frame).__name__}, not an RGB array")
    return frame
