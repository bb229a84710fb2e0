"""A network's evaluation on its task: greedy and sampled episodes from the same start positions, as
every learner (A3C, PPO, pre-training, DAgger) logs it."""

from __future__ import annotations

from typing import Any

from bimgame.learn.actor import evaluate_network
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.util.seeding import episode_seed

__all__ = ["evaluation_seed", "EVAL_COLUMNS", "evaluate_greedy_and_sampled"]


def evaluation_seed(seed: int) -> int:
    """Seed of the start positions of a run's evaluations, derived from the run's seed (the same
    every time, different from the training episodes' starts)."""
    return episode_seed(seed, 999_983)


#: The keys of :func:`evaluate_greedy_and_sampled`, in the order the learners' logs list them.
EVAL_COLUMNS = tuple(
    f"{mode}_{key}" for mode in ("greedy", "sampled") for key in ("success_rate", "mean_length", "mean_return")
)


def evaluate_greedy_and_sampled(
    net: RecurrentActorCritic,
    *,
    task: str,
    obs: str,
    episodes: int,
    seed: int,
    time_limit: int | None = None,
    mazes: dict[str, Any] | None = None,
) -> dict[str, float]:
    """Success rate, mean length and return of ``net`` on ``task``, acting greedily and sampling (keys
    ``greedy_…``, ``sampled_…``), over the same ``episodes`` start positions (and mazes: ``mazes``,
    env arguments such as ``num_mazes``) from ``seed``."""
    values: dict[str, float] = {}
    for mode, greedy in (("greedy", True), ("sampled", False)):
        result = evaluate_network(
            net,
            task=task,
            obs_mode=obs,
            episodes=episodes,
            seed=seed,
            greedy=greedy,
            max_episode_steps=time_limit,
            mazes=mazes,
        )
        values.update({f"{mode}_{k}": v for k, v in result.summary().items() if k != "episodes"})
    return values
