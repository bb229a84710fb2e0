"""CyberRunner's off-path test as a map (bimgame.sim.labyrinth_box_sight): open floor far from the
path still sees it, a wall or a hole between the marble and the path hides it, positions off the
board are off it, and on the real layouts it differs from the tolerance rule where it should."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.sim.labyrinth_box_sight import SIGHT_CELL, PathBoxSight, path_box_sight


def line_board(**changes) -> LabyrinthSpec:
    """An open board with a straight path along x through the centre (no walls, no holes)."""
    fields = dict(walls=(), holes=(), waypoints=((-0.1, 0.0), (0.1, 0.0)), name="line")
    return LabyrinthSpec(**{**fields, **changes})


def test_open_floor_sees_the_path_however_far_and_off_the_board_does_not():
    sight = PathBoxSight(line_board())
    assert sight.on_path(np.array([[0.0, 0.0], [0.0, 0.05], [0.05, -0.1], [0.13, 0.1]])).all()
    assert not sight.on_path(np.array([[0.0, 0.2], [-0.3, 0.0]])).any()  # beyond the board's edges
    assert sight.on_path([0.0, 0.05]).shape == ()  # one position, one answer


def test_a_wall_or_a_hole_between_marble_and_path_hides_it():
    wall = (-0.12, 0.01, 0.12, 0.015)  # a wall across the whole path, 10-15 mm above it
    walled = PathBoxSight(line_board(walls=(wall,)))
    assert not walled.on_path([0.0, 0.03]) and walled.on_path([0.0, 0.005])
    holed = PathBoxSight(line_board(holes=((0.0, 0.02),)))  # a hole (radius 7.5 mm) 20 mm above the path
    assert not holed.on_path([0.0, 0.04])  # straight behind the hole: the box stops at its edge
    assert holed.on_path([0.0 + 0.0075 + 2 * SIGHT_CELL, 0.04])  # beside it: the hole does not cover x
    # A wall covers positions within a marble radius beyond its ends (CyberRunner widens walls by it).
    short = PathBoxSight(line_board(walls=((-0.02, 0.01, 0.02, 0.015),)))
    assert not short.on_path([0.02 + 0.005, 0.03]) and short.on_path([0.02 + 0.008, 0.03])


@pytest.mark.parametrize(("layout", "lenient", "strict"), [("easy", True, False), ("hard", False, True)])
def test_on_the_layouts_it_is_more_lenient_on_open_floor_and_stricter_beside_holes(layout, lenient, strict):
    """Free positions 2 mm apart, the box test against the tolerance rule (a segment within 25 mm in
    sight): on easy's open floor the box sees path the tolerance does not (and rarely the reverse);
    on hard's narrow corridors lined with holes the box is the stricter."""
    spec = LabyrinthSpec.layout(layout)
    x, y = np.meshgrid(np.arange(-0.136, 0.137, 0.002), np.arange(-0.114, 0.115, 0.002))
    points = np.stack([x, y], -1).reshape(-1, 2)
    points = points[spec.clearance(points) > spec.marble_radius]
    every = np.broadcast_to(np.arange(spec.path.n_segments), (len(points), spec.path.n_segments))
    tolerance = spec.path.in_sight(points, every)[2].any(axis=-1)
    box = path_box_sight(spec).on_path(points)
    more, fewer = int((box & ~tolerance).sum()), int((tolerance & ~box).sum())
    assert (more > 2 * fewer) is lenient and (fewer > 2 * more) is strict, (more, fewer)
    assert path_box_sight(spec) is path_box_sight(spec)  # computed once per board
