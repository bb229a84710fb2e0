"""Gate bearings: where each wall's nearest gate lies as seen from the marble, an optional part of
the state observation on many mazes (``gate_bearings=True``).

The maze encoding (:func:`~bimgame.envs.mazes.maze_encoding`) shows each wall's gates in 11.25° bins
of the board's frame. To drop through a gate, a policy must relate its own angle to a gate's to well
within a gate's width (10–11° on the outer wall), across mazes it has not seen: a product of two
inputs that an MLP has to learn. Policies trained on many mazes fail mostly there (held-out failures
come within ≈ 2 cm of the goal and roll past the gate: ``benchmarks/bench_maze_difficulty.py``).
The bearings give that relation directly, per wall: the sine and cosine of the angle from the marble
to the centre of the wall's nearest gate (nearest by angle about the board's centre), and the gate's
half-width in units of an encoding bin. It is what a robot that knows the maze it holds could compute
from the marble's position, and the circular maze's counterpart of CyberRunner's "next path points
relative to the marble" (:mod:`bimgame.learn.cyberrunner`).

Measured (STG1 from state, unlimited mazes, 3 seeds, 100 held-out mazes; docs/guide/mazes.md): PPO
solves 91% of held-out mazes after 2M steps with the bearings, 63% without; π^s + PPO 100% after 300k
steps, 67% without.

One table per env row (padded to the set's most gates per wall), so a vector env of different mazes
computes every row's bearings in one numpy pass.
"""

from __future__ import annotations

import math

import numpy as np

from bimgame.envs.mazes import MAZE_ENCODING_ANGLES
from bimgame.sim.maze import MazeSpec

__all__ = ["BEARING_VALUES", "GateBearings", "check_gate_bearings", "gate_bearings_size"]

#: Values per wall: sin and cos of the angle to the nearest gate's centre, its half-width in bins.
BEARING_VALUES = 3
#: The unit of the half-width value: one bin of the maze encoding (11.25°), so that it is of order 1.
_WIDTH_UNIT = 2 * math.pi / MAZE_ENCODING_ANGLES


def check_gate_bearings(gate_bearings: object, num_mazes: int | None, obs_mode: str) -> None:
    """Refuse an env's ``gate_bearings`` argument unless it is a bool, and True only with ``num_mazes``
    and state observations (``ValueError`` naming what is allowed)."""
    if not isinstance(gate_bearings, bool):
        raise ValueError(f"gate_bearings must be True or False, got {gate_bearings!r}")
    if gate_bearings and (num_mazes is None or obs_mode != "state"):
        raise ValueError(
            "gate_bearings needs num_mazes and obs_mode='state' (they are part of the state observation "
            f"on many mazes), got num_mazes={num_mazes!r}, obs_mode={obs_mode!r}"
        )


def gate_bearings_size(spec: MazeSpec) -> int:
    """Length of the bearings for ``spec``'s number of walls."""
    return BEARING_VALUES * len(spec.walls)


class GateBearings:
    """The gate tables of ``rows`` mazes on ``base``'s board (each with at most ``max_gates`` gates per
    wall), and each row's bearings for a marble position (:meth:`__call__`)."""

    def __init__(self, base: MazeSpec, rows: int, max_gates: int):
        if not base.walls:
            raise ValueError("gate bearings need a board with walls")
        if max_gates < 1:
            raise ValueError(f"max_gates must be at least 1, got {max_gates!r}")
        walls = len(base.walls)
        self.walls = walls
        self._centre = np.zeros((rows, walls, max_gates))
        self._half_width = np.zeros((rows, walls, max_gates))
        self._present = np.zeros((rows, walls, max_gates), dtype=bool)
        #: Row 0's gates per wall as (centre, half-width) floats, for :meth:`one` (set by :meth:`set_row`).
        self._first_row: list[list[tuple[float, float]]] = [[] for _ in range(walls)]

    @classmethod
    def of(cls, spec: MazeSpec) -> GateBearings:
        """One row showing ``spec`` (a single env's)."""
        bearings = cls(spec, 1, max((len(wall.gates) for wall in spec.walls), default=1))
        bearings.set_row(0, spec)
        return bearings

    def set_row(self, row: int, spec: MazeSpec) -> None:
        """Row ``row`` shows ``spec`` (a maze on the same board; at most ``max_gates`` gates per wall)."""
        if len(spec.walls) != self.walls:
            raise ValueError(f"maze has {len(spec.walls)} walls, the board {self.walls}")
        self._present[row] = False
        self._half_width[row] = 0.0
        for w, wall in enumerate(spec.walls):
            if len(wall.gates) > self._centre.shape[2]:
                raise ValueError(f"wall {w} has {len(wall.gates)} gates, more than the table's {self._centre.shape[2]}")
            for g, gate in enumerate(wall.gates):
                self._centre[row, w, g] = gate.angle
                self._half_width[row, w, g] = gate.width / 2
                self._present[row, w, g] = True
        if row == 0:
            self._first_row = [[(gate.angle, gate.width / 2) for gate in wall.gates] for wall in spec.walls]

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Each row's bearings (rows, walls · 3) for a marble at board-frame ``x``, ``y`` (rows,): per
        wall, sin and cos of (gate centre − marble angle) for the wall's nearest gate, and its
        half-width in encoding bins; a wall without gates gives (0, −1, 0), a gate straight behind."""
        theta = np.arctan2(y, x)
        offset = (self._centre - theta[:, None, None] + math.pi) % (2 * math.pi) - math.pi  # in [-π, π)
        distance = np.where(self._present, np.abs(offset), np.inf)
        nearest = np.argmin(distance, axis=2)[..., None]
        chosen = np.take_along_axis(offset, nearest, axis=2)[..., 0]
        found = np.take_along_axis(self._present, nearest, axis=2)[..., 0]
        width = np.take_along_axis(self._half_width, nearest, axis=2)[..., 0]
        out = np.empty((len(theta), self.walls, BEARING_VALUES), dtype=np.float32)
        out[..., 0] = np.where(found, np.sin(chosen), 0.0)
        out[..., 1] = np.where(found, np.cos(chosen), -1.0)
        out[..., 2] = width / _WIDTH_UNIT  # 0 where a wall has no gate
        return out.reshape(len(theta), -1)

    def one(self, x: float, y: float) -> list[float]:
        """Row 0's bearings for one marble position, as :meth:`__call__` computes them (a single env's
        per-step path: plain floats, ≈ 10× faster than the arrays for one row)."""
        theta = math.atan2(y, x)
        values: list[float] = []
        for gates in self._first_row:
            best, best_width = math.inf, 0.0
            for centre, width in gates:
                offset = (centre - theta + math.pi) % (2 * math.pi) - math.pi
                if abs(offset) < abs(best):
                    best, best_width = offset, width
            if best == math.inf:
                values += [0.0, -1.0, 0.0]
            else:
                values += [math.sin(best), math.cos(best), best_width / _WIDTH_UNIT]
        return values
