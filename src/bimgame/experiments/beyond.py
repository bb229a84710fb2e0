"""The report's numbers beyond the paper: whether fine-tuning keeps what π^s knew, read from each A3C
and PPO run's periodic evaluations (``eval.csv``).

Evaluations, not training episodes: they always start from the task's own starts, also in runs with
a start curriculum (whose training episodes start nearer the goal), and they measure the greedy and
the sampled policy separately. The first row of a run's ``eval.csv`` is step 0, the policy it
started from — for a ``pretrain…`` run, π^s itself — and the last row is its final evaluation. A
PPO run evaluates first after ``eval_every`` steps: it has no step-0 row, so no start or drop.

Per run (:func:`run_metrics`): the final greedy and sampled success; the **dip**, the lowest
success after step 0 and how far it fell below step 0's (the forgetting the paper reports on STG3
and STG4); the **steps to** :data:`EVAL_TARGET` greedy success, the first evaluation at or above it
(step 0 when π^s already is; not reached: censored at the run's last evaluation). Per task and
algorithm (:func:`beyond_numbers`): every seed's values — never the best of them — and their mean
with a seeded percentile-bootstrap interval over seeds (:mod:`bimgame.experiments.statistics`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.experiments.algorithms import algorithm_named
from bimgame.experiments.budgets import Budget
from bimgame.experiments.kinds import run_kind
from bimgame.experiments.run_logs import RunResults
from bimgame.experiments.statistics import DEFAULT_RESAMPLES, first_crossing, mean_interval

__all__ = [
    "EVAL_TARGET",
    "BEYOND_TASKS",
    "MODES",
    "SUMMARISED",
    "shows_beyond",
    "eval_curve",
    "run_metrics",
    "mean_ci",
    "beyond_numbers",
]

#: Greedy evaluation success whose first reaching is "steps to 80%".
EVAL_TARGET = 0.8
#: Tasks the paper reports unlearned: a grid with any of them gets the section.
BEYOND_TASKS = ("STG3", "STG4")
#: The evaluations' two ways of acting.
MODES = ("greedy", "sampled")


def shows_beyond(budget: Budget) -> bool:
    """Whether the report has the section: evaluations during the runs (it measures dips between
    them) and a fine-tuning method beyond the paper's (its record's ``finetuning``), or STG3/STG4, in
    the grid."""
    finetuning = any(algorithm_named(a).finetuning for a in budget.algorithms)
    return budget.a3c.eval_every > 0 and (finetuning or any(t in BEYOND_TASKS for t in budget.tasks))


def eval_curve(table: dict[str, np.ndarray]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A run's evaluations in step order: (steps, {mode: success rates}); empty when it has none."""
    steps = np.asarray(table.get("step", ()), dtype=np.float64)
    order = np.argsort(steps, kind="stable")
    return steps[order], {
        mode: np.asarray(table.get(f"{mode}_success_rate", np.full(len(steps), np.nan)), dtype=np.float64)[order]
        for mode in MODES
    }


def _nan_min(values: np.ndarray) -> tuple[float, int | None]:
    """The smallest non-NaN value and its index (NaN, None when there is none)."""
    if len(values) == 0 or np.all(np.isnan(values)):
        return float("nan"), None
    index = int(np.nanargmin(values))
    return float(values[index]), index


def run_metrics(table: dict[str, np.ndarray], *, target: float = EVAL_TARGET) -> dict[str, Any]:
    """One run's numbers from its ``eval.csv`` columns (see the module notes): per mode ``start_*``
    (step 0's success; NaN without a step-0 row), ``final_*`` (the last row), ``lowest_*`` and
    ``lowest_*_step`` (the lowest after step 0), ``drop_*`` (how far that is below step 0's, 0 when
    it never fell); ``steps_to_target`` (None when not reached, then ``censored_at`` is the last
    evaluated step) and ``evaluations`` (rows)."""
    if not (isinstance(target, (int, float)) and 0.0 < target <= 1.0):
        raise ValueError(f"target must be a success rate in (0, 1], got {target!r}")
    steps, success = eval_curve(table)
    has_start = len(steps) > 0 and steps[0] == 0
    after = steps > 0
    out: dict[str, Any] = {"evaluations": len(steps)}
    for mode, values in success.items():
        start = float(values[0]) if has_start else float("nan")
        lowest, index = _nan_min(values[after])
        out[f"start_{mode}"] = start
        out[f"final_{mode}"] = float(values[-1]) if len(values) else float("nan")
        out[f"lowest_{mode}"] = lowest
        out[f"lowest_{mode}_step"] = float(steps[after][index]) if index is not None else None
        out[f"drop_{mode}"] = (
            max(0.0, start - lowest) if not (math.isnan(start) or math.isnan(lowest)) else float("nan")
        )
    out["steps_to_target"] = first_crossing(steps, success["greedy"], target)
    out["censored_at"] = None if out["steps_to_target"] is not None or not len(steps) else float(steps[-1])
    return out


def mean_ci(
    values: Sequence[float | None], *, resamples: int = DEFAULT_RESAMPLES, rng: np.random.Generator
) -> dict[str, Any]:
    """Mean of the values that are neither None nor NaN, with a percentile-bootstrap 95% interval
    over them (``ci`` None with fewer than two); ``n`` counts them."""
    kept = np.array([v for v in values if v is not None and not math.isnan(v)], dtype=np.float64)
    if len(kept) == 0:
        return {"mean": float("nan"), "ci": None, "n": 0}
    ci = list(mean_interval(kept, resamples=resamples, rng=rng)) if len(kept) >= 2 else None
    return {"mean": float(kept.mean()), "ci": ci, "n": len(kept)}


def _steps_summary(rows: list[dict[str, Any]], *, resamples: int, rng: np.random.Generator) -> dict[str, Any]:
    """Steps to the target over seeds: ``reached`` seeds; ``mean`` with unreached seeds counted at
    their last evaluation, a lower bound (``bound`` ``lower``) unless all reached (``exact``, with
    ``ci``); ``not reached`` when none did."""
    values = [r["steps_to_target"] if r["steps_to_target"] is not None else r["censored_at"] for r in rows]
    values = [v for v in values if v is not None]
    reached = sum(r["steps_to_target"] is not None for r in rows)
    if not values:
        return {"reached": 0, "mean": None, "ci": None, "bound": None}
    if reached == 0:
        return {"reached": 0, "mean": None, "ci": None, "bound": "not reached"}
    summary = mean_ci(values, resamples=resamples, rng=rng)
    exact = reached == len(rows)
    return {
        "reached": reached,
        "mean": summary["mean"],
        "ci": summary["ci"] if exact else None,
        "bound": "exact" if exact else "lower",
    }


#: The per-run numbers summarised over seeds (mean and interval).
SUMMARISED = tuple(f"{kind}_{mode}" for kind in ("start", "final", "lowest", "drop") for mode in MODES)


def beyond_numbers(
    runs: dict[str, dict[str, list[RunResults]]],
    planned: dict[tuple[str, str], int],
    *,
    out_dir: Path,
    target: float = EVAL_TARGET,
    resamples: int = DEFAULT_RESAMPLES,
    rng: np.random.Generator,
) -> dict[str, Any]:
    """The section's numbers: per task (``runs``: task → algorithm → finished runs) and A3C or PPO algorithm,
    each seed's :func:`run_metrics` and their summaries over seeds (:data:`SUMMARISED` as
    :func:`mean_ci`, ``steps_to_target``); ``planned`` counts the runs planned per (task, algorithm).
    Runs without periodic evaluations of their own (DAgger's) are left out."""
    tasks: dict[str, Any] = {}
    for task, by_algorithm in runs.items():
        algorithms: dict[str, Any] = {}
        for algorithm, group in by_algorithm.items():
            record = algorithm_named(algorithm)
            if not run_kind(record).training_episodes:
                continue
            rows = [
                {"seed": r.seed, "dir": str(r.path.relative_to(out_dir)), **run_metrics(r.table, target=target)}
                for r in group
            ]
            entry: dict[str, Any] = {
                "runs": rows,
                "seeds_finished": len(rows),
                "seeds_planned": planned.get((task, algorithm), 0),
                "starts_from_policy": record.starts_from_policy,
                "start_curriculum": record.start_curriculum,
            }
            for name in SUMMARISED:
                entry[name] = mean_ci([r[name] for r in rows], resamples=resamples, rng=rng)
            entry["steps_to_target"] = _steps_summary(rows, resamples=resamples, rng=rng)
            algorithms[algorithm] = entry
        tasks[task] = {"algorithms": algorithms}
    return {"target": target, "tasks": tasks}
