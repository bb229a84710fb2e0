"""The pieces of a reproduction: :class:`Piece`, one unit of work saved in its own directory, and
:func:`plan_pieces`, every piece a :class:`~bimgame.experiments.budgets.Budget` asks for, in the
order they run.

A reproduction directory ``DIR`` holds one directory per piece::

    data/                             the expert dataset (FULL by default: it labels every task)
    pretrain/<TASK>/policy-seed<k>/   π^s, pre-trained on the dataset relabelled for TASK
    pretrain/<TASK>/value-seed<k>/    V̂, the value-only network used as a shaping potential
    runs/<TASK>/<algorithm>/seed<k>/  an A3C, PPO or DAgger run (bimgame.learn.a3c, .ppo, .dagger)

**Pre-training is done per task and per seed**, not once per task: seed k of ``pretrain+a3c``
starts from a π^s trained with seed k (its own initial weights and held-out split), so the spread
over seeds — and the bootstrap intervals of :mod:`bimgame.experiments.report` — include the
variability of pre-training, which is part of the method being compared. On state observations a
pre-training costs seconds; on pixels minutes, still small next to an A3C run.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from bimgame.experiments.algorithms import Learner, algorithm_named
from bimgame.experiments.budgets import Budget

__all__ = [
    "DATASET",
    "PRETRAIN_POLICY",
    "PRETRAIN_VALUE",
    "PIECE_KINDS",
    "Piece",
    "algorithm_slug",
    "policy_path",
    "value_path",
    "run_path",
    "plan_pieces",
]

#: The kinds of the pieces that are not runs of an algorithm (as ``plan.json`` names them).
DATASET, PRETRAIN_POLICY, PRETRAIN_VALUE = "dataset", "pretrain-policy", "pretrain-value"
#: Every piece kind: the dataset, the pre-trainings, then one per learner (an algorithm's runs are
#: pieces of its learner's kind). How each kind is computed is :mod:`bimgame.experiments.kinds`.
PIECE_KINDS = (DATASET, PRETRAIN_POLICY, PRETRAIN_VALUE, *(learner.value for learner in Learner))


@dataclasses.dataclass(frozen=True)
class Piece:
    """One unit of work of a reproduction, saved in its own directory ``path`` (relative to DIR)."""

    id: str
    kind: str
    path: str
    task: str | None = None
    algorithm: str | None = None
    seed: int | None = None
    needs: tuple[str, ...] = ()
    """Ids of the pieces whose outputs this one reads."""

    def to_dict(self) -> dict[str, Any]:
        values = dataclasses.asdict(self)
        values["needs"] = list(self.needs)
        return values


def algorithm_slug(algorithm: str) -> str:
    """The directory name of an algorithm (``pretrain+a3c+value`` → ``pretrain-a3c-value``)."""
    return algorithm_named(algorithm).slug


def policy_path(task: str, seed: int) -> str:
    """Directory (relative to DIR) of the π^s pre-trained for ``task`` with ``seed``."""
    return f"pretrain/{task}/policy-seed{seed}"


def value_path(task: str, seed: int) -> str:
    """Directory (relative to DIR) of the V̂ pre-trained for ``task`` with ``seed``."""
    return f"pretrain/{task}/value-seed{seed}"


def run_path(task: str, algorithm: str, seed: int) -> str:
    """Directory (relative to DIR) of an A3C, PPO or DAgger run."""
    return f"runs/{task}/{algorithm_slug(algorithm)}/seed{seed}"


def plan_pieces(budget: Budget) -> list[Piece]:
    """Every piece of the grid in the order they run: the dataset, then per task and seed the
    pre-trainings that seed needs and its runs (seed 0 of every algorithm before seed 1, so a
    partial reproduction already holds whole comparisons). A run needs what its algorithm's record
    says it reads: the dataset, π^s, V̂ (:class:`~bimgame.experiments.algorithms.Algorithm`)."""
    pieces = [Piece(id="data", kind=DATASET, path="data", task=budget.dataset.task)]
    for task in budget.tasks:
        for seed in range(budget.seeds):
            policy, value = policy_path(task, seed), value_path(task, seed)
            if budget.needs_policy:
                pieces.append(
                    Piece(id=policy, kind=PRETRAIN_POLICY, path=policy, task=task, seed=seed, needs=("data",))
                )
            if budget.needs_value:
                pieces.append(Piece(id=value, kind=PRETRAIN_VALUE, path=value, task=task, seed=seed, needs=("data",)))
            for name in budget.algorithms:
                algorithm = algorithm_named(name)
                path = run_path(task, name, seed)
                needs = tuple(
                    p
                    for p, used in (
                        ("data", algorithm.needs_expert_data),
                        (policy, algorithm.starts_from_policy),
                        (value, algorithm.value_reward),
                    )
                    if used
                )
                pieces.append(
                    Piece(
                        id=path,
                        kind=algorithm.learner.value,
                        path=path,
                        task=task,
                        algorithm=name,
                        seed=seed,
                        needs=needs,
                    )
                )
    return pieces
