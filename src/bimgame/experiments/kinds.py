"""The kinds of pieces of a reproduction, one class each behind one interface (:class:`PieceKind`):
how a piece of the kind is computed, whether it is finished, how long it takes and how many CPUs it
keeps busy. The runs of an algorithm are pieces of its learner's kind (:class:`RunKind`), which
also read back what the run logged and the numbers the report takes from it.

Every part of a reproduction that treats pieces differently by kind — the plan, the cost model,
the backends, the cluster, the results, the report — asks the piece's kind (:func:`kind_of`,
:func:`run_kind`) instead of comparing kind names. ``plan.json`` records a piece's kind by its
:attr:`PieceKind.name`.

**Finished.** Decided from a piece's own outputs, never from ``status.json``: a dataset with its
``COMPLETE`` marker, a pre-training with its ``summary.json`` and checkpoint, an A3C or PPO run with
a ``summary.json`` that says it finished its steps (not its checkpoint: one holding all the steps
without a summary is a run stopped during its final evaluation, which a resume finishes), a DAgger
run whose ``dagger_state.json`` counts all its iterations.

**A3C and PPO runs** have the same directory (``episodes.csv``, ``eval.csv``, ``summary.json`` with
its ``final_eval``, ``config.json``) and the same step budget, so they are read back alike
(:class:`StepsRunKind`); they differ in how they are run and what they cost: A3C's worker processes
and evaluator against PPO's one process, which also evaluates.
"""

from __future__ import annotations

import abc
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.experiments.algorithms import Algorithm, Learner
from bimgame.experiments.budgets import Budget
from bimgame.experiments.cost_model import CostModel, compute_rates, eval_seconds
from bimgame.experiments.grid import DATASET, PRETRAIN_POLICY, PRETRAIN_VALUE, Piece
from bimgame.experiments.run_logs import RunResults, final_training_success
from bimgame.experiments.runners import run_a3c, run_dagger, run_dataset, run_ppo, run_pretrain
from bimgame.experiments.statistics import Crossing, dagger_crossing, run_crossing
from bimgame.expert.datasets import DatasetError, dataset_summary
from bimgame.learn.curves import read_table, run_config
from bimgame.sim.tasks import Task
from bimgame.util.files import read_json

__all__ = [
    "PieceKind",
    "RunKind",
    "StepsRunKind",
    "DatasetKind",
    "PretrainPolicyKind",
    "PretrainValueKind",
    "A3CRunKind",
    "PPORunKind",
    "DAggerRunKind",
    "KINDS",
    "kind_of",
    "run_kind",
]


class PieceKind(abc.ABC):
    """What a reproduction needs to know of one kind of piece."""

    name: str
    """The kind as ``plan.json`` and ``status.json`` record it."""
    resumable: bool = False
    """Whether an unfinished piece continues from its directory (its checkpoint, written atomically,
    is the commit point); the others start again. A cluster ships a resumable piece's directory
    home at each checkpoint."""

    @abc.abstractmethod
    def run(self, piece: Piece, budget: Budget, out_dir: Path) -> str:
        """Compute (or continue) ``piece`` in ``out_dir``; returns a note for ``status.json`` ("" when
        there is nothing to say). Raises ``KeyboardInterrupt`` when it stopped before it finished."""

    @abc.abstractmethod
    def done(self, piece: Piece, out_dir: Path, budget: Budget) -> bool:
        """Whether ``piece``'s outputs in ``out_dir`` show it finished (see the module notes)."""

    @abc.abstractmethod
    def seconds(self, piece: Piece, budget: Budget, costs: CostModel) -> float:
        """Expected wall time of ``piece`` on the reference machine."""

    def cpus(self, piece: Piece, budget: Budget) -> int:
        """The CPUs ``piece`` keeps busy, which a cluster reserves for it (by default its torch
        threads, the budget's ``torch_threads``)."""
        return budget.torch_threads


def _training_frames(budget: Budget, task: str, costs: CostModel) -> float:
    """Frames a pre-training trains on: the dataset's steps, 20% held out."""
    return budget.dataset.episodes * costs.expert_steps[task] * 0.8


class DatasetKind(PieceKind):
    """The expert's dataset (:func:`bimgame.expert.datasets.generate_dataset`)."""

    name = DATASET

    def run(self, piece: Piece, budget: Budget, out_dir: Path) -> str:
        return run_dataset(piece, budget, out_dir)

    def done(self, piece: Piece, out_dir: Path, budget: Budget) -> bool:
        try:
            dataset_summary(out_dir / piece.path)
        except (DatasetError, OSError):
            return False
        return True

    def seconds(self, piece: Piece, budget: Budget, costs: CostModel) -> float:
        per_episode = costs.expert_episode_s[budget.dataset.task]
        return costs.piece_overhead_s + budget.dataset.episodes * per_episode / min(budget.dataset.workers, 2)

    def cpus(self, piece: Piece, budget: Budget) -> int:
        """Its expert worker processes."""
        return budget.dataset.workers


class _PretrainKind(PieceKind):
    """A pre-training on the dataset relabelled for the piece's task (not resumable, and cheap)."""

    target: str
    """The library's pre-training target (``policy`` or ``value``)."""

    def run(self, piece: Piece, budget: Budget, out_dir: Path) -> str:
        return run_pretrain(piece, budget, out_dir, self.target)

    def done(self, piece: Piece, out_dir: Path, budget: Budget) -> bool:
        path = out_dir / piece.path
        return (path / "summary.json").is_file() and (path / "checkpoint.pt").is_file()


class PretrainPolicyKind(_PretrainKind):
    """π^s, and its success as a policy on its own."""

    name, target = PRETRAIN_POLICY, "policy"

    def seconds(self, piece: Piece, budget: Budget, costs: CostModel) -> float:
        task, rates = piece.task or budget.dataset.task, compute_rates(budget)
        epochs = min(budget.pretrain.epochs, costs.pretrain_epochs_expected)
        return (
            costs.piece_overhead_s
            + epochs * _training_frames(budget, task, costs) * costs.train_frame_s[rates]
            + eval_seconds(task, rates, budget.pretrain.eval_episodes, costs)
        )


class PretrainValueKind(_PretrainKind):
    """V̂, the value-only network used as a shaping potential."""

    name, target = PRETRAIN_VALUE, "value"

    def seconds(self, piece: Piece, budget: Budget, costs: CostModel) -> float:
        task, rates = piece.task or budget.dataset.task, compute_rates(budget)
        epochs = min(budget.value.epochs, 2 * costs.pretrain_epochs_expected)
        frames = _training_frames(budget, task, costs)
        return costs.piece_overhead_s + epochs * frames * costs.train_frame_s[rates] / 3  # feed-forward


def _run_task(piece: Piece) -> str:
    """The task of run piece ``piece`` (every run piece of a plan has one)."""
    if piece.task is None:
        raise ValueError(f"run piece {piece.id!r} has no task")
    return piece.task


def _run_seed(piece: Piece) -> int:
    """The seed of run piece ``piece`` (every run piece of a plan has one)."""
    if piece.seed is None:
        raise ValueError(f"run piece {piece.id!r} has no seed")
    return piece.seed


class RunKind(PieceKind):
    """The runs of the algorithms of one learner: besides computing them, reading back what they
    logged and the report's numbers from it."""

    learner: Learner
    resumable = True
    training_episodes: bool
    """Whether the run logs its own policy's training episodes (``episodes.csv``) and periodic
    evaluations (``eval.csv``): the report's training curves, final training success and section
    beyond the paper come from them."""

    @abc.abstractmethod
    def results(self, piece: Piece, out_dir: Path) -> RunResults:
        """What the finished run in ``out_dir / piece.path`` logged."""

    @abc.abstractmethod
    def crossing(self, run: RunResults, edges: np.ndarray, threshold: float) -> Crossing:
        """The run's steps to ``threshold`` success (``edges``: the bins of training episodes)."""

    def final_training_success(self, run: RunResults, steps: int) -> float | None:
        """Success of the run's last training episodes (None: it has none of its own)."""
        return final_training_success(run, steps) if self.training_episodes else None

    @abc.abstractmethod
    def final_evaluation(self, run: RunResults) -> dict[str, Any]:
        """The run's final evaluation as recorded apart from its table ({}: its table's last row is it)."""

    @abc.abstractmethod
    def env_steps(self, run: RunResults) -> float | None:
        """The environment steps the run used."""


class StepsRunKind(RunKind):
    """A run of the budget's environment steps for its task that logs its training episodes and
    evaluations in A3C's run directory (A3C's and PPO's): when it is finished and what it logged."""

    training_episodes = True

    def done(self, piece: Piece, out_dir: Path, budget: Budget) -> bool:
        summary = read_json(out_dir / piece.path / "summary.json")
        return (
            summary is not None
            and summary.get("stopped") == "finished"
            and int(summary.get("steps", 0)) >= budget.steps_for(_run_task(piece))
        )

    def results(self, piece: Piece, out_dir: Path) -> RunResults:
        path = out_dir / piece.path
        return RunResults(
            _run_seed(piece),
            path,
            read_table(path / "episodes.csv"),
            read_table(path / "eval.csv"),
            read_json(path / "summary.json"),
            run_config(path),
        )

    def crossing(self, run: RunResults, edges: np.ndarray, threshold: float) -> Crossing:
        return run_crossing(run.episodes, edges, threshold, until=run.until)

    def final_evaluation(self, run: RunResults) -> dict[str, Any]:
        return (run.summary or {}).get("final_eval") or {}

    def env_steps(self, run: RunResults) -> float | None:
        return (run.summary or {}).get("steps")


class A3CRunKind(StepsRunKind):
    """An A3C run (:func:`bimgame.learn.a3c.train`) of the budget's steps for its task."""

    name, learner = Learner.A3C.value, Learner.A3C

    def run(self, piece: Piece, budget: Budget, out_dir: Path) -> str:
        return run_a3c(piece, budget, out_dir)

    def seconds(self, piece: Piece, budget: Budget, costs: CostModel) -> float:
        sps = costs.a3c_sps[compute_rates(budget)] * min(budget.a3c.workers, 2) / 2
        return costs.a3c_overhead_s + budget.steps_for(piece.task or budget.dataset.task) / sps

    def cpus(self, piece: Piece, budget: Budget) -> int:
        """Its workers plus its evaluator process (when it evaluates during training)."""
        return budget.a3c.workers + (1 if budget.a3c.eval_every > 0 else 0)


class PPORunKind(StepsRunKind):
    """A PPO run (:func:`bimgame.learn.ppo.train_ppo`) of the budget's steps for its task, in one
    process: its environments, updates and evaluations on the budget's ``torch_threads``."""

    name, learner = Learner.PPO.value, Learner.PPO

    def run(self, piece: Piece, budget: Budget, out_dir: Path) -> str:
        return run_ppo(piece, budget, out_dir)

    def seconds(self, piece: Piece, budget: Budget, costs: CostModel) -> float:
        """Its steps at PPO's own measured speed (one process: more environments batch the same
        work, they add no CPU), and its evaluations, which stop its training while they run (A3C's
        evaluator process runs beside its workers instead)."""
        task, rates = piece.task or budget.dataset.task, compute_rates(budget)
        steps = budget.steps_for(task)
        evaluations = 1 + (steps // budget.a3c.eval_every if budget.a3c.eval_every > 0 else 0)
        return (
            costs.ppo_overhead_s
            + steps / costs.ppo_sps[rates]
            + evaluations * eval_seconds(task, rates, budget.a3c.eval_episodes, costs)
        )


class DAggerRunKind(RunKind):
    """A DAgger run (:func:`bimgame.learn.dagger.dagger`) of the budget's iterations."""

    name, learner, training_episodes = Learner.DAGGER.value, Learner.DAGGER, False

    def run(self, piece: Piece, budget: Budget, out_dir: Path) -> str:
        return run_dagger(piece, budget, out_dir)

    def done(self, piece: Piece, out_dir: Path, budget: Budget) -> bool:
        state = read_json(out_dir / piece.path / "dagger_state.json")
        return state is not None and int(state.get("iteration", 0)) >= budget.dagger.iterations

    def seconds(self, piece: Piece, budget: Budget, costs: CostModel) -> float:
        task, rates = piece.task or budget.dataset.task, compute_rates(budget)
        seconds = costs.piece_overhead_s
        aggregated = 0.0
        for iteration in range(budget.dagger.iterations):
            # Iteration 0 follows the expert; later ones mostly the learner, whose failures run long.
            length = costs.expert_steps[task] if iteration == 0 else costs.dagger_length_share * Task(task).time_limit
            labels = budget.dagger.episodes * length
            aggregated += labels
            seconds += (
                labels * costs.expert_label_s
                + budget.dagger.epochs * aggregated * costs.train_frame_s[rates]
                + eval_seconds(task, rates, budget.dagger.eval_episodes, costs)
            )
        return seconds

    def results(self, piece: Piece, out_dir: Path) -> RunResults:
        path = out_dir / piece.path
        return RunResults(
            _run_seed(piece), path, {}, read_table(path / "dagger.csv"), read_json(path / "dagger_state.json")
        )

    def crossing(self, run: RunResults, edges: np.ndarray, threshold: float) -> Crossing:
        return dagger_crossing(run.table, threshold)

    def final_evaluation(self, run: RunResults) -> dict[str, Any]:
        return {}

    def env_steps(self, run: RunResults) -> float | None:
        return float(run.table["step"][-1]) if run.table else (run.summary or {}).get("steps")


#: Every piece kind by name: the dataset, the pre-trainings, one run kind per learner.
KINDS: dict[str, PieceKind] = {
    kind.name: kind
    for kind in (
        DatasetKind(),
        PretrainPolicyKind(),
        PretrainValueKind(),
        A3CRunKind(),
        DAggerRunKind(),
        PPORunKind(),
    )
}


def kind_of(piece: Piece) -> PieceKind:
    """The kind of ``piece``; a ValueError naming the kinds there are otherwise."""
    try:
        return KINDS[piece.kind]
    except KeyError:
        raise ValueError(f"unknown piece kind {piece.kind!r}; allowed: {', '.join(KINDS)}") from None


def run_kind(algorithm: Algorithm) -> RunKind:
    """The kind of ``algorithm``'s run pieces (its learner's)."""
    kind = KINDS[algorithm.learner.value]
    assert isinstance(kind, RunKind)
    return kind
