"""How good the MPC expert is: success rate and episode lengths over many seeded episodes, run in
parallel worker processes, and the histogram of trajectory lengths (the paper's Fig. 1b)."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.expert.mpc import MPCConfig
from bimgame.expert.pool import episode_progress, expert_episodes
from bimgame.sim.tasks import parse_task
from bimgame.util.files import atomic_write_bytes, reporting_full_disk
from bimgame.util.images import save_png, subplots

__all__ = ["evaluate_expert", "summarise", "plot_length_histogram", "write_results", "EpisodeResult"]


@dataclasses.dataclass(frozen=True)
class EpisodeResult:
    index: int
    seed: int
    success: bool
    length: int
    episode_return: float
    seconds: float


def evaluate_expert(
    task: str,
    episodes: int,
    config: MPCConfig | None = None,
    *,
    seed: int = 0,
    workers: int | None = None,
    max_steps: int | None = None,
    progress: bool = True,
) -> list[EpisodeResult]:
    """Run ``episodes`` expert episodes (episode i from :func:`~bimgame.util.seeding.episode_seed`(seed, i))
    on ``workers`` processes (default: all cores, see :func:`~bimgame.expert.pool.expert_episodes`);
    results sorted by episode index, independent of ``workers``."""
    parse_task(task)
    config = config if config is not None else MPCConfig()
    if not (isinstance(episodes, int) and episodes >= 1):
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    workers = workers if workers is not None else (os.cpu_count() or 1)
    results: list[EpisodeResult] = []
    with episode_progress(progress, f"expert on {task}", episodes, transient=True) as update:
        for index, episode, seconds in expert_episodes(
            task, list(range(episodes)), seed, config, max_steps=max_steps, workers=workers
        ):
            results.append(
                EpisodeResult(
                    index,
                    int(episode["seed"]),
                    bool(episode["success"]),
                    len(episode["actions"]),
                    float(episode["rewards"].sum()),
                    seconds,
                )
            )
            update(results[-1].success)
    return sorted(results, key=lambda r: r.index)


def summarise(results: list[EpisodeResult]) -> dict[str, Any]:
    """Success rate, episode-length statistics (all episodes and successful ones) and timing."""
    lengths = np.array([r.length for r in results])
    solved = np.array([r.length for r in results if r.success])
    seconds = sum(r.seconds for r in results)
    return {
        "episodes": len(results),
        "success_rate": float(np.mean([r.success for r in results])),
        "mean_length": float(lengths.mean()),
        "median_length_solved": float(np.median(solved)) if len(solved) else None,
        "p90_length_solved": float(np.percentile(solved, 90)) if len(solved) else None,
        "max_length_solved": int(solved.max()) if len(solved) else None,
        "mean_return": float(np.mean([r.episode_return for r in results])),
        "ms_per_decision": 1e3 * seconds / max(int(lengths.sum()), 1),
    }


def plot_length_histogram(results: list[EpisodeResult], path: str | Path, *, title: str) -> Path:
    """The paper's Fig. 1b: histogram of the lengths of successful expert trajectories (PNG,
    written atomically; a full disk raises :class:`~bimgame.util.files.DiskFullError` naming it)."""
    solved = [r.length for r in results if r.success]
    failed = sum(not r.success for r in results)
    fig, ax = subplots(figsize=(6, 3.6))
    if solved:
        ax.hist(solved, bins=min(30, max(5, len(solved) // 3)), color="#4c72b0", edgecolor="white")
        ax.axvline(
            float(np.median(solved)), color="black", ls="--", lw=1, label=f"median {np.median(solved):.0f} steps"
        )
        ax.legend()
    ax.set_xlabel("trajectory length (steps at 30 Hz)")
    ax.set_ylabel("episodes")
    ax.set_title(f"{title}: {len(solved)} solved, {failed} not", fontsize=10)
    fig.tight_layout()
    with reporting_full_disk(path):
        return save_png(fig, path, dpi=130)


def write_results(results: list[EpisodeResult], summary: dict, config: MPCConfig, task: str, path: str | Path) -> Path:
    """Per-episode results, summary and settings as JSON (atomically; a full disk raises
    :class:`~bimgame.util.files.DiskFullError` naming the file)."""
    payload = {
        "task": task,
        "config": dataclasses.asdict(config),
        "summary": summary,
        "episodes": [dataclasses.asdict(r) for r in results],
    }
    with reporting_full_disk(path):
        return atomic_write_bytes(path, json.dumps(payload, indent=1).encode())
