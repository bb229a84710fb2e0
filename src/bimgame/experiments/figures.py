"""The report's figures, drawn from the runs' saved logs: the learning curves of each task (the
paper's Fig. 2), the lengths of the expert's dataset episodes (Fig. 1b), and beyond the paper the
periodic evaluations of each task's A3C and PPO runs (:func:`plot_eval_curves`).

Curves are training episodes binned by the step they *started* at, up to where the log holds all
of them (:attr:`bimgame.experiments.results.RunResults.until`), the task's own reward (also for
shaped runs), the mean over seeds with a bootstrap band (:mod:`bimgame.experiments.statistics`).
DAgger has no training episodes of its own policy: its line is its greedy evaluation after each
iteration, against the environment steps it had used by then. Figures are drawn without pyplot
(:func:`bimgame.util.images.subplots`), so building a report never changes matplotlib's backend.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.experiments.algorithms import algorithm_named, algorithm_names
from bimgame.experiments.beyond import MODES, eval_curve
from bimgame.experiments.budgets import Budget
from bimgame.experiments.kinds import run_kind
from bimgame.experiments.results import RunResults
from bimgame.experiments.statistics import CONFIDENCE, bootstrap_mean_band
from bimgame.expert.episode import Episode
from bimgame.expert.evaluation import EpisodeResult, plot_length_histogram
from bimgame.learn.curves import binned_means
from bimgame.util.images import save_png, subplots

__all__ = ["algorithm_colour", "plot_curves", "plot_eval_curves", "plot_expert_lengths"]

#: The algorithms' colours, the same in every figure: matplotlib's ten cycle colours in the
#: registry's order (the paper's five keep C0–C4), then a few more, then round again.
_PALETTE = [f"C{i}" for i in range(10)] + ["navy", "magenta", "darkgoldenrod", "teal"]


def algorithm_colour(algorithm: str) -> str:
    """The colour of ``algorithm`` (a registered one) in every figure."""
    return _PALETTE[algorithm_names().index(algorithm) % len(_PALETTE)]


def _legend(algorithm: str, group: list[RunResults]) -> str:
    """An algorithm's legend entry: its label and how many seeds its line is over."""
    return f"{algorithm_named(algorithm).label} ({len(group)} seed{'s' if len(group) != 1 else ''})"


def plot_curves(
    task: str,
    runs: dict[str, list[RunResults]],
    edges: np.ndarray,
    threshold: float | None,
    fraction: float,
    path: Path,
    *,
    resamples: int,
    rng: np.random.Generator,
    budget: Budget,
) -> Path:
    """The paper's Fig. 2 for ``task``: return and success rate of the training episodes against
    environment steps, one line per algorithm with a bootstrap band over seeds; the threshold as a
    dashed line. Written to ``path``."""
    centres = (edges[:-1] + edges[1:]) / 2
    fig, (ax_return, ax_success) = subplots(1, 2, figsize=(12, 4.4))
    for algorithm in algorithm_names():
        group = runs.get(algorithm) or []
        if not group:
            continue
        colour, label = algorithm_colour(algorithm), _legend(algorithm, group)
        if not run_kind(algorithm_named(algorithm)).training_episodes:
            _plot_dagger(ax_return, ax_success, task, group, colour, label, resamples=resamples, rng=rng)
            continue
        for axis, key in ((ax_return, "return"), (ax_success, "success")):
            curves = np.array(
                [
                    binned_means(r.episodes["start_step"], r.episodes[key], edges, until=r.until)[0]
                    if r.episodes
                    else np.full(len(centres), np.nan)
                    for r in group
                ]
            )
            mean, low, high = bootstrap_mean_band(curves, resamples=resamples, rng=rng)
            axis.plot(centres, mean, color=colour, label=label)
            axis.fill_between(centres, low, high, color=colour, alpha=0.18, linewidth=0)
    if threshold is not None:
        ax_success.axhline(
            threshold, color="black", ls="--", lw=0.8, label=f"threshold {threshold:.2f} ({fraction:.0%} of the expert)"
        )
    ax_return.set(
        xlabel="environment steps", ylabel="mean episode return (task reward)", title="cumulative reward per episode"
    )
    ax_success.set(xlabel="environment steps", ylabel="success rate", title="success rate", ylim=(-0.02, 1.02))
    for axis in (ax_return, ax_success):
        axis.grid(alpha=0.3)
        axis.legend(fontsize=7)
    fig.suptitle(
        f"{task}, {budget.obs} observations: training episodes by start step, mean over seeds with "
        f"bootstrap {CONFIDENCE:.0%} band; DAgger: greedy evaluation per iteration",
        fontsize=9,
    )
    fig.tight_layout()
    return save_png(fig, path, dpi=120)


def _plot_dagger(
    ax_return: Any,
    ax_success: Any,
    task: str,
    group: list[RunResults],
    colour: str,
    label: str,
    *,
    resamples: int,
    rng: np.random.Generator,
) -> None:
    """The greedy evaluations of runs without training episodes of their own (DAgger's, per
    iteration), aligned by iteration across seeds (x: mean environment steps)."""
    tables = [r.table for r in group if r.table and len(r.table.get("step", ())) > 0]
    if not tables:
        return
    count = max(len(t["step"]) for t in tables)

    def column(key: str) -> np.ndarray:
        out = np.full((len(tables), count), np.nan)
        for row, table in enumerate(tables):
            out[row, : len(table[key])] = table[key]
        return out

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        steps = np.nanmean(column("step"), axis=0)
    success = column("greedy_success_rate")
    if "greedy_mean_return" in tables[0]:
        returns = column("greedy_mean_return")
    elif task != "FULL":
        returns = success  # STGk pays 1 at the goal and 0 elsewhere: return = success
    else:
        returns = None  # dagger.csv has no mean return of FULL's ±1 rewards
    for axis, values in ((ax_success, success), (ax_return, returns)):
        if values is None:
            continue
        mean, low, high = bootstrap_mean_band(values, resamples=resamples, rng=rng)
        axis.plot(steps, mean, "o-", color=colour, label=label + ", greedy eval.", markersize=4)
        axis.fill_between(steps, low, high, color=colour, alpha=0.18, linewidth=0)


def plot_eval_curves(
    task: str, runs: dict[str, list[RunResults]], path: Path, *, budget: Budget, target: float | None = None
) -> Path:
    """Beyond the paper, for ``task``: greedy and sampled evaluation success (``eval.csv``, the task's
    own starts) against environment steps, one colour per A3C or PPO algorithm, a thin line per seed and a
    thick line for the mean over seeds (each seed interpolated between its evaluations; the mean
    only where every seed was evaluated); ``target`` as a dashed line. Written to ``path``."""
    fig, axes = subplots(1, len(MODES), figsize=(12, 4.4), sharey=True)
    for algorithm in algorithm_names():
        group = [r for r in runs.get(algorithm) or [] if len(r.table.get("step", ())) > 0]
        if not group or not run_kind(algorithm_named(algorithm)).training_episodes:
            continue
        colour, label = algorithm_colour(algorithm), _legend(algorithm, group)
        curves = [eval_curve(r.table) for r in group]
        grid = np.unique(np.concatenate([steps for steps, _ in curves]))
        for axis, mode in zip(axes, MODES, strict=True):
            aligned = []
            for steps, success in curves:
                axis.plot(steps, success[mode], color=colour, lw=0.7, alpha=0.35)
                inside = (grid >= steps[0]) & (grid <= steps[-1])
                aligned.append(np.where(inside, np.interp(grid, steps, success[mode]), np.nan))
            mean = np.mean(aligned, axis=0)  # NaN where a seed has no evaluation around the step
            axis.plot(grid, mean, color=colour, lw=2.2, label=label)
    axes[0].set_ylabel("success rate")
    for axis, mode in zip(axes, MODES, strict=True):
        if target is not None:
            axis.axhline(target, color="black", ls="--", lw=0.8, label=f"{target:.0%}")
        axis.set(xlabel="environment steps", title=f"{mode} evaluation", ylim=(-0.02, 1.02))
        axis.grid(alpha=0.3)
        axis.legend(fontsize=7)
    fig.suptitle(
        f"{task}, {budget.obs} observations: evaluation episodes from the task's own starts "
        f"({budget.a3c.eval_episodes} per evaluation); thin: one seed, thick: mean over seeds; step 0 is "
        f"the starting policy (π^s for pre-trained starts)",
        fontsize=9,
    )
    fig.tight_layout()
    return save_png(fig, path, dpi=120)


def plot_expert_lengths(sequences: list[Episode], task: str, path: Path) -> Path:
    """The paper's Fig. 1b: lengths of the expert's dataset episodes."""
    ids = [i if s.id is None else int(s.id) for i, s in enumerate(sequences)]  # a dataset's episodes have ids
    results = [
        EpisodeResult(n, n, bool(s.terminated), len(s), float(np.sum(s.rewards)), 0.0)
        for n, s in zip(ids, sequences, strict=True)
    ]
    return plot_length_histogram(results, path, title=f"MPC expert dataset, {task}")
