"""CyberRunner's own off-path test, as a map of the board: where a marble still has its path in sight.

CyberRunner (Bi & D'Andrea 2023; its repository's ``path.py``, facts read from it, no code copied)
ends an episode as off the path when no point of its path lies in the marble's *free box*: the
axis-aligned rectangle around the marble bounded, in each of ±x and ±y, by the nearest wall whose
extent (widened by the marble's radius) covers the marble's other coordinate, and by the nearest hole
treated as a square of ± the hole radius. Its path is sampled every 0.2 mm and the test precomputed
on a 0.2 mm grid of the board, looked up at the nearest cell.

The env's default rule (:class:`~bimgame.sim.labyrinth.PathProgress`: a candidate segment within
``path_tolerance`` of the marble, no wall between) is stricter on open floor, where the free box
reaches path 30–60 mm away; ``LabyrinthEnv(off_path_rule="cyberrunner")`` ends episodes by this map
instead (progress is still attributed by the tolerance rule, and frozen while outside it).

Why a map of our own: the test is the same few comparisons for every marble position of a board, so
it is computed once per board (:func:`path_box_sight`, cached) on a :data:`SIGHT_CELL` grid — coarser
than CyberRunner's 0.2 mm, which would take 25 times the cells for a marble of 12 mm — and each step
reads one cell per marble, batched.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np

from bimgame.sim.labyrinth import LabyrinthSpec

__all__ = ["SIGHT_CELL", "PathBoxSight", "path_box_sight"]

#: Grid spacing of the map and of the path's sample points (m).
SIGHT_CELL = 0.001
#: Cells computed at once (bounds the (cells × walls) and (cells × path points) arrays).
_CHUNK = 2048


class PathBoxSight:
    """Whether each board position has a path point in its free box (see the module notes), read from a
    grid precomputed for ``spec``."""

    def __init__(self, spec: LabyrinthSpec, cell: float = SIGHT_CELL):
        self.cell = float(cell)
        self.half = np.asarray(spec.board_size, dtype=np.float64) / 2
        xs = np.arange(-self.half[0], self.half[0] + self.cell / 2, self.cell)
        ys = np.arange(-self.half[1], self.half[1] + self.cell / 2, self.cell)
        grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
        points = _path_points(np.asarray(spec.waypoints, dtype=np.float64), self.cell)
        walls = np.asarray(spec.walls, dtype=np.float64).reshape(-1, 4)
        holes = np.asarray(spec.holes, dtype=np.float64).reshape(-1, 2)
        sees = np.zeros(len(grid), dtype=bool)
        for start in range(0, len(grid), _CHUNK):
            cells = grid[start : start + _CHUNK]
            low, high = _free_box(cells, walls, holes, spec.marble_radius, spec.hole_radius)
            inside = np.all((points[None] >= low[:, None]) & (points[None] <= high[:, None]), axis=-1)
            sees[start : start + _CHUNK] = inside.any(axis=1)
        #: (rows y, columns x): whether the cell's centre sees its path.
        self.grid = sees.reshape(len(ys), len(xs))

    def on_path(self, xy: np.ndarray | Sequence[float]) -> np.ndarray:
        """Whether each marble position (..., 2) (m, board frame) is on the path by CyberRunner's test
        (its nearest cell's); positions off the board are off the path."""
        p = np.asarray(xy, dtype=np.float64)
        column = np.rint((p[..., 0] + self.half[0]) / self.cell).astype(np.intp)
        row = np.rint((p[..., 1] + self.half[1]) / self.cell).astype(np.intp)
        rows, columns = self.grid.shape
        inside = (row >= 0) & (row < rows) & (column >= 0) & (column < columns)
        return np.where(inside, self.grid[np.clip(row, 0, rows - 1), np.clip(column, 0, columns - 1)], False)


def _path_points(waypoints: np.ndarray, spacing: float) -> np.ndarray:
    """(N, 2) points along the polyline through ``waypoints``, at most ``spacing`` apart, both ends in."""
    pieces = []
    for a, b in zip(waypoints[:-1], waypoints[1:], strict=True):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / spacing)))
        pieces.append(a + np.linspace(0.0, 1.0, n, endpoint=False)[:, None] * (b - a))
    return np.concatenate([*pieces, waypoints[-1:]])


def _free_box(
    cells: np.ndarray, walls: np.ndarray, holes: np.ndarray, marble_radius: float, hole_radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """Each cell's free box, (low (C, 2), high (C, 2)): in each axis the nearest bound on either side
    from the walls that cover the cell's other coordinate (widened by ``marble_radius``) and the holes
    as squares of ± ``hole_radius`` (a hole's bound never passes the cell)."""
    low = np.full(cells.shape, -np.inf)
    high = np.full(cells.shape, np.inf)
    for axis in range(2):
        other = 1 - axis
        here, across = cells[:, axis, None], cells[:, other, None]
        if len(walls):
            near, far = walls[:, axis], walls[:, axis + 2]
            covers = (across >= walls[:, other] - marble_radius) & (across <= walls[:, other + 2] + marble_radius)
            high[:, axis] = np.min(np.where(covers & (near >= here), near, np.inf), axis=1)
            low[:, axis] = np.max(np.where(covers & (far <= here), far, -np.inf), axis=1)
        if len(holes):
            centre = holes[:, axis]
            covers = np.abs(across - holes[:, other]) <= hole_radius
            ahead = np.maximum(here, centre - hole_radius)
            behind = np.minimum(here, centre + hole_radius)
            high[:, axis] = np.minimum(high[:, axis], np.min(np.where(covers & (centre >= here), ahead, np.inf), 1))
            low[:, axis] = np.maximum(low[:, axis], np.max(np.where(covers & (centre < here), behind, -np.inf), 1))
    return low, high


@functools.lru_cache(maxsize=8)
def path_box_sight(spec: LabyrinthSpec) -> PathBoxSight:
    """The map of ``spec`` (computed once per board in a process: 5–7 s on a 2-core machine)."""
    return PathBoxSight(spec)
