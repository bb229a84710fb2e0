"""The labyrinth's path-progress rule for one marble in plain Python floats: the single env's
per-step fast path.

:class:`~bimgame.sim.labyrinth.PathProgress` applies :meth:`~bimgame.sim.labyrinth.WaypointPath.advance`,
vectorised numpy written for batches; for one marble its per-call overhead on arrays of 3 × 53
elements costs ≈ 330 µs an update, three times the physics step (``benchmarks/bench_labyrinth.py``).
:class:`ScalarPathProgress` computes the same rule with scalar arithmetic in the same order
(projection, tolerance, the slab test for walls between the marble and its foot point, the
nearest candidate with ties to the earlier) and only tests walls whose box meets the box of the
line of sight; tests check it against :class:`PathProgress` point by point. The rule itself is
defined and documented in :mod:`bimgame.sim.labyrinth`, as ``env.py``'s plain-float observation is
a fast path of the batched observer.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence

from bimgame.sim.labyrinth import LabyrinthSpec, PathProgress, PathStep

__all__ = ["ScalarPathProgress"]

_INF = math.inf


class ScalarPathProgress(PathProgress):
    """:class:`~bimgame.sim.labyrinth.PathProgress` with a scalar :meth:`update` (same results) and
    :meth:`points_ahead`, the path points ahead of a progress."""

    def __init__(self, spec: LabyrinthSpec):
        super().__init__(spec)
        path = self.path
        self._starts = path.starts.tolist()
        self._vectors = path.vectors.tolist()
        self._lengths = path.lengths.tolist()
        self._squares = (path.lengths**2).tolist()
        self._cumulative = path.cumulative.tolist()
        self._walls = [(x0, y0, x1, y1) for x0, y0, x1, y1 in path.walls.tolist()]
        self._holes = [(float(x), float(y)) for x, y in spec.holes]
        self._hole_r2 = spec.hole_radius**2
        self._goal = (float(spec.waypoints[-1][0]), float(spec.waypoints[-1][1]))
        self._goal_r2 = spec.goal_radius**2
        self._tolerance = path.tolerance
        self._last = path.n_segments - 1

    # ------------------------------------------------------------------ geometry
    def _blocked(self, px: float, py: float, fx: float, fy: float) -> bool:
        """Whether a wall's interior crosses the line from ``(px, py)`` to ``(fx, fy)``
        (:meth:`~bimgame.sim.labyrinth.WaypointPath.blocked`, one line)."""
        dx, dy = fx - px, fy - py
        lox, hix = min(px, fx), max(px, fx)
        loy, hiy = min(py, fy), max(py, fy)
        for x0, y0, x1, y1 in self._walls:
            if x1 < lox or x0 > hix or y1 < loy or y0 > hiy:
                continue  # boxes apart: the slab intervals cannot overlap within [0, 1]
            enter, leave = 0.0, 1.0
            for pa, da, lo, hi in ((px, dx, x0, x1), (py, dy, y0, y1)):
                if da == 0:
                    inside = lo < pa < hi
                    enter, leave = max(enter, -_INF if inside else _INF), min(leave, _INF if inside else -_INF)
                else:
                    ta, tb = (lo - pa) / da, (hi - pa) / da
                    enter, leave = max(enter, min(ta, tb)), min(leave, max(ta, tb))
            if enter < leave:
                return True
        return False

    def _candidate(self, px: float, py: float, k: int) -> tuple[float, float, bool]:
        """Arc length, distance and whether segment ``k`` is in sight of the point."""
        (sx, sy), (vx, vy) = self._starts[k], self._vectors[k]
        t = ((px - sx) * vx + (py - sy) * vy) / self._squares[k]
        t = 0.0 if t < 0.0 else 1.0 if t > 1.0 else t
        fx, fy = sx + t * vx, sy + t * vy
        distance = math.sqrt((px - fx) ** 2 + (py - fy) ** 2)
        seen = distance <= self._tolerance and not self._blocked(px, py, fx, fy)
        return self._cumulative[k] + t * self._lengths[k], distance, seen

    # ------------------------------------------------------------------ the rule
    def update(self, xy: Sequence[float]) -> PathStep:
        """Advance by the marble's new position ``xy`` (m, board frame), as :meth:`PathProgress.update`."""
        px, py = float(xy[0]), float(xy[1])
        k = self.segment
        best, best_arc, best_distance = -1, 0.0, _INF
        for candidate in (max(k - 1, 0), k, min(k + 1, self._last)):
            arc, distance, seen = self._candidate(px, py, candidate)
            if seen and distance < best_distance:
                best, best_arc, best_distance = candidate, arc, distance
        off = best < 0
        delta = 0.0
        if not off:
            delta = best_arc - self.progress
            self.segment, self.progress = best, best_arc
        return self._scalar_step(px, py, delta, off)

    def _scalar_step(self, px: float, py: float, delta: float, off: bool) -> PathStep:
        r2 = self._hole_r2
        over = any((px - hx) ** 2 + (py - hy) ** 2 <= r2 for hx, hy in self._holes)
        gx, gy = self._goal
        goal = self.segment == self._last and (px - gx) ** 2 + (py - gy) ** 2 <= self._goal_r2
        return PathStep(self.segment, self.progress, delta, off, over, goal)

    def points_ahead(self, progress: float, n: int, spacing: float) -> list[tuple[float, float]]:
        """The ``n`` path points at arc lengths ``progress + k * spacing`` (k = 0 … n-1), clamped
        to the path's ends (m)."""
        cumulative, out = self._cumulative, []
        length = cumulative[-1]
        for i in range(n):
            s = min(max(progress + spacing * i, 0.0), length)
            k = min(max(bisect.bisect_right(cumulative, s) - 1, 0), self._last)
            t = (s - cumulative[k]) / self._lengths[k]
            (sx, sy), (vx, vy) = self._starts[k], self._vectors[k]
            out.append((sx + t * vx, sy + t * vy))
        return out
