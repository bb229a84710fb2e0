"""The pieces of a reproduction: :class:`Piece`, one unit of work saved in its own directory, and
:func:`plan_pieces`, every piece a :class:`~bimgame.experiments.budgets.Budget` asks for, in the
order they run.

A reproduction directory ``DIR`` holds one directory per piece::

    data/                             the expert dataset (FULL by default: it labels every task)
    pretrain/<TASK>/policy-seed<k>/   π^s, pre-trained on the dataset relabelled for TASK
    pretrain/<TASK>/value-seed<k>/    V̂, the value-only network used as a shaping potential
    runs/<TASK>/<algorithm>/seed<k>/  an A3C run (bimgame.learn.a3c) or a DAgger run (bimgame.learn.dagger)

**Pre-training is done per task and per seed**, not once per task: seed k of ``pretrain+a3c``
starts from a π^s trained with seed k (its own initial weights and held-out split), so the spread
over seeds — and the bootstrap intervals of :mod:`bimgame.experiments.report` — include the
variability of pre-training, which is part of the method being compared. On state observations a
pre-training costs seconds; on pixels minutes, still small next to an A3C run.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from bimgame.experiments.budgets import Budget, uses_policy, uses_value
from bimgame.experiments.methods import needs_expert_data

__all__ = ["PIECE_KINDS", "Piece", "algorithm_slug", "policy_path", "value_path", "run_path", "plan_pieces"]

PIECE_KINDS = ("dataset", "pretrain-policy", "pretrain-value", "a3c", "dagger")


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
    return algorithm.replace("+", "-")


def policy_path(task: str, seed: int) -> str:
    """Directory (relative to DIR) of the π^s pre-trained for ``task`` with ``seed``."""
    return f"pretrain/{task}/policy-seed{seed}"


def value_path(task: str, seed: int) -> str:
    """Directory (relative to DIR) of the V̂ pre-trained for ``task`` with ``seed``."""
    return f"pretrain/{task}/value-seed{seed}"


def run_path(task: str, algorithm: str, seed: int) -> str:
    """Directory (relative to DIR) of an A3C or DAgger run."""
    return f"runs/{task}/{algorithm_slug(algorithm)}/seed{seed}"


def plan_pieces(budget: Budget) -> list[Piece]:
    """Every piece of the grid in the order they run: the dataset, then per task and seed the
    pre-trainings that seed needs and its runs (seed 0 of every algorithm before seed 1, so a
    partial reproduction already holds whole comparisons). A run needs the dataset piece when its
    algorithm reads the expert's data (:func:`~bimgame.experiments.methods.needs_expert_data`)."""
    pieces = [Piece(id="data", kind="dataset", path="data", task=budget.dataset_task)]
    for task in budget.tasks:
        for seed in range(budget.seeds):
            policy, value = policy_path(task, seed), value_path(task, seed)
            if budget.needs_policy:
                pieces.append(Piece(id=policy, kind="pretrain-policy", path=policy, task=task, seed=seed,
                                    needs=("data",)))
            if budget.needs_value:
                pieces.append(Piece(id=value, kind="pretrain-value", path=value, task=task, seed=seed,
                                    needs=("data",)))
            for algorithm in budget.algorithms:
                path = run_path(task, algorithm, seed)
                if algorithm == "dagger":
                    pieces.append(Piece(id=path, kind="dagger", path=path, task=task, algorithm=algorithm, seed=seed))
                    continue
                needs = tuple(p for p, used in (("data", needs_expert_data(algorithm)),
                                                (policy, uses_policy(algorithm)), (value, uses_value(algorithm)))
                              if used)
                pieces.append(Piece(id=path, kind="a3c", path=path, task=task, algorithm=algorithm, seed=seed,
                                    needs=needs))
    return pieces
