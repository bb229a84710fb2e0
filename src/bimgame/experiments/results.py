"""The saved results of a reproduction, read back for the report: which pieces are finished, the
logs of each A3C and DAgger run (``episodes.csv``, ``eval.csv``, ``summary.json``, ``config.json``;
``dagger.csv``, ``dagger_state.json``), their final success rates, and the expert's success rate per
task from its dataset. Reading only: nothing here computes a statistic over seeds or writes a file.

An A3C run's training episodes count only where every episode that started has ended and is in its
log (:attr:`RunResults.until`, see :mod:`bimgame.learn.curves`): the log's last stretch holds the
short, successful episodes that started there but not the long ones still running when it stopped.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from bimgame.experiments.budgets import Budget
from bimgame.experiments.grid import Piece
from bimgame.experiments.plan import piece_done
from bimgame.expert.datasets import iterate_sequences
from bimgame.expert.episode import Episode, relabel
from bimgame.learn.curves import complete_until, episode_span, finished_at, read_table, run_config
from bimgame.sim.maze import MazeSpec
from bimgame.sim.tasks import parse_task
from bimgame.util.files import read_json

__all__ = ["FINAL_SHARE", "RunResults", "finished_pieces", "collect_runs", "final_training_success", "final_eval",
           "dataset_sequences", "expert_success_by_task"]

#: Share of a run's steps whose training episodes give its "final" success rate.
FINAL_SHARE = 0.1


@dataclasses.dataclass
class RunResults:
    """What a finished A3C or DAgger run logged, as read back from its directory."""

    seed: int
    path: Path
    episodes: dict[str, np.ndarray]
    table: dict[str, np.ndarray]
    """eval.csv (A3C) or dagger.csv (DAgger)."""
    summary: dict[str, Any] | None
    config: dict[str, Any] = dataclasses.field(default_factory=dict)
    """config.json (A3C; {} when there is none)."""

    @functools.cached_property
    def span(self) -> float:
        """The most environment steps one training episode can take from its start to its logged end
        (:func:`bimgame.learn.curves.episode_span`)."""
        return episode_span(self.episodes, self.config)

    @functools.cached_property
    def until(self) -> float:
        """Every training episode that started before this step has ended and is in the log
        (:func:`bimgame.learn.curves.complete_until`)."""
        return complete_until(self.episodes, self.span, finished_at=finished_at(self.summary))


def finished_pieces(pieces: list[Piece], out_dir: Path, budget: Budget) -> dict[str, Piece]:
    """The finished pieces by id (judged by :func:`~bimgame.experiments.plan.piece_done`)."""
    return {p.id: p for p in pieces if piece_done(p, out_dir, budget)}


def collect_runs(pieces: dict[str, Piece], out_dir: Path, task: str, algorithm: str) -> list[RunResults]:
    """The logs of the runs of ``algorithm`` on ``task`` among ``pieces``, by seed."""
    runs = []
    for piece in pieces.values():
        if piece.task != task or piece.algorithm != algorithm:
            continue
        path = out_dir / piece.path
        if piece.kind == "dagger":
            runs.append(RunResults(piece.seed, path, {}, read_table(path / "dagger.csv"),
                                   read_json(path / "dagger_state.json")))
        else:
            runs.append(RunResults(piece.seed, path, read_table(path / "episodes.csv"),
                                   read_table(path / "eval.csv"), read_json(path / "summary.json"), run_config(path)))
    return sorted(runs, key=lambda r: r.seed)


def final_training_success(run: RunResults, steps: int) -> float:
    """Success rate of the training episodes that started in the last :data:`FINAL_SHARE` of a run's
    ``steps`` before :attr:`RunResults.until` — the latest stretch of that length whose episodes
    have all ended — (NaN when there are none)."""
    if not run.episodes:
        return float("nan")
    end = min(run.until, float(steps))
    start = run.episodes["start_step"]
    late = (start >= end - FINAL_SHARE * steps) & (start < end)
    return float(np.mean(run.episodes["success"][late])) if late.any() else float("nan")


def final_eval(run: RunResults, algorithm: str, mode: str = "greedy") -> float:
    """Success rate of a run's last evaluation, acting ``greedy`` or ``sampled``: an A3C run's final
    evaluation (summary.json, else the last row of eval.csv), DAgger's after its last iteration."""
    key = f"{mode}_success_rate"
    final = {} if algorithm == "dagger" else (run.summary or {}).get("final_eval") or {}
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
        wins = [s.terminated and len(s) <= limit
                for s in (relabel(sequence, task, 0.99, spec) for sequence in sequences)]
        rates[task] = float(np.mean(wins)) if wins else float("nan")
    return rates
