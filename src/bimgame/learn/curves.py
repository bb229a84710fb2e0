"""Learning curves of a training run, drawn from its CSV logs (see :mod:`bimgame.learn.runs`)."""

from __future__ import annotations

import csv
import warnings
from pathlib import Path

import numpy as np

from bimgame.util.images import save_png, subplots

__all__ = ["read_table", "binned_means", "binned_by_start", "plot_run", "plot_comparison"]


def read_table(path: str | Path) -> dict[str, np.ndarray]:
    """A run's CSV log as columns of floats (empty cells are NaN); empty dict if there is none."""
    path = Path(path)
    if not path.is_file():
        return {}
    with path.open(newline="") as handle:
        rows = list(csv.DictReader(handle))
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


def binned_means(start_steps: np.ndarray, values: np.ndarray, edges: np.ndarray, *, min_count: int = 1,
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``values`` over the episodes that started in each bin of ``edges`` (episodes past
    the last edge fall in the last bin); NaN where a bin has fewer than ``min_count``. Returns
    (means, counts)."""
    start_steps = np.asarray(start_steps, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    bins = len(edges) - 1
    index = np.clip(np.searchsorted(edges, start_steps, side="right") - 1, 0, bins - 1)
    counts = np.bincount(index, minlength=bins)
    sums = np.bincount(index, weights=values, minlength=bins)
    means = np.full(bins, np.nan)
    keep = counts >= max(min_count, 1)
    means[keep] = sums[keep] / counts[keep]
    return means, counts


def binned_by_start(episodes: dict[str, np.ndarray], key: str, bins: int = 40, *,
                    edges: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``key`` over episodes grouped by the step they *started* at (counting by the end
    step would favour short, successful episodes early in training). Returns (bin centres, means)
    of the bins that hold episodes; ``edges`` fixes the bins (e.g. to average several runs),
    otherwise ``bins`` span the run."""
    start = episodes["start_step"]
    if edges is None:
        edges = np.linspace(start.min(), start.max() + 1, bins + 1)
    means, counts = binned_means(start, episodes[key], edges)
    keep = counts > 0
    return ((edges[:-1] + edges[1:]) / 2)[keep], means[keep]


def plot_run(run_dir: str | Path, out: str | Path | None = None, title: str | None = None) -> Path:
    """Success rate and episode length against environment steps (training episodes binned by
    start step, plus the evaluator's greedy and sampled episodes); writes a PNG (default
    ``RUN_DIR/curves.png``)."""
    run_dir = Path(run_dir)
    episodes = read_table(run_dir / "episodes.csv")
    evaluations = read_table(run_dir / "eval.csv")
    if not episodes:
        raise ValueError(f"{run_dir} has no finished training episodes to plot (episodes.csv)")
    fig, (ax_success, ax_length) = subplots(1, 2, figsize=(11, 4))
    steps, success = binned_by_start(episodes, "success")
    ax_success.plot(steps, success, label="training episodes (by start step)")
    steps, length = binned_by_start(episodes, "length")
    ax_length.plot(steps, length, label="training episodes (by start step)")
    if evaluations:
        for mode, marker in (("greedy", "o"), ("sampled", "s")):
            ax_success.plot(evaluations["step"], evaluations[f"{mode}_success_rate"], marker, label=f"evaluation, {mode}")
            ax_length.plot(evaluations["step"], evaluations[f"{mode}_mean_length"], marker, label=f"evaluation, {mode}")
    ax_success.set(xlabel="environment steps", ylabel="success rate", ylim=(-0.02, 1.02))
    ax_length.set(xlabel="environment steps", ylabel="episode length (steps)")
    for axis in (ax_success, ax_length):
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
    fig.suptitle(title or str(run_dir))
    fig.tight_layout()
    return save_png(fig, Path(out) if out is not None else run_dir / "curves.png", dpi=110)


def plot_comparison(groups: dict[str, list[str | Path]], out: str | Path, *, title: str = "",
                    bins: int = 30, max_step: float | None = None) -> Path:
    """One line per group of runs (e.g. ``{"A3C": [seed0, seed1], "pre-trained + A3C": [...]}``):
    the training episodes' success rate by start step, and the evaluator's greedy success, each
    averaged over the group's runs (thin lines: the single runs); ``max_step`` cuts longer runs
    to a common budget. Writes a PNG to ``out``."""
    tables = {label: [(read_table(Path(r) / "episodes.csv"), read_table(Path(r) / "eval.csv")) for r in runs]
              for label, runs in groups.items()}
    if max_step is not None:
        tables = {label: [(_up_to(e, "start_step", max_step), _up_to(ev, "step", max_step)) for e, ev in runs]
                  for label, runs in tables.items()}
    for label, runs in tables.items():
        for (episodes, _), run in zip(runs, groups[label]):
            if not episodes:
                raise ValueError(f"{run} has no finished training episodes to plot (episodes.csv)")
    last = max(float(e["start_step"].max()) for runs in tables.values() for e, _ in runs)
    edges = np.linspace(0, last + 1, bins + 1)
    centres = (edges[:-1] + edges[1:]) / 2
    fig, (ax_train, ax_eval) = subplots(1, 2, figsize=(11, 4))
    for index, (label, runs) in enumerate(tables.items()):
        colour = f"C{index}"
        curves = []
        for episodes, _ in runs:
            steps, success = binned_by_start(episodes, "success", edges=edges)
            curve = np.full(len(centres), np.nan)
            curve[np.searchsorted(centres, steps)] = success
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
    ax_train.set(xlabel="environment steps", ylabel="success rate", title="training episodes (by start step)",
                 ylim=(-0.02, 1.02))
    ax_eval.set(xlabel="environment steps", ylabel="success rate", title="evaluation, greedy", ylim=(-0.02, 1.02))
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
