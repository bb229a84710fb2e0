"""Tests of the backward curricula's stage schedule (bimgame.learn.start_stages)."""

from __future__ import annotations

import pytest

from bimgame.learn.start_stages import BackwardStages


def test_stages_grow_by_the_factor_up_to_the_longest_distance():
    stages = BackwardStages("T", 0.1, 1.5, 0.4, threshold=0.8, window=10)
    assert stages.backs == pytest.approx([0.1, 0.15, 0.225, 0.3375, 0.50625])
    assert stages.back == 0.1 and not stages.finished
    whole = BackwardStages("T", 7, 2.0, 100, threshold=0.8, window=10, whole=True)
    assert whole.backs == [7, 14, 28, 56, 112]
    assert BackwardStages("T", 3, 1.4, 10, threshold=0.8, window=1, whole=True).backs == [3, 5, 7, 10]
    assert BackwardStages("T", None, 2.0, 100, threshold=0.8, window=10, whole=True).backs == [100]  # all at once


def test_a_full_window_at_the_threshold_moves_on_and_other_stages_do_not_count():
    stages = BackwardStages("T", 0.1, 2.0, 0.3, threshold=0.75, window=4)
    for success in (True, True, False):
        stages.record(0, success)
    assert stages.stage == 0 and stages.window_success == pytest.approx(2 / 3)
    stages.record(1, True)  # an episode of a later stage (or -1, a true start) does not count
    stages.record(-1, True)
    assert stages.stage == 0
    stages.record(0, True)  # 3 of 4
    assert stages.stage == 1 and stages.window_success == 0.0 and stages.back == 0.2
    for _ in range(4):
        stages.record(1, False)
    assert stages.stage == 1  # a full window below the threshold keeps the stage
    for _ in range(4):
        stages.record(1, True)
    assert stages.stage == 2 and stages.back == 0.3  # clipped to the longest distance
    for _ in range(4):
        stages.record(2, True)
    assert stages.finished and stages.back == 0.3
    stages.record(3, True)  # nothing moves once finished
    assert stages.stage == 3


def test_distances_must_be_positive():
    with pytest.raises(ValueError, match="first_back and the longest distance must be finite and > 0"):
        BackwardStages("T", 0.0, 2.0, 1.0, threshold=0.8, window=1)
