"""Figures, statistics and ``report.md`` of a reproduction directory (:mod:`bimgame.experiments.reproduce`),
rebuilt from the saved results alone: ``bimgame report DIR``.

Outputs in DIR:

- ``fig_curves_<TASK>.png`` — the paper's Fig. 2: mean episode return (the task's own reward, also
  for shaped runs) and success rate of the training episodes against environment steps, one line
  per algorithm, the mean over seeds with a bootstrap 95% band (:mod:`bimgame.experiments.figures`).
- ``fig_expert_lengths.png`` — the paper's Fig. 1b: lengths of the expert's dataset episodes.
- ``fig_eval_<TASK>.png`` — beyond the paper (a grid with a fine-tuning method, STG3 or STG4): greedy
  and sampled evaluation success against environment steps, a line per seed and their mean
  (:func:`~bimgame.experiments.figures.plot_eval_curves`; the numbers: :mod:`bimgame.experiments.beyond`).
- ``table_speedup.md`` / ``table_speedup.json`` — steps to a success threshold, speed-up over A3C,
  final success, pre-training accuracy and π^s alone.
- ``report.md`` — each claim of the paper next to what this run measured, the figures, the tables
  and the settings with wall times (:mod:`bimgame.experiments.report_text`, its tables
  :mod:`bimgame.experiments.report_tables`).

This module assembles the numbers — ``table_speedup.json`` holds all of them — from the finished
pieces' logs (:mod:`bimgame.experiments.results`) with the statistics of
:mod:`bimgame.experiments.statistics`, which also defines steps to threshold, censoring and the
bootstrap. **The threshold** of a task is ``threshold_fraction`` (default 0.8) × the expert's
success rate on it, measured on the dataset's episodes relabelled for the task and counted as
successes only within the task's time limit; without a finished dataset, or with an expert that
never succeeds on the task, there is no threshold. Runs with a start curriculum get no
steps-to-threshold, training success or training curve: their training episodes start nearer the
goal than the task's; their evaluations are in the section beyond the paper.
"""

from __future__ import annotations

import collections
import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.experiments.algorithms import BASELINE, algorithm_named, registered
from bimgame.experiments.beyond import EVAL_TARGET, beyond_numbers, shows_beyond
from bimgame.experiments.budgets import Budget
from bimgame.experiments.figures import plot_curves, plot_eval_curves, plot_expert_lengths
from bimgame.experiments.grid import Piece
from bimgame.experiments.kinds import PretrainPolicyKind, PretrainValueKind, kind_of, run_kind
from bimgame.experiments.plan import load_plan, load_status
from bimgame.experiments.report_tables import tables_markdown
from bimgame.experiments.report_text import report_markdown
from bimgame.experiments.results import (
    RunResults,
    collect_runs,
    dataset_sequences,
    expert_success_by_task,
    final_eval,
    finished_pieces,
)
from bimgame.experiments.statistics import (
    CONFIDENCE,
    CURVE_BINS,
    DEFAULT_RESAMPLES,
    MIN_EPISODES,
    Crossing,
    nanmean,
    speedup,
)
from bimgame.expert.datasets import dataset_summary
from bimgame.util.files import atomic_write_bytes, read_json, write_json

__all__ = ["ReportPaths", "build_report"]


@dataclasses.dataclass
class ReportPaths:
    """The files :func:`build_report` wrote."""

    report: Path
    table_md: Path
    table_json: Path
    figures: list[Path]

    def all(self) -> list[Path]:
        return [*self.figures, self.table_md, self.table_json, self.report]


def build_report(
    out_dir: str | Path, *, threshold_fraction: float | None = None, resamples: int = DEFAULT_RESAMPLES, seed: int = 0
) -> ReportPaths:
    """Rebuild every figure, table and ``report.md`` of the reproduction in ``out_dir`` from its
    saved results (finished pieces only; nothing is trained). ``threshold_fraction`` overrides the
    budget's; ``seed`` seeds the bootstrap's generator, so the same results give the same report."""
    out_dir = Path(out_dir)
    budget, pieces = load_plan(out_dir)
    if threshold_fraction is None:
        threshold_fraction = budget.threshold_fraction
    if not (isinstance(threshold_fraction, (int, float)) and 0.0 < threshold_fraction <= 1.0):
        raise ValueError(f"threshold_fraction must be in (0, 1], got {threshold_fraction!r}")
    if not isinstance(resamples, int) or resamples < 1:
        raise ValueError(f"resamples must be an integer >= 1, got {resamples!r}")
    rng = np.random.default_rng(seed)
    finished = finished_pieces(pieces, out_dir, budget)
    figures: list[Path] = []
    dataset, expert = _expert(finished, out_dir, budget, figures)

    tasks: dict[str, Any] = {}
    all_runs: dict[str, dict[str, list[RunResults]]] = {}
    planned_runs = collections.Counter((p.task, p.algorithm) for p in pieces if p.algorithm is not None)
    context = _Context(out_dir, budget, threshold_fraction, resamples, rng)
    for task in budget.tasks:
        all_runs[task] = {a: collect_runs(finished, out_dir, task, a) for a in budget.algorithms}
        tasks[task] = _task_numbers(task, all_runs[task], context, expert, planned_runs, figures)

    beyond = None
    if shows_beyond(budget):
        # Its own generator: the paper's numbers stay what they were without this section.
        beyond = _beyond(
            all_runs, planned_runs, out_dir, budget, figures, resamples=resamples, rng=np.random.default_rng([seed, 1])
        )
    numbers = {
        "threshold_fraction": threshold_fraction,
        "bootstrap": {"resamples": resamples, "seed": seed, "confidence": CONFIDENCE},
        "expert": {"dataset": dataset, "success_by_task": expert},
        "tasks": tasks,
        "pretraining": _pretraining(finished, out_dir, budget),
        "beyond": beyond,
    }
    table_json = write_json(out_dir / "table_speedup.json", _without_nan(numbers))
    table_text = tables_markdown(numbers, budget)
    table_md = atomic_write_bytes(out_dir / "table_speedup.md", table_text.encode())
    report = atomic_write_bytes(
        out_dir / "report.md",
        report_markdown(numbers, table_text, budget, pieces, finished, load_status(out_dir)).encode(),
    )
    return ReportPaths(report, table_md, table_json, figures)


@dataclasses.dataclass(frozen=True)
class _Context:
    """What every task's numbers are computed with."""

    out_dir: Path
    budget: Budget
    threshold_fraction: float
    resamples: int
    rng: np.random.Generator


def _expert(
    finished: dict[str, Piece], out_dir: Path, budget: Budget, figures: list[Path]
) -> tuple[dict[str, Any] | None, dict[str, float]]:
    """The dataset's summary and the expert's success rate per task (None and {} without a finished
    dataset); draws the expert's episode lengths into ``figures``."""
    if "data" not in finished:
        return None, {}
    sequences = dataset_sequences(out_dir / "data")
    expert = expert_success_by_task(sequences, budget.tasks)
    figures.append(plot_expert_lengths(sequences, budget.dataset.task, out_dir / "fig_expert_lengths.png"))
    return dataset_summary(out_dir / "data"), expert


def _task_numbers(
    task: str,
    runs: dict[str, list[RunResults]],
    context: _Context,
    expert: dict[str, float],
    planned_runs: collections.Counter,
    figures: list[Path],
) -> dict[str, Any]:
    """One task's entry of ``table_speedup.json``: its threshold, per algorithm the runs' numbers,
    the speed-ups; its learning curves are drawn into ``figures``."""
    budget, rng = context.budget, context.rng
    steps = budget.steps_for(task) if task in budget.a3c.steps else 0
    edges = np.linspace(0.0, float(steps), CURVE_BINS + 1) if steps else np.array([0.0, 1.0])
    # No threshold without an expert that succeeds: 0 × anything would be "reached" at once.
    threshold = context.threshold_fraction * expert[task] if expert.get(task, 0.0) > 0 else None
    entry: dict[str, Any] = {
        "expert_success": expert.get(task),
        "threshold": threshold,
        "a3c_steps": steps,
        "curve_bin_steps": float(edges[1] - edges[0]),
        "min_episodes_per_bin": MIN_EPISODES,
        "algorithms": {},
    }
    crossings: dict[str, list[Crossing]] = {}
    for algorithm, group in runs.items():
        entry["algorithms"][algorithm], found = _algorithm_numbers(
            algorithm, group, planned_runs[task, algorithm], edges, threshold, steps, context.out_dir
        )
        if found:
            crossings[algorithm] = found
    _speedups(entry["algorithms"], crossings, context.resamples, rng)
    curves = {a: group for a, group in runs.items() if not algorithm_named(a).start_curriculum}
    if any(curves.values()):
        figures.append(
            plot_curves(
                task,
                curves,
                edges,
                threshold,
                context.threshold_fraction,
                context.out_dir / f"fig_curves_{task}.png",
                resamples=context.resamples,
                rng=rng,
                budget=budget,
            )
        )
        entry["figure"] = f"fig_curves_{task}.png"
    return entry


def _algorithm_numbers(
    name: str,
    group: list[RunResults],
    planned: int,
    edges: np.ndarray,
    threshold: float | None,
    steps: int,
    out_dir: Path,
) -> tuple[dict[str, Any], list[Crossing]]:
    """One algorithm's runs on one task: each run's numbers and their means, and the runs' crossings
    of the threshold (none with a start curriculum, whose training episodes are not the task's)."""
    algorithm = algorithm_named(name)
    kind = run_kind(algorithm)
    curriculum = algorithm.start_curriculum
    rows: list[dict[str, Any]] = []
    crossings: list[Crossing] = []
    for run in group:
        crossing = None if threshold is None or curriculum else kind.crossing(run, edges, threshold)
        if crossing is not None:
            crossings.append(crossing)
        rows.append(
            {
                "seed": run.seed,
                "dir": str(run.path.relative_to(out_dir)),
                "steps_to_threshold": crossing.steps if crossing and crossing.reached else None,
                "censored_at": crossing.steps if crossing and not crossing.reached else None,
                "final_success_training": None if curriculum else kind.final_training_success(run, steps),
                "final_greedy_success": final_eval(run, name, "greedy"),
                "final_sampled_success": final_eval(run, name, "sampled"),
                "env_steps": kind.env_steps(run),
            }
        )
    training = kind.training_episodes and not curriculum
    return {
        "runs": rows,
        "seeds_finished": len(group),
        "seeds_planned": planned,
        "reached": sum(c.reached for c in crossings),
        "mean_steps_censored_at_last": float(np.mean([c.steps for c in crossings])) if crossings else None,
        "final_success_training": nanmean([r["final_success_training"] for r in rows]) if training else None,
        "start_curriculum": curriculum,
        "final_greedy_success": nanmean([r["final_greedy_success"] for r in rows]),
        "final_sampled_success": nanmean([r["final_sampled_success"] for r in rows]),
    }, crossings


def _speedups(
    algorithms: dict[str, Any], crossings: dict[str, list[Crossing]], resamples: int, rng: np.random.Generator
) -> None:
    """Into each algorithm's entry: its speed-up over :data:`~bimgame.experiments.algorithms.BASELINE`
    (``speedup_vs_<baseline>``) and, for a value-reward algorithm, over the same start without the
    value reward (``speedup_vs_<that algorithm>``)."""
    base = crossings.get(BASELINE.name)
    for name, group in crossings.items():
        if name != BASELINE.name and base:
            algorithms[name][f"speedup_vs_{BASELINE.name}"] = speedup(base, group, resamples=resamples, rng=rng)
    for algorithm in registered():
        without = algorithm.without_value_reward
        if without is not None and crossings.get(without) and crossings.get(algorithm.name):
            algorithms[algorithm.name][f"speedup_vs_{without}"] = speedup(
                crossings[without], crossings[algorithm.name], resamples=resamples, rng=rng
            )


def _beyond(
    all_runs: dict[str, dict[str, list[RunResults]]],
    planned_runs: collections.Counter,
    out_dir: Path,
    budget: Budget,
    figures: list[Path],
    *,
    resamples: int,
    rng: np.random.Generator,
) -> dict[str, Any]:
    """The numbers of the section beyond the paper, with a figure of the evaluations per task that has any."""
    beyond = beyond_numbers(all_runs, planned_runs, out_dir=out_dir, resamples=resamples, rng=rng)
    for task, entry in beyond["tasks"].items():
        if any(r["evaluations"] for a in entry["algorithms"].values() for r in a["runs"]):
            figures.append(
                plot_eval_curves(
                    task, all_runs[task], out_dir / f"fig_eval_{task}.png", budget=budget, target=EVAL_TARGET
                )
            )
            entry["figure"] = f"fig_eval_{task}.png"
    return beyond


def _without_nan(value: Any) -> Any:
    """NaN → None throughout, so the JSON is standard (NaN is not JSON)."""
    if isinstance(value, dict):
        return {k: _without_nan(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_without_nan(v) for v in value]
    if isinstance(value, float) and math.isnan(value):
        return None
    return value


def _pretraining(finished: dict[str, Piece], out_dir: Path, budget: Budget) -> dict[str, Any]:
    """Per task: the held-out accuracy of each seed's π^s, its success alone, and V̂'s held-out RMSE."""
    out: dict[str, Any] = {}
    for task in budget.tasks:
        policy_pieces = [
            (p.seed, read_json(out_dir / p.path / "summary.json"))
            for p in finished.values()
            if isinstance(kind_of(p), PretrainPolicyKind) and p.task == task
        ]
        value_pieces = [
            (p.seed, read_json(out_dir / p.path / "summary.json"))
            for p in finished.values()
            if isinstance(kind_of(p), PretrainValueKind) and p.task == task
        ]
        if not policy_pieces and not value_pieces:
            continue
        # The seeds whose summary has something in it, in seed order.
        policy = sorted(((s, v) for s, v in policy_pieces if v), key=lambda pair: pair[0] or 0)
        value = sorted(((s, v) for s, v in value_pieces if v), key=lambda pair: pair[0] or 0)
        evals = [v.get("policy_eval") or {} for _, v in policy]
        out[task] = {
            "seeds": [s for s, _ in policy],
            "val_accuracy": [v.get("val_accuracy") for _, v in policy],
            "val_accuracy_mean": nanmean([v.get("val_accuracy") for _, v in policy]),
            "chance_accuracy": 0.2,
            "policy_greedy_success": [e.get("greedy_success_rate") for e in evals],
            "policy_sampled_success": [e.get("sampled_success_rate") for e in evals],
            "policy_eval_episodes": budget.pretrain.eval_episodes,
            "value_rmse": [v.get("val_value_rmse") for _, v in value],
        }
    return out
