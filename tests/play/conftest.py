"""Fixtures of the ``bimgame play`` tests: a tiny trained-looking agent run and a session factory."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.puzzles import puzzle
from bimgame.learn.checkpoints import save_checkpoint
from bimgame.learn.common import NetworkSettings
from bimgame.learn.runs import (
    CHECKPOINT,
    CONFIG,
    KIND_POLICY,
    torch_threads,
)
from bimgame.util.seeding import episode_seed


def _policy_run(run: Path, settings: NetworkSettings, task: str) -> Path:
    """A pre-trained-policy run directory with untrained weights: what ``bimgame pretrain`` writes
    (the network built for ``task``'s board)."""
    run.mkdir()
    with torch_threads(1):
        net = settings.build_policy(0, puzzle(task).spec)
    save_checkpoint(run / CHECKPOINT, model=net.state_dict(), step=0, epoch=0, kind=KIND_POLICY)
    (run / CONFIG).write_text(json.dumps({"kind": KIND_POLICY, "task": task, "seed": 0,
                                          "network": settings.to_dict()}))
    return run


@pytest.fixture(scope="session")
def tiny_agent_run(tmp_path_factory):
    """A pre-trained-policy run directory (untrained weights, state observations, STG1), small
    enough to build in a moment."""
    return _policy_run(tmp_path_factory.mktemp("agent") / "run", NetworkSettings(obs="state", hidden=8, features=8),
                       "STG1")


def seed_with_start_on_x_axis(task: str = "STG1") -> int:
    """A session seed whose first episode starts near the board's x axis (|x| ≫ |y|), where "up" and
    "down" roll the marble along its channel, away from walls."""
    env = BallInMazeEnv(task, obs_mode="state")
    try:
        for seed in range(200):
            obs, _ = env.reset(seed=episode_seed(seed, 0))
            if abs(obs[1]) < 0.15 * abs(obs[0]):
                return seed
    finally:
        env.close()
    raise AssertionError("no start near the x axis in 200 seeds")


@pytest.fixture
def x_axis_seed() -> int:
    return seed_with_start_on_x_axis()


@pytest.fixture(scope="session")
def tiny_pixel_agent_run(tmp_path_factory):
    """Like :func:`tiny_agent_run`, with a pixel network (its observations are rendered from the state)."""
    return _policy_run(tmp_path_factory.mktemp("pixel-agent") / "run",
                       NetworkSettings(obs="pixels", hidden=8, features=8, precision="fp32"), "STG2")


@pytest.fixture(scope="session")
def labyrinth_runs(tmp_path_factory):
    """Tiny untrained policy runs on LABYRINTH-HARD, by (observation, action type): a continuous state
    network (what PPO trains there), a discrete pixel one, a continuous CyberRunner one and a continuous
    state network that reads the marble's surroundings."""
    root = tmp_path_factory.mktemp("labyrinth-agents")
    kinds = [("state", "continuous"), ("pixels", "discrete"), ("cyberrunner", "continuous")]
    runs = {
        (obs, action): _policy_run(root / f"{obs}-{action}",
                                   NetworkSettings(obs=obs, hidden=8, features=8, precision="fp32", action_type=action,
                                                   aux_heads=False),
                                   "LABYRINTH-HARD")
        for obs, action in kinds
    }
    runs["surroundings", "continuous"] = _policy_run(
        root / "surroundings", NetworkSettings(obs="state", hidden=8, features=8, action_type="continuous",
                                               aux_heads=False, surroundings=True), "LABYRINTH-HARD")
    return runs
