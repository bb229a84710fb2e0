"""Tests of the labyrinth's spec and rules (bimgame.sim.labyrinth): validation with errors that name
the field, hashing, holes, the goal and the path-progress rule (no pay for skipped path)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bimgame.sim.labyrinth import LabyrinthSpec, PathProgress, WaypointPath
from bimgame.sim.labyrinth_layouts import LAYOUT_NAMES
from bimgame.sim.maze import Friction


@pytest.fixture(scope="module")
def hard() -> LabyrinthSpec:
    return LabyrinthSpec.layout("hard")


def walk(waypoints, step: float) -> np.ndarray:
    """Points every ``step`` m along the polyline (the marble following the path exactly)."""
    pts = np.asarray(waypoints)
    out = [pts[0]]
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        n = max(1, math.ceil(np.linalg.norm(b - a) / step))
        out.extend(a + (b - a) * (i / n) for i in range(1, n + 1))
    return np.array(out)


# ------------------------------------------------------------------------------------ the spec
def test_layouts_are_hashable_and_equal_by_value():
    specs = {LabyrinthSpec.layout(name) for name in LAYOUT_NAMES}
    assert len(specs) == 3
    assert LabyrinthSpec.layout("easy") == LabyrinthSpec.layout("easy")
    assert hash(LabyrinthSpec.layout("easy")) == hash(LabyrinthSpec.layout("easy"))
    assert LabyrinthSpec.layout("easy", max_tilt=0.1).max_tilt == 0.1


def test_lists_become_tuples_of_floats():
    spec = LabyrinthSpec(walls=[[0, 0, 0.01, 0.01]], holes=[], waypoints=np.array([[-0.1, 0.0], [0.1, 0.0]]))
    assert spec.walls == ((0.0, 0.0, 0.01, 0.01),) and spec.holes == ()
    assert isinstance(spec.waypoints[0][0], float)
    hash(spec)


def test_chosen_defaults_are_documented_values(hard):
    assert hard.board_size == (0.276, 0.231)
    assert hard.marble_radius == 0.006
    assert hard.marble_mass == pytest.approx(7850 * 4 / 3 * math.pi * 0.006**3)
    assert hard.max_tilt == pytest.approx(math.radians(10))


def test_unknown_layout_names_the_allowed_ones():
    with pytest.raises(ValueError, match=r"layout must be one of 'easy', 'medium', 'hard', got 'expert'"):
        LabyrinthSpec.layout("expert")


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"hole_radius": 0.0}, "hole_radius"),
        ({"marble_radius": -1.0}, "marble_radius"),
        ({"marble_mass": float("nan")}, "marble_mass"),
        ({"max_tilt": True}, "max_tilt"),
        ({"max_tilt": math.radians(31)}, "max_tilt"),
        ({"path_tolerance": "1"}, "path_tolerance"),
        ({"goal_radius": math.inf}, "goal_radius"),
        ({"wall_height": 0.005}, "wall_height"),
        ({"board_size": (0.2, -0.1)}, r"board_size\[1\]"),
        ({"board_size": (0.2,)}, "board_size"),
        ({"walls": ((0.0, 0.0, -0.01, 0.01),)}, r"walls\[0\]"),
        ({"walls": ((0.0, 0.0, 0.01),)}, "walls"),
        ({"holes": ((0.0, math.nan),)}, "holes"),
        ({"holes": ((0.5, 0.0),)}, r"holes\[0\]"),
        ({"waypoints": ((0.0, 0.0),)}, "waypoints"),
        ({"waypoints": ((0.0, 0.0), (0.0, 0.0))}, r"waypoints\[0\] and waypoints\[1\]"),
        ({"waypoints": ((0.0, 0.0), (0.135, 0.0))}, r"waypoints\[1\]"),
        ({"friction": (0.5, 0, 0, 0)}, "friction"),
        ({"friction": Friction(slide=-1.0)}, "friction.slide"),
        ({"name": 3}, "name"),
    ],
)
def test_bad_fields_raise_value_error_naming_them(hard, change, field):
    with pytest.raises(ValueError, match=field):
        dataclasses.replace(hard, **change)


# ------------------------------------------------------------------------------------ holes and goal
def test_over_hole_within_hole_radius(hard):
    hole = np.array(hard.holes[3])
    r = hard.hole_radius
    assert hard.over_hole(hole)
    assert hard.over_hole(hole + [r * 0.999, 0.0])
    assert not hard.over_hole(hole + [0.0, r * 1.001])
    batch = hard.over_hole(np.array([hole, hole + [0.0, 2 * r], hard.start]))
    assert batch.tolist() == [True, False, False]


def test_clearance_of_walls_and_rim(hard):
    x0, y0, x1, y1 = hard.walls[3]  # the hard layout's wall along y = 204.5 mm, x 94.5..159.5 mm
    assert hard.clearance(((x0 + x1) / 2, (y0 + y1) / 2)) <= 0
    assert hard.clearance(((x0 + x1) / 2, y1 + 0.004)) == pytest.approx(0.004)
    assert hard.clearance((0.2, 0.0)) < 0  # off the board


# ------------------------------------------------------------------------------------ path progress
def test_progress_increases_along_the_path_and_reaches_the_goal():
    for name in LAYOUT_NAMES:
        spec = LabyrinthSpec.layout(name)
        tracker = PathProgress(spec)
        points = walk(spec.waypoints, step=2e-3)
        first = tracker.reset(points[0], segment=0)
        assert first.progress == 0.0 and not first.off_path
        progress = [tracker.update(p) for p in points[1:]]
        values = np.array([s.progress for s in progress])
        assert np.all(np.diff(values) >= -1e-12)
        assert not any(s.off_path or s.over_hole for s in progress)
        assert values[-1] == pytest.approx(spec.path.length)
        assert sum(s.delta for s in progress) == pytest.approx(spec.path.length)
        assert progress[-1].goal and not any(s.goal for s in progress[: len(progress) // 2])


def test_progress_is_the_arc_length_of_the_projection():
    path = WaypointPath([(0.0, 0.0), (0.1, 0.0), (0.1, 0.05)], tolerance=0.01)
    arc, distance = path.project(np.array([0.04, 0.003]), np.array(0))
    assert (arc, distance) == pytest.approx((0.04, 0.003))
    segment, progress, off = path.advance(np.array([0.097, 0.02]), np.array(0), np.array(0.09))
    assert (int(segment), float(progress), bool(off)) == (1, pytest.approx(0.12), False)


def test_jump_to_a_far_waypoint_pays_nothing_for_the_skipped_path(hard):
    """A marble that appears at a much later waypoint is off the path: no progress at all."""
    tracker = PathProgress(hard)
    tracker.reset(hard.start, segment=0)
    for j in (10, 30, len(hard.waypoints) - 1):
        step = tracker.update(hard.waypoints[j])
        assert step.off_path and step.delta == 0.0 and step.progress == 0.0 and step.segment == 0
        assert not step.goal


def test_one_update_pays_at_most_up_to_the_end_of_the_next_segment(hard):
    """From every segment k, a marble put at any later waypoint j (even within the tolerance of
    segment k+1) gets at most the arc length up to the end of segment k+1."""
    path = hard.path
    n = path.n_segments
    ks, js = np.meshgrid(np.arange(n), np.arange(len(hard.waypoints)), indexing="ij")
    later = js > ks + 2
    ks, js = ks[later], js[later]
    xy = np.asarray(hard.waypoints)[js]
    start = path.cumulative[ks]
    segment, progress, off = path.advance(xy, ks, start)
    assert np.all(progress <= path.cumulative[np.minimum(ks + 2, n)] + 1e-12)
    assert np.all(segment <= ks + 1)
    assert np.all(progress[off] == start[off])
    assert off.mean() > 0.9  # far jumps are almost always off the path


def test_rolling_back_lowers_progress(hard):
    tracker = PathProgress(hard)
    tracker.reset(hard.start, segment=0)
    a, b = np.array(hard.waypoints[0]), np.array(hard.waypoints[1])
    forward = tracker.update(a + 0.5 * (b - a))
    back = tracker.update(a + 0.25 * (b - a))
    assert forward.delta > 0 and back.delta == pytest.approx(-0.25 * np.linalg.norm(b - a))


def test_reset_locates_the_nearest_segment_and_checks_the_index(hard):
    tracker = PathProgress(hard)
    step = tracker.reset(hard.waypoints[20])
    assert step.segment in (19, 20) and step.progress == pytest.approx(hard.path.cumulative[20])
    with pytest.raises(ValueError, match="segment"):
        tracker.reset(hard.start, segment=hard.path.n_segments)


def test_a_wall_between_marble_and_path_puts_it_off_the_path():
    """Within the tolerance by distance but behind a wall: off the path; in front of it: on it."""
    wall = (0.02, 0.005, 0.08, 0.010)
    path = WaypointPath([(0.0, 0.0), (0.1, 0.0), (0.1, 0.05)], tolerance=0.025, walls=[wall])
    xy = np.array([[0.05, 0.015], [0.05, 0.004], [0.01, 0.015], [0.05, 0.0075]])
    segment, progress, off = path.advance(xy, np.zeros(4, dtype=int), np.zeros(4))
    assert segment.tolist() == [0, 0, 0, 0]
    assert off.tolist() == [True, False, False, True]  # behind, in front, beside the wall's end, inside it
    assert progress.tolist() == pytest.approx([0.0, 0.05, 0.01, 0.0])


def test_line_of_sight_slab_test():
    path = WaypointPath([(0.0, 0.0), (1.0, 0.0)], tolerance=1.0, walls=[(0.4, -0.1, 0.6, 0.1)])
    p = np.array([[0.0, 0.0], [0.0, 0.2], [0.0, -0.3], [0.5, 0.05], [0.7, 0.0], [0.6, 0.1]])
    q = np.array([[1.0, 0.0], [1.0, 0.2], [1.0, 0.3], [0.5, 0.5], [0.9, 0.0], [0.9, 0.1]])
    # through it; above it (parallel); diagonally through it; leaving it; beyond it; along its face
    assert path.blocked(p, q).tolist() == [True, False, True, True, False, False]


def test_layout_walls_hide_the_path_behind_them(hard):
    """Hard layout: a point just above the wall along y = 204.5 mm (x 94.5..159.5) is 9 mm from the
    start segment (y = 218 mm) — in sight — and one just below it is 19.5 mm away but hidden."""
    tracker = PathProgress(hard)
    tracker.reset(hard.start, segment=0)
    x = 0.120 - 0.138
    assert not tracker.update((x, 0.209 - 0.1155)).off_path
    assert tracker.update((x, 0.1985 - 0.1155)).off_path


def test_point_at_inverts_project_along_the_path(hard):
    path = hard.path
    arcs = np.linspace(0.0, path.length, 57)
    points, segments = path.point_at(arcs)
    back, distance = path.project(points, segments)
    np.testing.assert_allclose(back, arcs, atol=1e-12)
    np.testing.assert_allclose(distance, 0.0, atol=1e-12)
    np.testing.assert_allclose(points[0], path.points[0])
    np.testing.assert_allclose(points[-1], path.points[-1])
    assert segments[0] == 0 and segments[-1] == path.n_segments - 1


def test_point_at_a_waypoint_starts_its_segment_and_clips_outside_the_path():
    path = WaypointPath([(0.0, 0.0), (1.0, 0.0), (1.0, 2.0)], tolerance=0.1)
    points, segments = path.point_at([1.0, 2.0, -5.0, 9.0])
    np.testing.assert_allclose(points, [(1.0, 0.0), (1.0, 1.0), (0.0, 0.0), (1.0, 2.0)])
    assert segments.tolist() == [1, 1, 0, 1]
