"""Synthetic training logs shared by the curve and report tests, and writing them as a run does."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np


def running_log(steps: int, *, envs: int = 64, limit: int = 200, rate: float = 0.5, seed: int = 0) -> dict:
    """The episodes.csv columns of ``envs`` environments stepped in lockstep until ``steps`` (the
    x-axis counts the steps of all environments together, as A3C's does): every episode succeeds
    with probability ``rate`` whatever its start, in 5–30 steps, or fails at the time limit
    ``limit``. Only the episodes that ended by ``steps`` are logged, as in a run's log: near the
    end the long, failing episodes are missing."""
    rng = np.random.default_rng(seed)
    start = np.zeros(envs)
    length = np.zeros(envs)
    wins = rng.random(envs) < rate
    target = np.where(wins, rng.integers(5, 31, envs), limit)
    rows = []
    for tick in range(steps // envs):
        length += 1
        now = (tick + 1) * envs
        for i in np.flatnonzero(length >= target):
            rows.append((now, start[i], length[i], float(wins[i])))
            start[i], length[i] = now, 0
            wins[i] = rng.random() < rate
            target[i] = rng.integers(5, 31) if wins[i] else limit
    step, start_step, lengths, success = map(np.array, zip(*rows))
    return {"step": step, "start_step": start_step, "worker": np.zeros(len(step)), "return": success,
            "length": lengths, "success": success}


def write_csv(path: Path, rows: list[dict]) -> None:
    """A log table as a run writes it: a header from the first row's keys, then the rows."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
