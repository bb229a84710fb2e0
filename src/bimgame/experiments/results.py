"""The saved results of a reproduction, read back for the report: which pieces are finished, the
logs of each A3C, PPO and DAgger run (``episodes.csv``, ``eval.csv``, ``summary.json``, ``config.json``;
``dagger.csv``, ``dagger_state.json``), their final success rates, and the expert's success rate per
task from its dataset. Reading only: nothing here computes a statistic over seeds or writes a file.
What a run's directory holds is its kind's to read (:meth:`bimgame.experiments.kinds.RunKind.results`;
:class:`~bimgame.experiments.run_logs.RunResults`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bimgame.experiments.algorithms import algorithm_named
from bimgame.experiments.budgets import Budget
from bimgame.experiments.grid import Piece
from bimgame.experiments.kinds import run_kind
from bimgame.experiments.plan import piece_done
from bimgame.experiments.run_logs import FINAL_SHARE, RunResults, final_training_success
from bimgame.expert.datasets import iterate_sequences
from bimgame.expert.episode import Episode, relabel
from bimgame.sim.maze import MazeSpec
from bimgame.sim.tasks import parse_task

__all__ = [
    "FINAL_SHARE",
    "RunResults",
    "finished_pieces",
    "collect_runs",
    "final_training_success",
    "final_eval",
    "dataset_sequences",
    "expert_success_by_task",
]


def finished_pieces(pieces: list[Piece], out_dir: Path, budget: Budget) -> dict[str, Piece]:
    """The finished pieces by id (judged by :func:`~bimgame.experiments.plan.piece_done`)."""
    return {p.id: p for p in pieces if piece_done(p, out_dir, budget)}


def collect_runs(pieces: dict[str, Piece], out_dir: Path, task: str, algorithm: str) -> list[RunResults]:
    """The logs of the runs of ``algorithm`` on ``task`` among ``pieces``, by seed."""
    runs = []
    for piece in pieces.values():
        if piece.task != task or piece.algorithm != algorithm:
            continue
        runs.append(run_kind(algorithm_named(algorithm)).results(piece, out_dir))
    return sorted(runs, key=lambda r: r.seed)


def final_eval(run: RunResults, algorithm: str, mode: str = "greedy") -> float:
    """Success rate of a run's last evaluation, acting ``greedy`` or ``sampled``: an A3C or PPO run's final
    evaluation (summary.json, else the last row of eval.csv), DAgger's after its last iteration."""
    key = f"{mode}_success_rate"
    final = run_kind(algorithm_named(algorithm)).final_evaluation(run)
    if key in final:
        return float(final[key])
    values = run.table.get(key, np.array([]))
    return float(values[-1]) if len(values) else float("nan")


# ------------------------------------------------------------------------------------ the expert
def dataset_sequences(data_dir: Path) -> list[Episode]:
    """The episodes of the reproduction's expert dataset, with state observations."""
    return list(iterate_sequences(data_dir, obs="state"))


def expert_success_by_task(sequences: list[Episode], tasks: Sequence[str]) -> dict[str, float]:
    """The expert's success rate on each task: its dataset episodes relabelled for the task
    (:func:`bimgame.expert.episode.relabel`), a success being the task's goal reached within the task's
    time limit."""
    spec = MazeSpec.merl()
    rates = {}
    for task in tasks:
        limit = parse_task(task).time_limit
        wins = [
            s.terminated and len(s) <= limit for s in (relabel(sequence, task, 0.99, spec) for sequence in sequences)
        ]
        rates[task] = float(np.mean(wins)) if wins else float("nan")
    return rates
