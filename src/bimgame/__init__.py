"""bimgame: the Ball-in-Maze Game on MuJoCo, as Gymnasium environments.

Importing the package registers ``BiMGame/FULL-v0`` and ``BiMGame/STG1-v0`` … ``BiMGame/STG4-v0``.
"""

from __future__ import annotations

import gymnasium as gym

from bimgame.sim.maze import Friction, Gate, MazeSpec, MazeSpecError, Wall
from bimgame.sim.tasks import MAX_EPISODE_STEPS, Task

__version__ = "0.1.0"

__all__ = ["Friction", "Gate", "MazeSpec", "MazeSpecError", "Wall", "Task", "ENV_IDS", "register_envs"]

ENV_IDS = tuple(f"BiMGame/{task.value}-v0" for task in Task)


def register_envs() -> None:
    """Register the five task ids with Gymnasium (idempotent)."""
    for task in Task:
        env_id = f"BiMGame/{task.value}-v0"
        if env_id in gym.registry:
            continue
        gym.register(
            id=env_id,
            entry_point="bimgame.envs.env:BallInMazeEnv",
            vector_entry_point="bimgame.envs.vector:BallInMazeVectorEnv",
            max_episode_steps=MAX_EPISODE_STEPS[task],
            kwargs={"task": task.value},
        )


register_envs()
