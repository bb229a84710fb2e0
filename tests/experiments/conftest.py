"""Fixtures shared by the experiments tests: a tiny budget that runs every kind of piece in seconds,
and hand-made training episodes with known success rates."""

from __future__ import annotations

from typing import Callable

import numpy as np
import pytest
from support import logs

from bimgame.experiments.budgets import BUDGETS, Budget

#: A reproduction small enough for a test: the ``smoke`` preset's sizes (16-unit networks, 2,000 A3C
#: steps on one worker, one DAgger iteration of two episodes, two seeds), narrowed to four STG1 expert
#: episodes on one worker and three algorithms that cover every kind of piece: plain A3C, A3C from
#: π^s with V̂'s reward (both pre-trainings), and DAgger.
TINY = BUDGETS["smoke"].replace(name="tiny", algorithms=("a3c", "pretrain+a3c+value", "dagger"),
                                a3c={"steps": {"STG1": 2_000}, "checkpoint_every": 400},
                                dataset={"task": "STG1", "workers": 1})


@pytest.fixture
def tiny_budget() -> Budget:
    """:data:`TINY`."""
    return TINY


def _episodes(ranges: list[tuple[int, int, float]], bin_steps: int, per_bin: int = 20) -> dict:
    """Training episodes: in every bin of ``bin_steps`` inside each (start, end, rate) range,
    ``per_bin`` episodes started evenly, exactly round(rate · per_bin) of them successful."""
    starts, successes = [], []
    for low, high, rate in ranges:
        for left in range(low, high, bin_steps):
            wins = int(round(rate * per_bin))
            starts += list(np.linspace(left, left + bin_steps - 1, per_bin))
            successes += [1.0] * wins + [0.0] * (per_bin - wins)
    n = len(starts)
    return {"start_step": np.array(starts), "success": np.array(successes), "return": np.array(successes),
            "length": np.full(n, 50.0), "worker": np.zeros(n)}


@pytest.fixture
def training_episodes() -> Callable[..., dict]:
    """``episodes(ranges, bin_steps, per_bin=20)``: the columns of an ``episodes.csv`` with known
    success rates per bin (see :func:`_episodes`)."""
    return _episodes


@pytest.fixture
def running_log() -> Callable[..., dict]:
    """``running_log(steps, envs=64, limit=200, rate=0.5)``: a run's episodes.csv columns with a
    success rate that does not change, whose last episodes are still running (see :func:`support.logs.running_log`)."""
    return logs.running_log
