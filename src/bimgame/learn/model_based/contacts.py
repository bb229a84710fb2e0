"""The labyrinth's walls as the marble model meets them: a predicted marble centre closer to a wall
or the rim than its radius is pushed back out, and the part of its velocity that runs into the wall
is removed (a perfectly inelastic contact; what runs along the wall stays).

Geometry, not learned (:mod:`bimgame.learn.model_based`): the walls are the layout's axis-aligned
rectangles, so the nearest point of each is a clip of the centre to it, exact and batched over the
planner's K sequences in one numpy expression.
"""

from __future__ import annotations

import numpy as np

from bimgame.sim.labyrinth import LabyrinthSpec

__all__ = ["WallContacts"]

#: Push-out passes: a centre in a corner touches two walls, and pushing it off one can press it into
#: the other; where walls meet at a wall's end (a corner point's normal is diagonal), the passes
#: converge slowly: 6 leave at most ≈ 3 µm (2 passes left 0.1 mm). A pass with nothing touching ends them.
_PASSES = 6


class WallContacts:
    """Resolve marble centres against ``board``'s inner walls and rim (:meth:`resolve`)."""

    def __init__(self, board: LabyrinthSpec):
        if not isinstance(board, LabyrinthSpec):
            raise TypeError(f"board must be a LabyrinthSpec, got {type(board).__name__}")
        self.radius = float(board.marble_radius)
        walls = np.asarray(board.walls, dtype=np.float64).reshape(-1, 4)
        self._low, self._high = walls[:, :2], walls[:, 2:]
        half = np.asarray(board.board_size, dtype=np.float64) / 2
        self._inner = half - self.radius  # the farthest a centre gets from the board's centre

    def resolve(self, xy: np.ndarray, velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centres (K, 2) m and velocities (K, 2) m/s after the contacts: centres at least the marble's
        radius from every wall and inside the rim, velocities without their component into a touched
        wall. Inputs are not modified."""
        xy, velocity = np.array(xy, dtype=np.float64), np.array(velocity, dtype=np.float64)
        if len(self._low):
            for _ in range(_PASSES):
                nearest = np.clip(xy[:, None, :], self._low, self._high)  # (K, W, 2)
                away = xy[:, None, :] - nearest
                distance = np.sqrt((away**2).sum(axis=-1))
                touching = distance < self.radius
                if not touching.any():
                    break
                # A centre exactly on a wall's face has no direction out of it: left as it is (the
                # model never puts one there from outside, the step being far shorter than the radius).
                normal = np.divide(away, distance[..., None], out=np.zeros_like(away), where=distance[..., None] > 0)
                depth = np.where(touching, self.radius - distance, 0.0)
                xy = xy + (normal * depth[..., None]).sum(axis=1)
                inward = (velocity[:, None, :] * normal).sum(axis=-1)
                velocity = velocity - (normal * np.where(touching & (inward < 0), inward, 0.0)[..., None]).sum(axis=1)
        outside = np.abs(xy) > self._inner
        velocity = np.where(outside & (np.sign(velocity) == np.sign(xy)), 0.0, velocity)
        return np.clip(xy, -self._inner, self._inner), velocity
