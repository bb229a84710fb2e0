"""Learning curves of a training run, drawn from its CSV logs (see :mod:`bimgame.learn.runs`).

**Which episodes are counted.** Training episodes are grouped by the step they *started* at
(``start_step``), since grouping by the end step favours short, successful episodes early in
training. But ``episodes.csv`` holds only the episodes that had *ended* when the log stops: of those
that started in its last stretch, the short, successful ones are there and the long ones, failing
at the time limit, are not — the last bins would show a false jump towards 100% success. So a bin
counts only if every episode that started in it must have ended before the run's last step (the
last logged end step, or a finished run's steps): the bin ends at least one *episode span* before
it (:func:`complete_until`). The span is the most steps of the x-axis one episode can take from its
logged start to its logged end: the run's time limit plus one update segment (start steps are
counted at the segment's start), times all its environments (the x-axis counts every worker's
environments together), and at least the longest span in the log (workers running at different
speeds stretch it) — :func:`episode_span`. Later bins are left out rather than counted with their
missing episodes as "censored": those episodes' start steps are nowhere in the log, so there is
nothing to count them with.
"""

from __future__ import annotations

import csv
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.envs.puzzles import puzzle
from bimgame.learn.runs import CONFIG, read_run_config
from bimgame.util.files import complete_lines, read_json
from bimgame.util.images import save_png, subplots

__all__ = [
    "read_table",
    "episode_span",
    "complete_until",
    "finished_at",
    "run_config",
    "run_until",
    "binned_means",
    "binned_by_start",
    "plot_run",
    "plot_comparison",
]


def read_table(path: str | Path) -> dict[str, np.ndarray]:
    """A run's CSV log as columns of floats (empty cells are NaN); empty dict if there is none. A
    last line cut off mid-write is left out, so a log can be read while its run writes it."""
    path = Path(path)
    if not path.is_file():
        return {}
    rows = list(csv.DictReader(complete_lines(path)))
    if not rows:
        return {}
    return {key: np.array([_number(r[key]) for r in rows]) for key in rows[0]}


def _number(text: str | None) -> float:
    """A CSV cell as a float: booleans as 0/1, empty cells as NaN."""
    if text in ("", None):
        return np.nan
    if text in ("True", "False"):
        return float(text == "True")
    return float(text)


def episode_span(episodes: dict[str, np.ndarray], config: dict[str, Any] | None = None) -> float:
    """The most steps of the x-axis one training episode can take from its ``start_step`` to its
    logged end ``step``: with a run's ``config.json`` (its ``"a3c"`` settings), (time limit +
    n_steps) × workers × envs_per_worker, and never less than the longest span in the log (0 when
    there is neither)."""
    longest = 0.0
    if len(episodes.get("step", ())) and len(episodes.get("start_step", ())):
        longest = float(np.nanmax(episodes["step"] - episodes["start_step"]))
    a3c = (config or {}).get("a3c")
    if not isinstance(a3c, dict) or not all(a3c.get(k) for k in ("task", "workers", "envs_per_worker")):
        return max(longest, 0.0)
    limit = a3c.get("max_episode_steps") or puzzle(a3c["task"]).time_limit
    nominal = (limit + (a3c.get("n_steps") or 0)) * a3c["workers"] * a3c["envs_per_worker"]
    return float(max(longest, nominal))


def complete_until(episodes: dict[str, np.ndarray], span: float, *, finished_at: float | None = None) -> float:
    """The step before which every episode that started has ended and is in the log: the run's last
    step − ``span`` + 1 (steps are whole numbers), ``span`` being :func:`episode_span`'s. The run's
    last step is ``finished_at`` (:func:`finished_at`) when it is later than the last logged end
    step. Infinite when the table has no end steps and no ``finished_at`` (nothing to cut by)."""
    ends = [float(np.nanmax(episodes["step"]))] if len(episodes.get("step", ())) else []
    if finished_at is not None:
        ends.append(float(finished_at))
    if not ends:
        return np.inf if "step" not in episodes else -np.inf
    return max(ends) - span + 1


def finished_at(summary: dict[str, Any] | None) -> float | None:
    """The last step of a run that ran to its end (its summary.json says ``finished``); None for
    others, whose last logged end step stands in for it (an interrupted run may be resumed from an
    earlier checkpoint)."""
    if not summary or summary.get("stopped") != "finished" or summary.get("steps") is None:
        return None
    return float(summary["steps"])


def binned_means(
    start_steps: np.ndarray, values: np.ndarray, edges: np.ndarray, *, min_count: int = 1, until: float = np.inf
) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``values`` over the episodes that started in each bin of ``edges`` (episodes past
    the last edge fall in the last bin); NaN where a bin has fewer than ``min_count``, and for the
    bins that end after ``until`` (:func:`complete_until`: some of their episodes may still have been
    running when the log stopped; they count 0 episodes, as do episodes that started at ``until`` or
    later). Returns (means, counts)."""
    start_steps = np.asarray(start_steps, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if np.isfinite(until):
        start_steps, values = start_steps[start_steps < until], values[start_steps < until]
    bins = len(edges) - 1
    index = np.clip(np.searchsorted(edges, start_steps, side="right") - 1, 0, bins - 1)
    counts = np.bincount(index, minlength=bins)
    counts[np.asarray(edges[1:]) > until] = 0
    sums = np.bincount(index, weights=values, minlength=bins)
    means = np.full(bins, np.nan)
    keep = counts >= max(min_count, 1)
    means[keep] = sums[keep] / counts[keep]
    return means, counts


def binned_by_start(
    episodes: dict[str, np.ndarray],
    key: str,
    bins: int = 40,
    *,
    edges: np.ndarray | None = None,
    until: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``key`` over episodes grouped by the step they *started* at, leaving out the bins
    that end after ``until``, whose episodes may not all have ended (see the module notes; by
    default :func:`complete_until` with the longest span in the log; :func:`run_until` also reads
    the run's settings). Returns (bin centres, means) of the bins that hold episodes; ``edges``
    fixes the bins (e.g. to average several runs), otherwise ``bins`` span the run's complete part."""
    start = episodes["start_step"]
    if until is None:
        until = complete_until(episodes, episode_span(episodes))
    if edges is None:
        right = min(start.max() + 1, until)
        if right <= start.min():
            return np.array([]), np.array([])
        edges = np.linspace(start.min(), right, bins + 1)
    means, counts = binned_means(start, episodes[key], edges, until=until)
    keep = counts > 0
    return ((edges[:-1] + edges[1:]) / 2)[keep], means[keep]


def run_config(run_dir: str | Path) -> dict[str, Any]:
    """A run's ``config.json`` ({} when there is none, e.g. logs copied without it)."""
    return read_run_config(run_dir) if (Path(run_dir) / CONFIG).is_file() else {}


def run_until(run_dir: str | Path, episodes: dict[str, np.ndarray]) -> float:
    """:func:`complete_until` of a run directory's training ``episodes`` (its whole log), with the
    span from its config.json and the last step from its summary.json."""
    return complete_until(
        episodes,
        episode_span(episodes, run_config(run_dir)),
        finished_at=finished_at(read_json(Path(run_dir) / "summary.json")),
    )


def plot_run(run_dir: str | Path, out: str | Path | None = None, title: str | None = None) -> Path:
    """Success rate and episode length against environment steps (training episodes binned by
    start step, up to where they may not all have ended — see the module notes — plus the
    evaluator's greedy and sampled episodes); writes a PNG (default ``RUN_DIR/curves.png``)."""
    run_dir = Path(run_dir)
    episodes = read_table(run_dir / "episodes.csv")
    evaluations = read_table(run_dir / "eval.csv")
    if not episodes:
        raise ValueError(f"{run_dir} has no finished training episodes to plot (episodes.csv)")
    until = run_until(run_dir, episodes)
    # The line stops where the episodes that started may not all have ended (see the module notes).
    label = f"training episodes (by start step, to {until:,.0f})"
    fig, (ax_success, ax_length) = subplots(1, 2, figsize=(11, 4))
    steps, success = binned_by_start(episodes, "success", until=until)
    ax_success.plot(steps, success, label=label)
    steps, length = binned_by_start(episodes, "length", until=until)
    ax_length.plot(steps, length, label=label)
    if evaluations:
        for mode, marker in (("greedy", "o"), ("sampled", "s")):
            ax_success.plot(
                evaluations["step"], evaluations[f"{mode}_success_rate"], marker, label=f"evaluation, {mode}"
            )
            ax_length.plot(evaluations["step"], evaluations[f"{mode}_mean_length"], marker, label=f"evaluation, {mode}")
    ax_success.set(xlabel="environment steps", ylabel="success rate", ylim=(-0.02, 1.02))
    ax_length.set(xlabel="environment steps", ylabel="episode length (steps)")
    for axis in (ax_success, ax_length):
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
    fig.suptitle(title or str(run_dir))
    fig.tight_layout()
    return save_png(fig, Path(out) if out is not None else run_dir / "curves.png", dpi=110)


def plot_comparison(
    groups: dict[str, list[str | Path]],
    out: str | Path,
    *,
    title: str = "",
    bins: int = 30,
    max_step: float | None = None,
) -> Path:
    """One line per group of runs (e.g. ``{"A3C": [seed0, seed1], "pre-trained + A3C": [...]}``):
    the training episodes' success rate by start step, and the evaluator's greedy success, each
    averaged over the group's runs (thin lines: the single runs); ``max_step`` cuts longer runs
    to a common budget. Training episodes count up to where they may not all have ended (see the
    module notes). Writes a PNG to ``out``."""
    tables = {
        label: [(read_table(Path(r) / "episodes.csv"), read_table(Path(r) / "eval.csv")) for r in runs]
        for label, runs in groups.items()
    }
    # Each run's complete part comes from its whole log (cutting it at max_step loses no episode
    # that started before max_step).
    untils = {
        label: [run_until(r, e) if e else -np.inf for (e, _), r in zip(runs, groups[label], strict=True)]
        for label, runs in tables.items()
    }
    if max_step is not None:
        tables = {
            label: [(_up_to(e, "start_step", max_step), _up_to(ev, "step", max_step)) for e, ev in runs]
            for label, runs in tables.items()
        }
    for label, runs in tables.items():
        for (episodes, _), run in zip(runs, groups[label], strict=True):
            if not episodes:
                raise ValueError(f"{run} has no finished training episodes to plot (episodes.csv)")
    last = max(
        min(float(e["start_step"].max()) + 1, until)
        for label, runs in tables.items()
        for (e, _), until in zip(runs, untils[label], strict=True)
    )
    edges = np.linspace(0, max(last, 1.0), bins + 1)
    centres = (edges[:-1] + edges[1:]) / 2
    fig, (ax_train, ax_eval) = subplots(1, 2, figsize=(11, 4))
    for index, (label, runs) in enumerate(tables.items()):
        colour = f"C{index}"
        curves = []
        for (episodes, _), until in zip(runs, untils[label], strict=True):
            curve, _ = binned_means(episodes["start_step"], episodes["success"], edges, until=until)
            curves.append(curve)
            ax_train.plot(centres, curve, color=colour, alpha=0.25, linewidth=0.8)
        with warnings.catch_warnings():  # bins no run reached are NaN, not an error
            warnings.simplefilter("ignore", RuntimeWarning)
            mean = np.nanmean(curves, axis=0)
        ax_train.plot(centres, mean, color=colour, label=f"{label} ({len(runs)} runs)")
        evaluations = [ev for _, ev in runs if ev]
        for ev in evaluations:
            ax_eval.plot(ev["step"], ev["greedy_success_rate"], color=colour, alpha=0.25, linewidth=0.8)
        if evaluations:
            length = min(len(ev["step"]) for ev in evaluations)
            mean = np.mean([ev["greedy_success_rate"][:length] for ev in evaluations], axis=0)
            ax_eval.plot(evaluations[0]["step"][:length], mean, "o-", color=colour, label=label)
    ax_train.set(
        xlabel="environment steps", ylabel="success rate", title="training episodes (by start step)", ylim=(-0.02, 1.02)
    )
    ax_eval.set(xlabel="environment steps", ylabel="success rate", title="evaluation, greedy", ylim=(-0.02, 1.02))
    # Both panels on one step axis (a run's only evaluation may be its last, one update past the budget).
    (train_left, train_right), (eval_left, eval_right) = ax_train.get_xlim(), ax_eval.get_xlim()
    for axis in (ax_train, ax_eval):
        axis.set_xlim(min(train_left, eval_left), max(train_right, eval_right))
    for axis in (ax_train, ax_eval):
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    return save_png(fig, Path(out), dpi=110)


def _up_to(table: dict[str, np.ndarray], key: str, max_step: float) -> dict[str, np.ndarray]:
    """The rows of a log table whose ``key`` is at most ``max_step`` (empty stays empty)."""
    if not table:
        return table
    keep = table[key] <= max_step
    return {k: v[keep] for k, v in table.items()} if keep.any() else {}
