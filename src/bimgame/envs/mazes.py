"""Many mazes in one env: what the envs need to draw a maze per episode and show it to the agent.

An env built with ``num_mazes`` (Procgen's ``num_levels``; see :mod:`bimgame.sim.maze_sets`) draws
each episode's maze from a :class:`~bimgame.sim.maze_sets.MazeSet` on its board. The physics model
is built once with a fixed number of pieces per wall and switched between mazes by
:meth:`~bimgame.sim.physics.MazeSim.set_walls`; the pixel raster's background is drawn per maze
(cached); state observations end with :func:`maze_encoding`, a fixed-size picture of the gates.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import numpy as np

from bimgame.sim.generate import GateRules
from bimgame.sim.maze import MazeSpec
from bimgame.sim.maze_sets import MAZE_SPLITS, MazeSet
from bimgame.sim.mjcf import wall_slots
from bimgame.sim.render import MazeRenderer
from bimgame.sim.render_rings import GateSamples

__all__ = ["MAZE_ENCODING_ANGLES", "EnvMazes", "maze_encoding", "maze_encoding_size", "maze_raster"]

#: Angular bins per wall of :func:`maze_encoding`: 11.25° each, about one of MERL's outer gates.
MAZE_ENCODING_ANGLES = 32
#: Points sampled per bin to measure its open fraction.
_SAMPLES_PER_BIN = 16
#: Rasters (one per maze and size) kept per process.
_RASTER_CACHE = 256


def maze_encoding_size(spec: MazeSpec) -> int:
    """Length of :func:`maze_encoding` for ``spec``'s number of walls."""
    return len(spec.walls) * MAZE_ENCODING_ANGLES


@functools.lru_cache(maxsize=4096)
def maze_encoding(spec: MazeSpec) -> np.ndarray:
    """Each wall's openness at :data:`MAZE_ENCODING_ANGLES` equal angular bins, wall 0 first and bin
    ``j`` covering board angles ``[-π + jΔ, -π + (j + 1)Δ)``: the fraction of the bin that is gate
    (0 solid … 1 open), float32, read-only. In the board frame, like the marble's position, so a
    policy can relate the two."""
    # Every gate of every wall in one pass, each sample compared as Wall.in_gate compares it but only
    # near a gate (a test compares the two).
    walls = len(spec.walls)
    opened = _encoding_samples(walls).open_mask(spec.walls).reshape(walls, MAZE_ENCODING_ANGLES, _SAMPLES_PER_BIN)
    encoding = opened.mean(axis=2).reshape(-1).astype(np.float32)
    encoding.flags.writeable = False
    return encoding


@functools.lru_cache(maxsize=16)
def _encoding_samples(walls: int) -> GateSamples:
    """The angles :func:`maze_encoding` samples on each of ``walls`` walls (bin after bin,
    ``_SAMPLES_PER_BIN`` per bin: ascending)."""
    return GateSamples.of([_ENCODING_ANGLES] * walls)


def _encoding_angles() -> np.ndarray:
    """The angles :func:`maze_encoding` samples on a wall, bin after bin: ``_SAMPLES_PER_BIN`` per bin."""
    width = 2 * math.pi / MAZE_ENCODING_ANGLES
    offsets = (np.arange(_SAMPLES_PER_BIN) + 0.5) / _SAMPLES_PER_BIN * width
    angles = -math.pi + np.arange(MAZE_ENCODING_ANGLES)[:, None] * width + offsets[None, :]
    return angles.reshape(-1)


_ENCODING_ANGLES = _encoding_angles()


@functools.lru_cache(maxsize=_RASTER_CACHE)
def maze_raster(spec: MazeSpec, size: int, board: MazeSpec | None = None) -> MazeRenderer:
    """The pixel raster of ``spec`` at ``size``, cached per process; with ``board`` (a maze with the
    same radii and marble, e.g. an env's base), drawn from the board's raster where the gates differ
    (:meth:`~bimgame.sim.render.MazeRenderer.for_maze`, ~0.1 ms against ~10 ms at 84 px)."""
    if board is None or board == spec:
        return MazeRenderer(spec, size)
    return maze_raster(board, size).for_maze(spec)


@dataclasses.dataclass(frozen=True)
class EnvMazes:
    """An env's mazes: the :class:`MazeSet` it draws from and the board (``base``) they share."""

    maze_set: MazeSet
    base: MazeSpec

    @classmethod
    def from_options(
        cls, base: MazeSpec, num_mazes: Any, start_maze: Any, maze_split: Any, rules: GateRules | None
    ) -> EnvMazes:
        """Checked env arguments (``ValueError`` naming the argument and what is allowed)."""
        if maze_split not in MAZE_SPLITS:
            raise ValueError(f"unknown maze_split {maze_split!r}; allowed: {', '.join(MAZE_SPLITS)}")
        if rules is not None and not isinstance(rules, GateRules):
            raise ValueError(f"maze_rules must be a GateRules or None, got {type(rules).__name__}")
        if not base.walls:
            raise ValueError("num_mazes needs a maze with walls (its board's walls get random gates)")
        return cls(MazeSet(num_mazes, start_maze, maze_split, rules or GateRules()), base)

    @property
    def wall_slots(self) -> tuple[int, ...]:
        """Pieces per wall of the physics model: enough for any maze of the set."""
        return wall_slots(self.base, self.maze_set.rules.max_gates)

    def maze(self, number: int) -> MazeSpec:
        """The maze of ``number`` on the board."""
        return self.maze_set.maze(number, self.base)

    def first_number(self) -> int:
        """The maze an env shows before its first reset (the set's first)."""
        return self.maze_set.start_maze

    def check_number(self, number: Any, where: str) -> int:
        """A maze number a caller chose (``reset(options={"maze": …})``), checked against the set."""
        valid = isinstance(number, (int, np.integer)) and not isinstance(number, (bool, np.bool_)) and number >= 0
        if valid and self.maze_set.num_mazes:
            valid = number in self.maze_set.numbers()
        if not valid:
            allowed = (
                f"{self.maze_set.numbers().start}..{self.maze_set.numbers().stop - 1}"
                if self.maze_set.num_mazes
                else "any integer >= 0"
            )
            raise ValueError(f"{where} must be a maze number of this env's set ({allowed}), got {number!r}")
        return int(number)

    def raster(self, spec: MazeSpec, size: int) -> MazeRenderer:
        """The pixel raster of ``spec``, a maze of the set, at ``size`` (cached per process)."""
        return maze_raster(spec, size, self.base)
