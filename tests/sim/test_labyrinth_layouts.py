"""Tests of CyberRunner's three layouts (bimgame.sim.labyrinth_layouts): the transcribed data is
consistent with the board it describes — paths run inside the board, clear of walls and holes,
holes lie clear of walls — and the frame transform is the documented one."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.sim.labyrinth_layouts import BOARD_SIZE, LAYOUT_NAMES, WALL_THICKNESS, get_layout

#: The repository's counts per layout: horizontal + vertical walls, holes, waypoints.
COUNTS = {"easy": (18 + 14, 8, 37), "medium": (20 + 20, 16, 30), "hard": (18 + 35, 40, 71)}


@pytest.fixture(scope="module", params=LAYOUT_NAMES)
def spec(request) -> LabyrinthSpec:
    return LabyrinthSpec.layout(request.param)


def polyline_samples(waypoints, step: float = 0.5e-3) -> np.ndarray:
    """Points every ``step`` m along the path through ``waypoints``."""
    points = np.asarray(waypoints)
    out = []
    for a, b in zip(points[:-1], points[1:], strict=True):
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / step)) + 1)
        out.append(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a))
    return np.concatenate(out)


def test_three_layouts_with_the_repository_counts():
    assert LAYOUT_NAMES == ("easy", "medium", "hard")
    for name in LAYOUT_NAMES:
        layout = get_layout(name)
        assert (len(layout.walls), len(layout.holes), len(layout.waypoints)) == COUNTS[name]


def test_transform_centres_the_board_without_flipping():
    """The hard layout's first waypoint is (150, 218) mm from the lower-left corner: (0.012, 0.1025) m
    from the centre; its first horizontal wall spans x 0..25 mm at y = 204.5 mm, 5 mm thick."""
    hard = get_layout("hard")
    assert hard.start == pytest.approx((0.150 - 0.138, 0.218 - 0.1155))
    x0, y0, x1, y1 = hard.walls[0]
    assert (x0, x1) == pytest.approx((-BOARD_SIZE[0] / 2, 0.025 - 0.138))
    assert (y0, y1) == pytest.approx((0.2045 - 0.1155 - WALL_THICKNESS / 2, 0.2045 - 0.1155 + WALL_THICKNESS / 2))


def test_every_wall_lies_on_the_board(spec):
    walls = np.array(spec.walls)
    hx, hy = spec.board_size[0] / 2, spec.board_size[1] / 2
    tol = WALL_THICKNESS / 2 + 1e-12  # a wall along the rim may overlap it by its half thickness
    assert np.all(walls[:, [0, 2]] >= -hx - tol) and np.all(walls[:, [0, 2]] <= hx + tol)
    assert np.all(walls[:, [1, 3]] >= -hy - tol) and np.all(walls[:, [1, 3]] <= hy + tol)


def test_waypoints_inside_board_and_clear_of_walls(spec):
    """Every waypoint, and every point of the path between them, lies inside the board and at least
    5 mm from any wall (the data's tightest spot is 5.2 mm): the path never crosses a wall."""
    clearance = spec.clearance(polyline_samples(spec.waypoints))
    assert clearance.min() > 5e-3
    assert spec.clearance(np.array(spec.waypoints)).min() > 5e-3


def test_start_and_path_are_not_over_holes(spec):
    assert not spec.over_hole(spec.start)
    assert not np.any(spec.over_hole(polyline_samples(spec.waypoints)))


def test_holes_are_clear_of_walls(spec):
    """A hole's whole opening is floor: its centre is farther than the hole radius from every wall."""
    assert np.all(spec.clearance(np.array(spec.holes)) > spec.hole_radius)


def test_goal_is_the_last_waypoint(spec):
    assert spec.reached_goal(spec.waypoints[-1])
    assert not spec.reached_goal(spec.start)


def test_unknown_layout_names_the_allowed_ones():
    with pytest.raises(ValueError, match="'easy', 'medium', 'hard'"):
        get_layout("expert")
    with pytest.raises(ValueError, match="wall_thickness"):
        get_layout("easy", wall_thickness=0.0)
