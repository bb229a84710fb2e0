"""bimgame: the Ball-in-Maze Game on MuJoCo, as Gymnasium environments.

Importing the package registers ``BiMGame/FULL-v0`` and ``BiMGame/STG1-v0`` … ``BiMGame/STG4-v0`` (the
circular maze's tasks, :data:`ENV_IDS`) and CyberRunner's labyrinth, ``BiMGame/Labyrinth-Easy-v0``,
``-Medium-v0`` and ``-Hard-v0`` (:data:`LABYRINTH_ENV_IDS`).
"""

from __future__ import annotations

import gymnasium as gym

from bimgame.sim.maze import Friction, Gate, MazeSpec, MazeSpecError, Wall
from bimgame.sim.tasks import MAX_EPISODE_STEPS, Task

__version__ = "0.1.0"

__all__ = [
    "Friction",
    "Gate",
    "MazeSpec",
    "MazeSpecError",
    "Wall",
    "Task",
    "ENV_IDS",
    "LABYRINTH_ENV_IDS",
    "register_envs",
]

ENV_IDS = tuple(f"BiMGame/{task.value}-v0" for task in Task)
#: The labyrinth's ids: a separate tuple, since code iterating ENV_IDS means the circular maze's tasks.
LABYRINTH_ENV_IDS = tuple(f"BiMGame/Labyrinth-{layout}-v0" for layout in ("Easy", "Medium", "Hard"))
#: The labyrinth's time limit at its default 55 Hz: CyberRunner's 3000 steps (see LabyrinthEnv).
LABYRINTH_MAX_EPISODE_STEPS = 3000


def register_envs() -> None:
    """Register the five task ids and the three labyrinth ids with Gymnasium (idempotent)."""
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
    for env_id in LABYRINTH_ENV_IDS:
        if env_id not in gym.registry:
            gym.register(
                id=env_id,
                entry_point="bimgame.envs.labyrinth_env:LabyrinthEnv",
                max_episode_steps=LABYRINTH_MAX_EPISODE_STEPS,
                kwargs={"layout": env_id.split("-")[1].lower()},
            )


register_envs()
