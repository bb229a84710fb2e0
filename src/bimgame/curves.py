"""Learning curves of a training run, drawn from its CSV logs (see :mod:`bimgame.runs`)."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from bimgame.io import atomic_write_bytes

__all__ = ["read_table", "binned_by_start", "plot_run"]


def read_table(path: str | Path) -> dict[str, np.ndarray]:
    """A run's CSV log as columns of floats (empty cells are NaN); empty dict if there is none."""
    path = Path(path)
    if not path.is_file():
        return {}
    with path.open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    if not rows:
        return {}
    return {key: np.array([float(r[key]) if r[key] not in ("", None) else np.nan for r in rows])
            for key in rows[0]}


def binned_by_start(episodes: dict[str, np.ndarray], key: str, bins: int = 40,
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``key`` over episodes grouped by the step they *started* at (counting by the end
    step would favour short, successful episodes early in training). Returns (bin centres, means)."""
    start = episodes["start_step"]
    edges = np.linspace(start.min(), start.max() + 1, bins + 1)
    index = np.clip(np.digitize(start, edges) - 1, 0, bins - 1)
    counts = np.bincount(index, minlength=bins)
    sums = np.bincount(index, weights=episodes[key], minlength=bins)
    keep = counts > 0
    return ((edges[:-1] + edges[1:]) / 2)[keep], sums[keep] / counts[keep]


def plot_run(run_dir: str | Path, out: str | Path | None = None, title: str | None = None) -> Path:
    """Success rate and episode length against environment steps (training episodes binned by
    start step, plus the evaluator's greedy and sampled episodes); writes a PNG (default
    ``RUN_DIR/curves.png``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run_dir = Path(run_dir)
    episodes = read_table(run_dir / "episodes.csv")
    evaluations = read_table(run_dir / "eval.csv")
    if not episodes:
        raise ValueError(f"{run_dir} has no finished training episodes to plot (episodes.csv)")
    fig, (ax_success, ax_length) = plt.subplots(1, 2, figsize=(11, 4))
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
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    return atomic_write_bytes(Path(out) if out is not None else run_dir / "curves.png", buffer.getvalue())
