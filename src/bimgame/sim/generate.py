"""Procedural circular mazes: random gates on a fixed board, and a hash that names a maze.

:func:`random_maze` draws a valid, solvable maze on a base board (MERL's by default): the base's
walls (radii), rim, marble, tilt and friction are kept; each wall gets a random number of gates
(``min_gates`` … ``max_gates``, uniform) at random angles. A gate's opening at the wall's inner face
(its chord, where the marble's fit is tightest) is the marble's diameter plus ``margin`` plus a
uniform draw in ``[0, extra_margin]``: 0.7–2 mm by default, as on MERL's board, whose gates are
0.7–2 mm wider than the marble at that face (``../shared/DESIGN.md`` §2). The solid arcs between
gates are at least ``min_solid`` long (m, at the wall's inner face) and share the rest of the
circle in uniform proportions (a flat Dirichlet), turned by a uniform random angle: no rejection
loop, so a draw never fails and costs the same every time. Every wall has a gate and the channels
are annuli, so every generated maze is solvable; it is validated like every
:class:`~bimgame.sim.maze.MazeSpec`.

Keeping the base's radii is a choice, not a limit of :class:`MazeSpec`: the tasks (STG1 … STG4 pass
the k-th wall), the start circle and the fixed set of wall pieces the physics switches between
(:meth:`~bimgame.sim.physics.MazeSim.set_walls`) then mean the same on every maze.

:func:`maze_hash` names a maze up to a rotation: starts are uniform in angle, so a maze turned as a
whole poses the same puzzle. The hash is that of a canonical form — among the rotations that bring
one gate of the wall with the fewest gates to angle 0, the one whose rounded gate list sorts first —
with every other field of the spec. Angles are rounded to micro-radians (the hash of a rotated copy
could differ only if a rounded value fell exactly on a rounding boundary).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import math

import numpy as np

from bimgame.sim.geodesic import wrap_angle_one
from bimgame.sim.maze import Gate, MazeSpec, MazeSpecError, Wall

__all__ = ["GateRules", "random_maze", "maze_hash", "rotate_maze"]

#: Decimal places of angles (rad) and lengths (m) in :func:`maze_hash`: micro-radians, nanometres.
_ANGLE_DIGITS = 6
_LENGTH_DIGITS = 9


@dataclasses.dataclass(frozen=True)
class GateRules:
    """How :func:`random_maze` draws each wall's gates (lengths in metres, at the wall's inner face)."""

    min_gates: int = 1
    """Fewest gates per wall."""
    max_gates: int = 4
    """Most gates per wall."""
    margin: float = 0.7e-3
    """Smallest clearance of a gate's opening over the marble's diameter."""
    extra_margin: float = 1.3e-3
    """A uniform draw in [0, extra_margin] added to ``margin`` per gate."""
    min_solid: float = 8e-3
    """Shortest solid arc between two gates of a wall."""

    def check(self) -> None:
        """Raise :class:`MazeSpecError` naming the first field out of range."""
        if not (isinstance(self.min_gates, int) and isinstance(self.max_gates, int) and 1 <= self.min_gates):
            raise MazeSpecError(f"min_gates must be an integer >= 1, got {self.min_gates!r}")
        if not self.min_gates <= self.max_gates <= 8:
            raise MazeSpecError(f"max_gates must be an integer in {self.min_gates}..8, got {self.max_gates!r}")
        for name in ("margin", "extra_margin", "min_solid"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise MazeSpecError(f"{name} must be a non-negative number of metres, got {value!r}")
        if self.margin <= 0:
            raise MazeSpecError(f"margin must be positive (a gate must be wider than the marble), got {self.margin!r}")


def _gate_width(inner_radius: float, chord: float) -> float:
    """Angular width (rad) of a gate whose opening at radius ``inner_radius`` is ``chord`` long."""
    return 2 * math.asin(min(1.0, chord / (2 * inner_radius)))


@functools.lru_cache(maxsize=16)
def _ones(count: int) -> np.ndarray:
    """The Dirichlet's flat parameters for ``count`` gates (read-only, made once)."""
    ones = np.ones(count)
    ones.flags.writeable = False
    return ones


def _random_gates(wall: Wall, diameter: float, rules: GateRules, rng: np.random.Generator) -> tuple[Gate, ...]:
    """Gates for ``wall``: as many as the rules draw, fewer if the circle cannot hold them."""
    count = int(rng.integers(rules.min_gates, rules.max_gates + 1))
    least = diameter + rules.margin
    chords = [least + extra for extra in rng.uniform(0.0, rules.extra_margin, size=count).tolist()]
    widths = [_gate_width(wall.inner_radius, c) for c in chords]
    solid = rules.min_solid / wall.inner_radius
    free = 2 * math.pi - sum(widths) - count * solid
    while free < 0 and count > 1:  # too many gates for this wall: drop one (deterministic)
        count -= 1
        widths = widths[:count]
        free = 2 * math.pi - sum(widths) - count * solid
    if free < 0:
        raise MazeSpecError(
            f"wall at {wall.inner_radius * 1e3:.1f} mm cannot hold one gate of {math.degrees(widths[0]):.1f}° "
            f"with min_solid {rules.min_solid * 1e3:.1f} mm: lower GateRules.min_solid or margin"
        )
    shares = [share * free for share in rng.dirichlet(_ones(count)).tolist()] if count > 1 else [free]
    start = float(rng.uniform(-math.pi, math.pi))
    gates = []
    for width, share in zip(widths, shares, strict=True):
        gates.append(Gate(wrap_angle_one(start + width / 2), width))
        start += width + solid + share
    return tuple(gates)


def random_maze(rng: np.random.Generator, base: MazeSpec | None = None, rules: GateRules | None = None) -> MazeSpec:
    """A random maze on ``base``'s board (default MERL's): new gates on every wall, all else kept.

    Draws only from ``rng``, so the same generator state gives the same maze. See the module
    docstring for the distribution.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    base = MazeSpec.merl() if base is None else base
    rules = GateRules() if rules is None else rules
    rules.check()
    diameter = 2 * base.marble_radius
    walls = tuple(Wall(w.inner_radius, w.outer_radius, _random_gates(w, diameter, rules, rng)) for w in base.walls)
    return base.replace(walls=walls)


def rotate_maze(spec: MazeSpec, angle: float) -> MazeSpec:
    """``spec`` turned by ``angle`` (rad, counter-clockwise): every gate's angle moved by it."""
    walls = tuple(
        Wall(w.inner_radius, w.outer_radius, tuple(Gate(wrap_angle_one(g.angle + angle), g.width) for g in w.gates))
        for w in spec.walls
    )
    return spec.replace(walls=walls)


def _rounded_gates(spec: MazeSpec) -> list[list[tuple[float, float]]]:
    """Per wall, its gates' ``(angle, width rounded)``: what :func:`_turned_lists` turns."""
    return [[(gate.angle, round(gate.width, _ANGLE_DIGITS)) for gate in wall.gates] for wall in spec.walls]


def _turned_lists(gates: list[list[tuple[float, float]]], turn: float) -> tuple[tuple[tuple[float, float], ...], ...]:
    """Per wall, its gates (:func:`_rounded_gates`: widths rounded once for every turn) turned by
    ``turn``, as sorted ``(angle in [0, 2π), width)`` rounded pairs."""
    two_pi = 2 * math.pi
    full_turn = round(two_pi, _ANGLE_DIGITS)
    lists = []
    for wall in gates:
        turned = []
        for angle, width in wall:
            rounded = round(float((angle + turn) % two_pi), _ANGLE_DIGITS)
            turned.append((0.0 if rounded >= full_turn else rounded, width))
        lists.append(tuple(sorted(turned)))
    return tuple(lists)


def maze_hash(spec: MazeSpec) -> str:
    """A hex SHA-256 naming ``spec`` up to a rotation of the whole maze (see the module docstring)."""
    if not isinstance(spec, MazeSpec):
        raise TypeError(f"spec must be a MazeSpec, got {type(spec).__name__}")
    if spec.walls:
        pivot = min(range(len(spec.walls)), key=lambda k: (len(spec.walls[k].gates), k))
        gates = _rounded_gates(spec)
        canonical = min(_turned_lists(gates, -gate.angle) for gate in spec.walls[pivot].gates)
    else:
        canonical = ()
    radii = tuple((round(w.inner_radius, _LENGTH_DIGITS), round(w.outer_radius, _LENGTH_DIGITS)) for w in spec.walls)
    board = {field.name: getattr(spec, field.name) for field in dataclasses.fields(spec) if field.name != "walls"}
    text = repr((radii, canonical, sorted((k, repr(v)) for k, v in board.items())))
    return hashlib.sha256(text.encode()).hexdigest()
