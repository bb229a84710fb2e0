"""How good the MPC expert is: success rate and episode lengths over many seeded episodes, run in
parallel worker processes, and the histogram of trajectory lengths (the paper's Fig. 1b)."""

from __future__ import annotations

import dataclasses
import io
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.expert import MPCConfig, episode_seed, run_expert_episode
from bimgame.io import atomic_write_bytes
from bimgame.tasks import parse_task

__all__ = ["evaluate_expert", "summarise", "plot_length_histogram", "EpisodeResult"]


@dataclasses.dataclass(frozen=True)
class EpisodeResult:
    index: int
    seed: int
    success: bool
    length: int
    episode_return: float
    seconds: float


def _one_episode(task: str, index: int, run_seed: int, config: MPCConfig, max_steps: int | None) -> EpisodeResult:
    seed = episode_seed(run_seed, index)
    start = time.perf_counter()
    episode = run_expert_episode(task, seed, config, max_steps=max_steps)
    return EpisodeResult(index, seed, bool(episode["success"]), int(len(episode["actions"])),
                         float(episode["rewards"].sum()), time.perf_counter() - start)


def evaluate_expert(task: str, episodes: int, config: MPCConfig | None = None, *, seed: int = 0,
                    workers: int | None = None, max_steps: int | None = None,
                    progress: bool = True) -> list[EpisodeResult]:
    """Run ``episodes`` expert episodes (episode i from :func:`episode_seed`(seed, i)) on ``workers``
    processes (default: all cores); results sorted by episode index, independent of ``workers``."""
    parse_task(task)
    config = config if config is not None else MPCConfig()
    if not (isinstance(episodes, int) and episodes >= 1):
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    workers = workers if workers is not None else (os.cpu_count() or 1)
    if not (isinstance(workers, int) and workers >= 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    config = dataclasses.replace(config, nthread=1)  # one thread per worker process
    results: list[EpisodeResult] = []
    with _progress(progress, f"expert on {task}", episodes) as update:
        if workers == 1:
            for i in range(episodes):
                results.append(_one_episode(task, i, seed, config, max_steps))
                update(results)
        else:
            with ProcessPoolExecutor(max_workers=workers) as pool:
                futures = [pool.submit(_one_episode, task, i, seed, config, max_steps) for i in range(episodes)]
                for future in as_completed(futures):
                    results.append(future.result())
                    update(results)
    return sorted(results, key=lambda r: r.index)


class _progress:
    """A rich progress bar (episodes, success so far, ETA), or nothing."""

    def __init__(self, enabled: bool, label: str, total: int):
        self.enabled, self.label, self.total = enabled, label, total

    def __enter__(self):
        if not self.enabled:
            return lambda results: None
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self.bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                            TextColumn("success {task.fields[success]}"), TimeRemainingColumn(),
                            transient=True)
        self.bar.__enter__()
        task = self.bar.add_task(self.label, total=self.total, success="-")

        def update(results: list[EpisodeResult]) -> None:
            rate = np.mean([r.success for r in results])
            self.bar.update(task, completed=len(results), success=f"{rate:.0%}")
        return update

    def __exit__(self, *exc) -> None:
        if self.enabled:
            self.bar.__exit__(*exc)


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
    """The paper's Fig. 1b: histogram of the lengths of successful expert trajectories (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    solved = [r.length for r in results if r.success]
    failed = sum(not r.success for r in results)
    fig, ax = plt.subplots(figsize=(6, 3.6))
    if solved:
        ax.hist(solved, bins=min(30, max(5, len(solved) // 3)), color="#4c72b0", edgecolor="white")
        ax.axvline(float(np.median(solved)), color="black", ls="--", lw=1,
                   label=f"median {np.median(solved):.0f} steps")
        ax.legend()
    ax.set_xlabel("trajectory length (steps at 30 Hz)")
    ax.set_ylabel("episodes")
    ax.set_title(f"{title}: {len(solved)} solved, {failed} not", fontsize=10)
    buffer = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buffer, format="png", dpi=130)
    plt.close(fig)
    return atomic_write_bytes(path, buffer.getvalue())


def write_results(results: list[EpisodeResult], summary: dict, config: MPCConfig, task: str, path: str | Path) -> Path:
    """Per-episode results, summary and settings as JSON (atomically)."""
    payload = {"task": task, "config": dataclasses.asdict(config), "summary": summary,
               "episodes": [dataclasses.asdict(r) for r in results]}
    return atomic_write_bytes(path, json.dumps(payload, indent=1).encode())
