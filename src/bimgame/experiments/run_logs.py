"""What a finished A3C, PPO or DAgger run logged, as read back from its directory (:class:`RunResults`),
and the success rate of its last training episodes (:func:`final_training_success`).

An A3C or PPO run's training episodes count only where every episode that started has ended and is in its
log (:attr:`RunResults.until`, see :mod:`bimgame.learn.curves`): the log's last stretch holds the
short, successful episodes that started there but not the long ones still running when it stopped.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.learn.curves import complete_until, episode_span, finished_at

__all__ = ["FINAL_SHARE", "RunResults", "final_training_success"]

#: Share of a run's steps whose training episodes give its "final" success rate.
FINAL_SHARE = 0.1


@dataclasses.dataclass
class RunResults:
    """What a finished A3C, PPO or DAgger run logged, as read back from its directory."""

    seed: int
    path: Path
    episodes: dict[str, np.ndarray]
    table: dict[str, np.ndarray]
    """eval.csv (A3C, PPO) or dagger.csv (DAgger)."""
    summary: dict[str, Any] | None
    config: dict[str, Any] = dataclasses.field(default_factory=dict)
    """config.json (A3C, PPO; {} when there is none)."""

    @functools.cached_property
    def span(self) -> float:
        """The most environment steps one training episode can take from its start to its logged end
        (:func:`bimgame.learn.curves.episode_span`)."""
        return episode_span(self.episodes, _schedule_config(self.config))

    @functools.cached_property
    def until(self) -> float:
        """Every training episode that started before this step has ended and is in the log
        (:func:`bimgame.learn.curves.complete_until`)."""
        return complete_until(self.episodes, self.span, finished_at=finished_at(self.summary))


def _schedule_config(config: dict[str, Any]) -> dict[str, Any]:
    """``config`` as :func:`~bimgame.learn.curves.episode_span` reads a run's schedule: from its
    ``"a3c"`` settings. A PPO run keeps the same names (task, workers, envs_per_worker, n_steps,
    max_episode_steps) under ``"ppo"``, so its span is reckoned from them alike."""
    if "a3c" not in config and isinstance(config.get("ppo"), dict):
        return {**config, "a3c": config["ppo"]}
    return config


def final_training_success(run: RunResults, steps: int) -> float:
    """Success rate of the training episodes that started in the last :data:`FINAL_SHARE` of a run's
    ``steps`` before :attr:`RunResults.until` — the latest stretch of that length whose episodes
    have all ended — (NaN when there are none)."""
    if not run.episodes:
        return float("nan")
    end = min(run.until, float(steps))
    start = run.episodes["start_step"]
    late = (start >= end - FINAL_SHARE * steps) & (start < end)
    return float(np.mean(run.episodes["success"][late])) if late.any() else float("nan")
