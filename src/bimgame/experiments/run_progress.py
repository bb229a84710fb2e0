"""What a benchmark's runs have done so far, read from their logs while they run.

A benchmark trains its seeds in worker processes, each run's own progress bar off: several bars
from several processes garble one terminal and fill a ``nohup`` log with redraws, and a run of an
hour or more was silent until it ended. Instead the parent reads every run's CSV log each
``interval`` seconds and prints one line for each run whose log has grown
(:func:`completed_with_progress`), readable in a terminal and in a log file alike:

    seed 1: DAgger 3/8 iterations, 8,905 labels; in-run greedy 0% (return 0.15), sampled 0% (0.17)
    seed 0: PPO 250,880/1,000,000 steps (25%); last 100 episodes from the start: 12% solved, return 0.84

The lines come from the logs the runs write anyway (``dagger.csv``, ``episodes.csv``), whose rows
are appended and flushed one at a time; a row being written is left out
(:func:`~bimgame.learn.curves.read_table`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Hashable, Iterator, Mapping
from concurrent.futures import FIRST_COMPLETED, Future, wait
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from bimgame.learn.curves import read_table

__all__ = ["PROGRESS_INTERVAL_S", "dagger_progress", "training_progress", "completed_with_progress"]

#: Seconds between two looks at the runs' logs: a DAgger iteration or 10k PPO steps take minutes.
PROGRESS_INTERVAL_S = 60.0
#: Training episodes from the layout's start whose success and return a PPO line reports.
RECENT_EPISODES = 100

Key = TypeVar("Key", bound=Hashable)
Result = TypeVar("Result")


def dagger_progress(run_dir: str | Path, iterations: int) -> str | None:
    """One line on a DAgger run's progress from its ``dagger.csv``: iterations done of
    ``iterations``, labels aggregated and the last iteration's in-run evaluation (if the run has
    one); None before its first iteration has ended."""
    table = read_table(Path(run_dir) / "dagger.csv")
    if not len(table.get("iteration", ())):
        return None
    last = {name: float(column[-1]) for name, column in table.items()}
    line = f"DAgger {int(last['iteration']) + 1}/{iterations} iterations, {int(last['labels']):,} labels"
    if np.isnan(last.get("greedy_success_rate", np.nan)):  # a run without in-run evaluation
        return line
    return (
        f"{line}; in-run greedy {last['greedy_success_rate']:.0%} (return {last['greedy_mean_return']:.2f}), "
        f"sampled {last['sampled_success_rate']:.0%} ({last['sampled_mean_return']:.2f})"
    )


def training_progress(
    run_dir: str | Path, steps: int, *, learner: str = "PPO", recent: int = RECENT_EPISODES
) -> str | None:
    """One line on a PPO or A3C run's progress from its ``episodes.csv`` (``learner`` names it):
    steps done of ``steps`` and the success rate and mean return of its last ``recent`` training
    episodes from the task's own start (all episodes where the log does not mark the start); None
    before its first episode."""
    episodes = read_table(Path(run_dir) / "episodes.csv")
    if not len(episodes.get("step", ())):
        return None
    step = int(episodes["step"][-1])
    chosen = episodes["true_start"] == 1 if "true_start" in episodes else np.ones(len(episodes["step"]), bool)
    line = f"{learner} {step:,}/{steps:,} steps ({step / steps:.0%})"
    if not chosen.any():
        return line + "; no episode from the start yet"
    success = episodes["success"][chosen][-recent:]
    returns = episodes["return"][chosen][-recent:]
    return (
        f"{line}; last {len(success)} episodes from the start: {np.mean(success):.0%} solved, "
        f"return {np.mean(returns):.2f}"
    )


def completed_with_progress(
    futures: Mapping[Future[Result], Key],
    describe: Callable[[Key], str | None],
    *,
    name: Callable[[Key], str] = str,
    interval: float = PROGRESS_INTERVAL_S,
    echo: Callable[[str], Any] | None = None,
) -> Iterator[Future[Result]]:
    """The ``futures`` as they complete (as :func:`concurrent.futures.as_completed`), and meanwhile,
    every ``interval`` seconds, ``echo`` of ``"NAME: LINE"`` (``name(key)``, ``describe(key)``) for
    each unfinished run whose line has changed since it was last shown (None: nothing to show yet; a
    log that cannot be read is said so, and the runs go on).
    ``echo`` defaults to a print that flushes each line, so a log file shows it at once."""
    echo = echo or functools.partial(print, flush=True)
    if interval <= 0:
        raise ValueError(f"interval must be > 0 seconds, got {interval!r}")
    pending: set[Future[Result]] = set(futures)
    shown: dict[Key, str] = {}
    while pending:
        done, pending_now = wait(pending, timeout=interval, return_when=FIRST_COMPLETED)
        pending = set(pending_now)
        for future in pending:
            key = futures[future]
            try:
                line = describe(key)
            except (OSError, ValueError) as error:  # a log it cannot read must not end the runs it watches
                line = f"progress unreadable ({type(error).__name__}: {error})"
            if line is not None and line != shown.get(key):
                shown[key] = line
                echo(f"{name(key)}: {line}")
        yield from done
