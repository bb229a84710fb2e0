"""What lies around the labyrinth's marble: an optional part of its state observation.

The labyrinth's ``state`` observation (:class:`~bimgame.envs.labyrinth_env.LabyrinthEnv`) holds the
marble, the tilt and the path ahead, but nothing of the holes and walls the path runs between; a
learner has to learn where they are from the marble's position alone, on every layout anew.
CyberRunner's own observation shows them in a 64 × 64 crop around the marble; these values are the
same facts at a state observation's price (``surroundings=True``):

- the :data:`SURROUNDING_HOLES` nearest holes' centres relative to the marble (x, y each, m), nearest
  first (a board with fewer holes repeats a far point, :data:`NO_HOLE`, for the missing ones);
- the distance (m) from the marble's centre to the first wall or rim face along :data:`WALL_RAYS`
  directions (0°, 45°, … from the board's x axis), at most :data:`RAY_RANGE`.

Written here rather than taken from MuJoCo's ray casts (``mj_ray``): the walls are axis-aligned boxes in
the board's frame, so a slab test on the spec's rectangles is exact, batched over boards in one numpy
expression and independent of the board's tilt and of contact geometry (the marble's own sphere).
"""

from __future__ import annotations

import math

import numpy as np

from bimgame.sim.labyrinth import LabyrinthSpec

__all__ = [
    "SURROUNDING_HOLES",
    "WALL_RAYS",
    "RAY_RANGE",
    "NO_HOLE",
    "SURROUNDINGS_SIZE",
    "Surroundings",
    "surroundings_scale",
    "check_surroundings",
]

#: Holes observed: the easy layout has 8, the medium 16, the hard 40; the marble meets them one or two at
#: a time along the path.
SURROUNDING_HOLES = 4
#: Directions of the wall distances: every 45°.
WALL_RAYS = 8
#: Farthest wall distance observed (m): about eight marble radii, the length of a turn's approach.
RAY_RANGE = 0.05
#: The relative position reported for a hole the board does not have (m): farther than any board.
NO_HOLE = (1.0, 1.0)
#: Values appended to the state observation: 2 per hole, 1 per ray (16).
SURROUNDINGS_SIZE = 2 * SURROUNDING_HOLES + WALL_RAYS
#: A direction component below this is taken as this (a slab test divides by it; the sign does not
#: matter for a ray parallel to a slab).
_TINY = 1e-12


def surroundings_scale() -> np.ndarray:
    """Divisors that bring the surroundings to order 1 (a state network's ``obs_scale`` part): hole
    offsets by :data:`RAY_RANGE` (a hole within reach reads within ±1), distances by :data:`RAY_RANGE`
    (0 at a wall, 1 with nothing in reach)."""
    return np.full(SURROUNDINGS_SIZE, RAY_RANGE, dtype=np.float32)


def check_surroundings(surroundings: object, obs_mode: str) -> None:
    """Refuse a ``surroundings`` that is not True or False, or True with an ``obs_mode`` other than
    ``"state"`` (pixels and CyberRunner's crop show the holes and walls themselves)."""
    if not isinstance(surroundings, (bool, np.bool_)):
        raise ValueError(f"surroundings must be True or False, got {surroundings!r}")
    if surroundings and obs_mode != "state":
        raise ValueError(
            f"surroundings are part of obs_mode 'state', not {obs_mode!r} (pixels and CyberRunner's crop show the "
            "holes and walls themselves)"
        )


class Surroundings:
    """The surroundings of marbles on ``board``: :meth:`of` positions (…, 2) gives (…, 16) values."""

    def __init__(self, board: LabyrinthSpec):
        self.board = board
        self._holes = np.array(board.holes, dtype=np.float64).reshape(-1, 2)
        #: Holes the board lacks for a full observation, each read as NO_HOLE.
        self._missing = max(0, SURROUNDING_HOLES - len(self._holes))
        self._walls = np.array(board.walls, dtype=np.float64).reshape(-1, 4)
        angles = 2 * math.pi * np.arange(WALL_RAYS) / WALL_RAYS
        directions = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        directions[np.abs(directions) < _TINY] = _TINY
        self._inverse = 1.0 / directions  # (R, 2)
        # The rim's inner face each ray meets: +half-size where the ray points up the axis, −half-size down.
        self._rim = np.where(directions > 0, 1.0, -1.0) * np.asarray(board.board_size) / 2  # (R, 2)

    def of(self, xy: np.ndarray) -> np.ndarray:
        """The surroundings (…, :data:`SURROUNDINGS_SIZE`) float32 of marble centres ``xy`` (…, 2) m:
        the nearest holes' offsets, then the wall distances."""
        p = np.asarray(xy, dtype=np.float64)
        offsets = self._holes - p[..., None, :]  # (..., H, 2)
        nearest = np.argsort((offsets**2).sum(axis=-1), axis=-1, kind="stable")[..., :SURROUNDING_HOLES]
        holes = np.take_along_axis(offsets, nearest[..., None], axis=-2)
        if self._missing:
            absent = np.broadcast_to(NO_HOLE, (*p.shape[:-1], self._missing, 2))
            holes = np.concatenate([holes, absent], axis=-2)
        return np.concatenate([holes.reshape(*p.shape[:-1], -1), self._distances(p)], axis=-1, dtype=np.float32)

    def _distances(self, p: np.ndarray) -> np.ndarray:
        """(…, R) distances from ``p`` (…, 2) to the first wall or rim face along each ray, at most
        :data:`RAY_RANGE`; 0 for a centre inside a wall (slab test on each wall's rectangle)."""
        x, y = p[..., 0, None, None], p[..., 1, None, None]  # (..., 1, 1)
        inverse_x, inverse_y = self._inverse[:, 0, None], self._inverse[:, 1, None]  # (R, 1)
        x_low, x_high = (self._walls[:, 0] - x) * inverse_x, (self._walls[:, 2] - x) * inverse_x  # (..., R, W)
        y_low, y_high = (self._walls[:, 1] - y) * inverse_y, (self._walls[:, 3] - y) * inverse_y
        enter = np.maximum(np.minimum(x_low, x_high), np.minimum(y_low, y_high))
        leave = np.minimum(np.maximum(x_low, x_high), np.maximum(y_low, y_high))
        enter = np.maximum(enter, 0.0)
        walls = np.where(leave >= enter, enter, np.inf).min(axis=-1, initial=np.inf)
        rim = np.minimum(
            (self._rim[:, 0] - p[..., 0, None]) * self._inverse[:, 0],
            (self._rim[:, 1] - p[..., 1, None]) * self._inverse[:, 1],
        )
        return np.clip(np.minimum(walls, rim), 0.0, RAY_RANGE)
