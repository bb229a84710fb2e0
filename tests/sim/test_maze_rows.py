"""Geodesic distances of many mazes at once equal each maze's own."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.sim.maze import MazeSpec, MazeSpecError
from bimgame.sim.maze_rows import MazeRows
from bimgame.sim.maze_sets import maze_number


def _specs() -> list[MazeSpec]:
    """Twelve random mazes and MERL's."""
    return [maze_number(i) for i in range(12)] + [MazeSpec.merl()]


def _points(rows: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """400 random board points per row, (rows, 400) x and y, inside the rim."""
    rng = np.random.default_rng(seed)
    radius = rng.uniform(0.0, 0.0968, (rows, 400))
    angle = rng.uniform(-np.pi, np.pi, (rows, 400))
    return radius * np.cos(angle), radius * np.sin(angle)


def test_rows_give_each_mazes_own_geodesic_distance():
    specs = _specs()
    rows = MazeRows(MazeSpec.merl(), len(specs), max_gates=4)
    for i, spec in enumerate(specs):
        rows.set_row(i, spec)
    x, y = _points(len(specs), seed=0)
    expected = np.stack([spec.geodesic_distance(x[i], y[i]) for i, spec in enumerate(specs)])
    np.testing.assert_array_equal(rows.geodesic_distance(x, y), expected)
    rows.set_row(0, specs[1])  # a row switched to another maze forgets the old one's gates
    np.testing.assert_array_equal(rows.geodesic_distance(x, y)[0], specs[1].geodesic_distance(x[0], y[0]))


def test_rows_measure_to_a_tasks_goal_channel_as_each_maze_does():
    specs = _specs()
    x, y = _points(len(specs), seed=1)
    for to_channel in (1, 3):
        rows = MazeRows(MazeSpec.merl(), len(specs), max_gates=4, to_channels=(to_channel,))
        for i, spec in enumerate(specs):
            rows.set_row(i, spec)
        expected = np.stack([spec.geodesic_distance(x[i], y[i], to_channel) for i, spec in enumerate(specs)])
        np.testing.assert_array_equal(rows.geodesic_distance(x, y), expected)
        assert (expected == 0).any() and (expected > 0).any()  # points past the goal wall, and before it
    with pytest.raises(MazeSpecError, match="to_channel must be an integer in 0..3, got 4"):
        MazeRows(MazeSpec.merl(), 2, max_gates=4, to_channels=(0, 4))


def test_one_pass_to_several_targets_equals_a_pass_to_each():
    specs = _specs()
    x, y = _points(len(specs), seed=2)
    both = MazeRows(MazeSpec.merl(), len(specs), max_gates=4, to_channels=(0, 3))
    for i, spec in enumerate(specs):
        both.set_row(i, spec)
    centre, goal = both.geodesic_distances(x, y)
    np.testing.assert_array_equal(centre, np.stack([s.geodesic_distance(x[i], y[i]) for i, s in enumerate(specs)]))
    np.testing.assert_array_equal(goal, np.stack([s.geodesic_distance(x[i], y[i], 3) for i, s in enumerate(specs)]))
    one = [specs[0].geodesic_distances_one(float(a), float(b), (0, 3)) for a, b in zip(x[0], y[0], strict=True)]
    np.testing.assert_allclose(np.array(one), np.stack([centre[0], goal[0]], axis=1), rtol=0, atol=1e-12)
