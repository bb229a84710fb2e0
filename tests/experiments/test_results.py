"""Reading a run's results back: its final training success counts only the episodes known to
have ended."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bimgame.experiments.results import RunResults, final_training_success


def _rate(episodes: dict, low: float, high: float) -> float:
    """Success rate of the episodes that started in [low, high)."""
    start = episodes["start_step"]
    return float(episodes["success"][(start >= low) & (start < high)].mean())


def test_final_training_success_leaves_out_episodes_that_may_still_be_running(running_log):
    # 50% success throughout; an episode spans at most 200 × 64 steps. The run's log stops at
    # 400k; the same run logged 200 × 64 steps longer holds every episode started before 400k.
    steps, span = 400_000, 200 * 64
    episodes, whole = running_log(steps), running_log(steps + span)
    # Before: the episodes that started in the last 10% of the steps, without the failing ones
    # still running at 400k (0.573 against 0.476 with them).
    assert _rate(episodes, 360_000, steps) - _rate(whole, 360_000, steps) > 0.05
    run = RunResults(0, Path("run"), episodes, {}, None)
    assert run.until == episodes["step"].max() - span + 1  # the last logged end step − the span
    assert final_training_success(run, steps) == pytest.approx(_rate(whole, run.until - 40_000, run.until))
    assert final_training_success(run, steps) == pytest.approx(0.5, abs=0.05)
    # The run's settings (config.json) give the longest an episode may take: here longer than any
    # logged; a finished run's summary gives its last step.
    a3c = {"task": "STG1", "max_episode_steps": 200, "workers": 1, "envs_per_worker": 64, "n_steps": 20}
    run = RunResults(0, Path("run"), episodes, {}, {"stopped": "finished", "steps": steps + 64}, {"a3c": a3c})
    assert run.span == (200 + 20) * 64 and run.until == steps + 64 - run.span + 1
    assert final_training_success(run, steps) == pytest.approx(_rate(whole, run.until - 40_000, run.until))
    assert np.isnan(final_training_success(RunResults(0, Path("run"), {}, {}, None), steps))
