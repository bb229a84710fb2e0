"""Geometry and rules of a rectangular labyrinth (the BRIO board CyberRunner learned): walls, holes,
the waypoint path and the marble's progress along it.

A :class:`LabyrinthSpec` is a validated, hashable description in SI units of one board; the MuJoCo
model (:mod:`bimgame.sim.labyrinth_physics`) and the rules below are derived from it.
:meth:`LabyrinthSpec.layout` gives CyberRunner's three boards (:mod:`bimgame.sim.labyrinth_layouts`).

Facts and choices. Cited (``thomasbi1/cyberrunner``, commit ``f148e4e744f2f822b621d084f3cc93627f9c7002``
for the ``cyberrunner_dreamer`` files, ``7b63cbe3d4bc1371dc94942ce4b7e5b573928383`` for the others):

- board 0.276 m × 0.231 m inside the rim, walls, holes, waypoints (``cyberrunner_layout.py``);
- wall thickness 5 mm (``path.py``: ``wall_r = 0.0025``);
- marble radius 6 mm (``cyberrunner_state_estimation/core/plate_pose.py``: ``R_BALL = 0.012 / 2``);
- rim height 22 mm (``plate_pose.py``: ``H_BORDERS``, the height of the markers on the borders) and
  rim width 7.5 mm (``plate_pose.py``: ``edge_width``, marked "to check" there);
- hole radius 7.5 mm (``path.py``: ``hole_r = 0.0075``, the extent around a hole centre its path map
  treats as blocked);
- 55 Hz camera and control (``cyberrunner_state_estimation_subimg.py``: ``fps=55.0``).

Chosen (not in the paper or repository; each is a field):

- marble mass 7.1 g: a 12 mm steel ball (7850 kg/m³);
- inner wall height 15 mm: at least the marble's diameter, so the marble cannot hop over
  (MazeSpec's rule);
- max tilt 10°: the scale CyberRunner's env normalises the measured tilt by (``env.py``:
  ``norm_max``); the board's real range is not published;
- friction: MERL's maze's defaults (:class:`~bimgame.sim.maze.Friction`);
- goal radius 10 mm and path tolerance 25 mm (see below).

Path progress. The path is the polyline through the waypoints; a marble's progress is the arc
length, from the start, of its projection onto the segment it is attributed to. The rule that keeps
shortcuts unpaid (the record rules forbid them; CyberRunner ends an episode whose progress jumps by
more than 300 path points, 60 mm, in one step, ``env.py``): the attributed segment changes by **at
most one per update** — from segment ``k`` the marble is attributed to the nearest of ``k-1, k, k+1``
(ties to the lower index) that it *sees*: within ``path_tolerance`` of its projection onto that
segment, with no wall crossing the straight line between the two. With none, it is **off the path**:
segment and progress stay as they were (CyberRunner ends such an episode as a failure; its own test
is similar: a position is off the path when walls or holes hide every path point from it,
``path.py``). One update can therefore pay at most the rest of segment ``k`` and segment ``k+1``; a
marble that appears beside a far-later part of the path gains nothing for the part between, and the
line-of-sight test keeps a marble behind a wall from being attributed to the path on its other side.
Progress can decrease (the marble rolls back), as CyberRunner's can. The tolerance is a choice: on
the open parts of the easy and medium boards a marble can be 30–60 mm from the path (10% of their
free floor lies more than 28–39 mm from it, 1% more than 41–58 mm), on the hard board's corridors
rarely more than 14 mm (90%); 25 mm counts the corridors and their corners as on the path and
dead-end pockets as off it.

Holes are a rule, not geometry: a marble is over a hole when its centre lies within ``hole_radius``
of a hole centre (its support point is then on the hole's edge and it drops in); the physics model
has a solid floor (:mod:`bimgame.sim.labyrinth_physics` says why). The goal is reached when the
marble's centre is within ``goal_radius`` of the last waypoint.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from bimgame.sim.labyrinth_layouts import BOARD_SIZE, LAYOUT_NAMES, WALL_THICKNESS, get_layout
from bimgame.sim.maze import Friction

__all__ = ["LabyrinthSpec", "LabyrinthSpecError", "WaypointPath", "PathStep", "PathProgress", "STEEL_DENSITY"]

#: Density of steel (kg/m³), for the chosen marble mass.
STEEL_DENSITY = 7850.0
_MARBLE_RADIUS = 0.006
_MAX_TILT_LIMIT = math.radians(30.0)


class LabyrinthSpecError(ValueError):
    """A :class:`LabyrinthSpec` describes a board that cannot be built; the message names the field."""


def _positive(name: str, value: Any) -> float:
    if isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise LabyrinthSpecError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


def _points(name: str, value: Any, width: int) -> tuple[tuple[float, ...], ...]:
    """``value`` as a tuple of ``width``-tuples of finite floats, or an error naming ``name``."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise LabyrinthSpecError(f"{name} must be a sequence of {width} numbers per row, got {value!r}") from error
    if array.size == 0:
        array = array.reshape(0, width)
    if array.ndim != 2 or array.shape[1] != width:
        raise LabyrinthSpecError(f"{name} must have {width} numbers per row, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise LabyrinthSpecError(f"{name} must be finite numbers (m)")
    return tuple(tuple(float(v) for v in row) for row in array)


@dataclasses.dataclass(frozen=True)
class LabyrinthSpec:
    """A rectangular labyrinth in the board frame (m; origin at the board's centre, x right, y up).

    Attributes:
        walls: inner walls, rectangles ``(x_min, y_min, x_max, y_max)`` (m).
        holes: hole centres ``(x, y)`` (m).
        waypoints: the path from the start (first) to the goal (last), at least two points (m).
        name: a label (the layout's name, or ``"custom"``).
        board_size: playable width (x) and height (y) inside the rim (m).
        hole_radius: a marble whose centre comes this close to a hole centre falls in (m).
        goal_radius: the goal is reached within this distance of the last waypoint (m).
        path_tolerance: farthest a marble may be from its path segment and still be on the path (m),
            if no wall hides the segment from it.
        wall_height: height of the inner walls (m).
        rim_thickness: width of the rim around the board (m).
        rim_height: height of the rim (m).
        marble_radius: marble radius (m).
        marble_mass: marble mass (kg).
        max_tilt: largest board tilt about either axis (rad).
        friction: contact and static friction of the marble.
    """

    walls: tuple[tuple[float, float, float, float], ...]
    holes: tuple[tuple[float, float], ...]
    waypoints: tuple[tuple[float, float], ...]
    name: str = "custom"
    board_size: tuple[float, float] = BOARD_SIZE
    hole_radius: float = 0.0075
    goal_radius: float = 0.010
    path_tolerance: float = 0.025
    wall_height: float = 0.015
    rim_thickness: float = 0.0075
    rim_height: float = 0.022
    marble_radius: float = _MARBLE_RADIUS
    marble_mass: float = STEEL_DENSITY * 4.0 / 3.0 * math.pi * _MARBLE_RADIUS**3
    max_tilt: float = math.radians(10.0)
    friction: Friction = dataclasses.field(default_factory=Friction)

    def __post_init__(self) -> None:
        object.__setattr__(self, "walls", _points("walls", self.walls, 4))
        object.__setattr__(self, "holes", _points("holes", self.holes, 2))
        object.__setattr__(self, "waypoints", _points("waypoints", self.waypoints, 2))
        size = _points("board_size", [self.board_size], 2)[0]
        object.__setattr__(
            self, "board_size", (_positive("board_size[0]", size[0]), _positive("board_size[1]", size[1]))
        )
        for name in (
            "hole_radius",
            "goal_radius",
            "path_tolerance",
            "wall_height",
            "rim_thickness",
            "rim_height",
            "marble_radius",
            "marble_mass",
            "max_tilt",
        ):
            object.__setattr__(self, name, _positive(name, getattr(self, name)))
        self._validate()

    # ------------------------------------------------------------------ construction
    @classmethod
    def layout(cls, name: str, *, wall_thickness: float = WALL_THICKNESS, **overrides: Any) -> LabyrinthSpec:
        """CyberRunner's board ``name`` (``"easy"``, ``"medium"`` or ``"hard"``), with any field
        overridden; ``wall_thickness`` (m) rebuilds the walls from the layout's segments."""
        if name not in LAYOUT_NAMES:
            raise LabyrinthSpecError(f"layout must be one of {', '.join(map(repr, LAYOUT_NAMES))}, got {name!r}")
        board = get_layout(name, wall_thickness)
        fields = {"walls": board.walls, "holes": board.holes, "waypoints": board.waypoints, "name": name}
        return cls(**{**fields, **overrides})

    def replace(self, **changes: Any) -> LabyrinthSpec:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------------ validation
    def _validate(self) -> None:
        if not isinstance(self.name, str):
            raise LabyrinthSpecError(f"name must be a str, got {type(self.name).__name__}")
        if not isinstance(self.friction, Friction):
            raise LabyrinthSpecError(f"friction must be a Friction, got {type(self.friction).__name__}")
        try:
            self.friction.validate()
        except ValueError as error:
            raise LabyrinthSpecError(str(error)) from error
        if self.max_tilt > _MAX_TILT_LIMIT:
            raise LabyrinthSpecError(f"max_tilt must be at most 30° ({_MAX_TILT_LIMIT:.4f} rad), got {self.max_tilt!r}")
        if self.wall_height < 2 * self.marble_radius or self.rim_height < 2 * self.marble_radius:
            raise LabyrinthSpecError(
                f"wall_height ({self.wall_height!r} m) and rim_height ({self.rim_height!r} m) must be at least the "
                f"marble's diameter ({2 * self.marble_radius!r} m), or the marble could hop over them"
            )
        if min(self.board_size) <= 2 * self.marble_radius:
            raise LabyrinthSpecError(f"board_size {self.board_size} must exceed the marble's diameter in both axes")
        for k, (x0, y0, x1, y1) in enumerate(self.walls):
            if not (x0 < x1 and y0 < y1):
                raise LabyrinthSpecError(
                    f"walls[{k}] = {(x0, y0, x1, y1)} must be (x_min, y_min, x_max, y_max) with x_min < x_max "
                    "and y_min < y_max"
                )
        self._validate_points("holes", self.holes, 0.0)
        if len(self.waypoints) < 2:
            raise LabyrinthSpecError(
                f"waypoints must hold at least 2 points (start and goal), got {len(self.waypoints)}"
            )
        self._validate_points("waypoints", self.waypoints, self.marble_radius)
        for k, (a, b) in enumerate(zip(self.waypoints, self.waypoints[1:], strict=False)):
            if a == b:
                raise LabyrinthSpecError(f"waypoints[{k}] and waypoints[{k + 1}] are the same point {a}: remove one")

    def _validate_points(self, name: str, points: tuple[tuple[float, ...], ...], margin: float) -> None:
        """Every point of ``points`` at least ``margin`` inside the board's edges."""
        hx, hy = self.board_size[0] / 2 - margin, self.board_size[1] / 2 - margin
        for k, (x, y) in enumerate(points):
            if abs(x) > hx or abs(y) > hy:
                raise LabyrinthSpecError(
                    f"{name}[{k}] = {(x, y)} lies outside the board: |x| must be at most {hx!r} m and |y| at most "
                    f"{hy!r} m (board_size {self.board_size}{' less the marble radius' if margin else ''})"
                )

    # ------------------------------------------------------------------ geometry
    @functools.cached_property
    def _wall_array(self) -> np.ndarray:
        return np.array(self.walls, dtype=np.float64).reshape(-1, 4)

    @functools.cached_property
    def _hole_array(self) -> np.ndarray:
        return np.array(self.holes, dtype=np.float64).reshape(-1, 2)

    @functools.cached_property
    def path(self) -> WaypointPath:
        """The waypoint polyline with this board's ``path_tolerance`` and walls."""
        return WaypointPath(self.waypoints, self.path_tolerance, self.walls)

    @property
    def start(self) -> tuple[float, float]:
        """The marble's start: the first waypoint."""
        return (self.waypoints[0][0], self.waypoints[0][1])

    def clearance(self, xy: np.ndarray | Sequence[float]) -> np.ndarray:
        """Distance (m) from each point (..., 2) to the nearest inner wall or the rim's inner face;
        negative inside a wall or outside the board (by how far, for the rim; walls give −0 inside).
        A marble centred at ``xy`` touches nothing when this exceeds ``marble_radius``."""
        p = np.asarray(xy, dtype=np.float64)
        hx, hy = self.board_size[0] / 2, self.board_size[1] / 2
        rim = np.minimum(hx - np.abs(p[..., 0]), hy - np.abs(p[..., 1]))
        walls = self._wall_array
        if len(walls) == 0:
            return rim
        dx = np.maximum(np.maximum(walls[:, 0] - p[..., 0, None], p[..., 0, None] - walls[:, 2]), 0.0)
        dy = np.maximum(np.maximum(walls[:, 1] - p[..., 1, None], p[..., 1, None] - walls[:, 3]), 0.0)
        inside = (dx == 0) & (dy == 0)
        wall = np.where(inside, -0.0, np.hypot(dx, dy)).min(axis=-1)
        return np.minimum(rim, wall)

    def over_hole(self, xy: np.ndarray | Sequence[float]) -> np.ndarray:
        """Whether each marble centre (..., 2) lies within ``hole_radius`` of a hole centre."""
        p = np.asarray(xy, dtype=np.float64)
        holes = self._hole_array
        if len(holes) == 0:
            return np.zeros(p.shape[:-1], dtype=bool)
        d2 = ((p[..., None, :] - holes) ** 2).sum(axis=-1)
        return np.any(d2 <= self.hole_radius**2, axis=-1)

    def reached_goal(self, xy: np.ndarray | Sequence[float]) -> np.ndarray:
        """Whether each marble centre (..., 2) lies within ``goal_radius`` of the last waypoint."""
        p = np.asarray(xy, dtype=np.float64)
        goal = np.asarray(self.waypoints[-1])
        return ((p - goal) ** 2).sum(axis=-1) <= self.goal_radius**2


class WaypointPath:
    """The polyline through ``waypoints`` and the progress rule of the module docstring, vectorised
    over any leading shape of positions (B, ..., 2) and segment indices (B, ...); ``walls``
    (rectangles ``(x_min, y_min, x_max, y_max)``) block the line of sight to the path.

    Segment ``k`` runs from ``waypoints[k]`` to ``waypoints[k+1]``; ``cumulative[k]`` is the arc
    length (m) from the start to ``waypoints[k]``; ``length`` the whole path's."""

    def __init__(
        self,
        waypoints: Sequence[Sequence[float]],
        tolerance: float,
        walls: Sequence[Sequence[float]] = (),
    ):
        points = np.asarray(waypoints, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 2 or len(points) < 2:
            raise ValueError(f"waypoints must be at least 2 points (x, y), got shape {points.shape}")
        self.tolerance = _positive("path_tolerance", tolerance)
        self.walls = np.asarray(walls, dtype=np.float64).reshape(-1, 4)
        self.points = points
        self.starts = points[:-1]
        self.vectors = np.diff(points, axis=0)
        self.lengths = np.linalg.norm(self.vectors, axis=1)
        if np.any(self.lengths == 0):
            raise ValueError("waypoints must not repeat a point twice in a row (a segment of zero length)")
        self.cumulative = np.concatenate([[0.0], np.cumsum(self.lengths)])
        self.length = float(self.cumulative[-1])
        self.n_segments = len(self.lengths)

    def _foot(self, p: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Arc length, distance and the foot point of each point's projection onto segment ``k``."""
        start, vector, length = self.starts[k], self.vectors[k], self.lengths[k]
        t = np.clip(((p - start) * vector).sum(axis=-1) / length**2, 0.0, 1.0)
        foot = start + t[..., None] * vector
        return self.cumulative[k] + t * length, np.linalg.norm(p - foot, axis=-1), foot

    def project(self, xy: np.ndarray, segment: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arc length (m, from the path's start) of each point's projection onto its ``segment``
        (clamped to the segment's ends) and the point's distance (m) from that segment."""
        arc, distance, _ = self._foot(np.asarray(xy, dtype=np.float64), np.asarray(segment, dtype=np.intp))
        return arc, distance

    def point_at(self, arc: np.ndarray | Sequence[float] | float) -> tuple[np.ndarray, np.ndarray]:
        """The path's points (..., 2) at arc lengths ``arc`` (m from the start, clipped to the path)
        and the segment each lies on (a waypoint starts its segment; the goal ends the last one):
        where a marble's progress puts it on the path."""
        s = np.clip(np.asarray(arc, dtype=np.float64), 0.0, self.length)
        k = np.clip(np.searchsorted(self.cumulative, s, side="right") - 1, 0, self.n_segments - 1)
        t = (s - self.cumulative[k]) / self.lengths[k]
        return self.starts[k] + t[..., None] * self.vectors[k], k

    def blocked(self, p: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Whether a wall's interior crosses each straight line from ``p`` to ``q`` (..., 2) (the
        slab test: the line's parameter intervals inside each wall's x and y extents overlap)."""
        if len(self.walls) == 0:
            return np.zeros(np.broadcast_shapes(p.shape, q.shape)[:-1], dtype=bool)
        d = q - p
        lo, hi = self.walls[:, :2], self.walls[:, 2:]
        enter = np.zeros(np.broadcast_shapes(p.shape, q.shape)[:-1] + (len(self.walls),))
        leave = np.ones_like(enter)
        for axis in range(2):
            pa, da = p[..., axis, None], d[..., axis, None]
            with np.errstate(divide="ignore", invalid="ignore"):
                ta, tb = (lo[:, axis] - pa) / da, (hi[:, axis] - pa) / da
            parallel = da == 0
            inside = (pa > lo[:, axis]) & (pa < hi[:, axis])
            enter = np.maximum(enter, np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb)))
            leave = np.minimum(leave, np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb)))
        return np.any(enter < leave, axis=-1)

    def in_sight(self, p: np.ndarray, candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For each point (..., 2) and its candidate segments (..., C): arc lengths, distances and
        whether the segment is in sight (no wall between point and foot; within the tolerance)."""
        arc, distance, foot = self._foot(p[..., None, :], candidates)
        seen = (distance <= self.tolerance) & ~self.blocked(np.broadcast_to(p[..., None, :], foot.shape), foot)
        return arc, distance, seen

    def locate(self, xy: np.ndarray) -> np.ndarray:
        """The nearest segment in sight of each point over the whole path (none in sight: the nearest
        one; ties: the earlier one): where a marble placed by hand starts. Not a progress rule: it
        ignores the path's order."""
        p = np.asarray(xy, dtype=np.float64)
        every = np.broadcast_to(np.arange(self.n_segments), p.shape[:-1] + (self.n_segments,))
        _, distance, seen = self.in_sight(p, every)
        visible = np.where(seen, distance, np.inf)
        return np.where(seen.any(axis=-1), np.argmin(visible, axis=-1), np.argmin(distance, axis=-1))

    def advance(
        self, xy: np.ndarray, segment: np.ndarray, progress: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One update of the progress rule: from ``segment``/``progress`` (the previous update's),
        the new segment, progress (m) and whether the marble is off the path (then both unchanged)."""
        p = np.asarray(xy, dtype=np.float64)
        k = np.asarray(segment, dtype=np.intp)
        old = np.asarray(progress, dtype=np.float64)
        candidates = np.clip(k[..., None] + np.array([-1, 0, 1]), 0, self.n_segments - 1)
        arc, distance, seen = self.in_sight(p, candidates)
        best = np.argmin(np.where(seen, distance, np.inf), axis=-1)[..., None]
        new_segment = np.take_along_axis(candidates, best, axis=-1)[..., 0]
        new_arc = np.take_along_axis(arc, best, axis=-1)[..., 0]
        off = np.logical_not(seen.any(axis=-1))
        return np.where(off, k, new_segment), np.where(off, old, new_arc), off


@dataclasses.dataclass(frozen=True)
class PathStep:
    """The outcome of one :meth:`PathProgress.update`.

    Attributes:
        segment: the segment the marble is attributed to.
        progress: arc length (m) along the path of its projection (unchanged when off the path).
        delta: change of ``progress`` since the last update (m): what a progress reward pays.
        off_path: none of the candidate segments is in sight (within the path tolerance, no wall
            between).
        over_hole: the marble's centre is over a hole (it falls).
        goal: on the last segment and within ``goal_radius`` of the goal.
    """

    segment: int
    progress: float
    delta: float
    off_path: bool
    over_hole: bool
    goal: bool


class PathProgress:
    """The progress of one marble along a :class:`LabyrinthSpec`'s path, update by update (the
    rule of the module docstring; :meth:`WaypointPath.advance` is its batched form)."""

    def __init__(self, spec: LabyrinthSpec):
        self.spec = spec
        self.path = spec.path
        self.segment = 0
        self.progress = 0.0

    def reset(self, xy: Sequence[float], segment: int | None = None) -> PathStep:
        """Start from marble position ``xy`` on ``segment`` (None: the nearest segment overall)."""
        p = np.asarray(xy, dtype=np.float64)
        if segment is None:
            segment = int(self.path.locate(p))
        if not (isinstance(segment, (int, np.integer)) and 0 <= segment < self.path.n_segments):
            raise ValueError(f"segment must be an integer in 0..{self.path.n_segments - 1}, got {segment!r}")
        arc, _, seen = self.path.in_sight(p, np.asarray([segment]))
        self.segment, self.progress = int(segment), float(arc[0])
        return self._step(p, 0.0, not bool(seen[0]))

    def update(self, xy: Sequence[float]) -> PathStep:
        """Advance by the marble's new position ``xy`` (m, board frame)."""
        p = np.asarray(xy, dtype=np.float64)
        segment, progress, off = self.path.advance(p, np.asarray(self.segment), np.asarray(self.progress))
        delta = float(progress) - self.progress
        self.segment, self.progress = int(segment), float(progress)
        return self._step(p, delta, bool(off))

    def _step(self, p: np.ndarray, delta: float, off: bool) -> PathStep:
        goal = self.segment == self.path.n_segments - 1 and bool(self.spec.reached_goal(p))
        return PathStep(self.segment, self.progress, delta, off, bool(self.spec.over_hole(p)), goal)
