"""Geometry of a circular ball-in-maze puzzle: rings, walls, gates, marble, board.

A :class:`MazeSpec` is a plain, validated description of the puzzle in SI units (metres, radians,
kilograms). Everything else in bimgame (the MuJoCo model, the raster observations, the task rewards
and the geodesic distance used by rewards and the expert) is derived from it, so a custom maze is
one ``MazeSpec(...)`` away.

Layout. The board is a disc bounded by a closed rim. ``walls[0]`` is the innermost ring wall and
``walls[-1]`` the outermost one; each wall is an annulus ``[inner_radius, outer_radius]`` with
``gates``: angular sectors (radial edges, centred at ``angle``, ``width`` wide) where the wall is
open. The walls split the board into channels numbered from the centre out: channel 0 is the goal
region inside wall 0, channel ``k`` lies between wall ``k-1`` and wall ``k``, and the outermost
channel ``len(walls)`` lies between the last wall and the rim.

The default (:meth:`MazeSpec.merl`) reproduces MERL's circular maze used by Paul & van Baar (2018).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from bimgame.sim.geodesic import annulus_path_length, geodesic_tables, wrap_angle, wrap_angle_one

__all__ = ["Gate", "Wall", "MazeSpec", "Friction", "MazeSpecError"]


#: Above this many (angle, gate) pairs :meth:`Wall.in_gate` loops over the gates (bounded temporaries).
_IN_GATE_BLOCK = 1 << 16


class MazeSpecError(ValueError):
    """A :class:`MazeSpec` (or one of its parts) describes a maze that cannot be built."""


def _require_positive(name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise MazeSpecError(f"{name} must be a positive finite number, got {value!r}")


def _require_non_negative(name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
        raise MazeSpecError(f"{name} must be a non-negative finite number, got {value!r}")


@dataclasses.dataclass(frozen=True)
class Gate:
    """An opening in a ring wall: a sector centred at ``angle`` (rad), ``width`` (rad) wide."""

    angle: float
    width: float

    @classmethod
    def deg(cls, angle_deg: float, width_deg: float) -> Gate:
        """A gate given in degrees (the user-facing unit for angles)."""
        return cls(math.radians(angle_deg), math.radians(width_deg))


@dataclasses.dataclass(frozen=True)
class Wall:
    """A ring wall occupying radii ``[inner_radius, outer_radius]`` (m), open at its ``gates``."""

    inner_radius: float
    outer_radius: float
    gates: tuple[Gate, ...]

    @property
    def mid_radius(self) -> float:
        return 0.5 * (self.inner_radius + self.outer_radius)

    @property
    def thickness(self) -> float:
        return self.outer_radius - self.inner_radius

    def solid_arcs(self) -> list[tuple[float, float]]:
        """The closed parts of the wall as ``(start, end)`` angles (rad), counter-clockwise,
        ``start`` in [-pi, pi) and ``end > start`` (it may exceed pi)."""
        if not self.gates:
            return [(-math.pi, math.pi)]
        gates = sorted(self.gates, key=lambda g: wrap_angle_one(g.angle))
        arcs = []
        for i, gate in enumerate(gates):
            nxt = gates[(i + 1) % len(gates)]
            start = wrap_angle_one(gate.angle + gate.width / 2)
            end = wrap_angle_one(nxt.angle - nxt.width / 2)
            while end <= start:
                end += 2 * math.pi
            arcs.append((start, end))
        return arcs

    def in_gate(self, angle: np.ndarray | float) -> np.ndarray:
        """Whether each angle (rad) lies inside one of the wall's gates (every gate in one pass)."""
        angle = np.asarray(angle, dtype=float)
        if not self.gates:
            return np.zeros(angle.shape, dtype=bool)
        centres, half_widths = self._gate_arrays
        if angle.size * len(self.gates) > _IN_GATE_BLOCK:  # large: a gate at a time, no (…, gates) temporaries
            inside = np.zeros(angle.shape, dtype=bool)
            for centre, half_width in zip(centres.tolist(), half_widths.tolist(), strict=True):
                inside |= np.abs(wrap_angle(angle - centre)) <= half_width
            return inside
        shape = (-1,) + (1,) * angle.ndim  # gates on the leading axis: long inner loops
        return np.any(np.abs(wrap_angle(angle - centres.reshape(shape))) <= half_widths.reshape(shape), axis=0)

    @functools.cached_property
    def _gate_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The gates' centre angles and half widths (rad), for :meth:`in_gate`."""
        return (
            np.array([gate.angle for gate in self.gates], dtype=float),
            np.array([gate.width / 2 for gate in self.gates], dtype=float),
        )


@dataclasses.dataclass(frozen=True)
class Friction:
    """Contact friction of the marble with the board (MuJoCo's ``friction`` triple) and static
    friction on the marble's free joint (MuJoCo's ``frictionloss``, in N for the translational and
    N·m for the rotational degrees of freedom)."""

    slide: float = 0.5
    spin: float = 1e-5
    roll: float = 1e-6
    static: float = 1e-6

    @classmethod
    def low(cls) -> Friction:
        """MERL's low-friction variant: the marble slides rather than rolls."""
        return cls(slide=0.001, spin=1e-6, roll=1e-7, static=1e-6)

    def validate(self) -> None:
        for field in dataclasses.fields(self):
            _require_non_negative(f"friction.{field.name}", getattr(self, field.name))


def _validate_wall(k: int, wall: Wall, previous_outer: float, diameter: float) -> None:
    """Check ``walls[k]``, whose inner neighbour ends at ``previous_outer`` (0 for the centre)."""
    if not isinstance(wall, Wall):
        raise MazeSpecError(f"walls[{k}] must be a Wall, got {type(wall).__name__}")
    _require_positive(f"walls[{k}].inner_radius", wall.inner_radius)
    _require_positive(f"walls[{k}].outer_radius", wall.outer_radius)
    if wall.outer_radius <= wall.inner_radius:
        raise MazeSpecError(
            f"walls[{k}]: outer_radius ({wall.outer_radius!r} m) must exceed inner_radius ({wall.inner_radius!r} m)"
        )
    if wall.inner_radius < previous_outer:
        raise MazeSpecError(
            f"walls[{k}] (from {wall.inner_radius!r} m) overlaps walls[{k - 1}] "
            f"(up to {previous_outer!r} m); walls must be listed from the centre out "
            "without overlapping"
        )
    room = wall.inner_radius - previous_outer
    what = "the centre region" if k == 0 else f"channel {k}"
    if room <= diameter:
        raise MazeSpecError(
            f"{what} is {room * 1e3:.2f} mm wide, narrower than the marble "
            f"({diameter * 1e3:.2f} mm): walls[{k}].inner_radius must exceed "
            f"{(previous_outer + diameter) * 1e3:.2f} mm"
        )
    if not wall.gates:
        raise MazeSpecError(f"walls[{k}] has no gate: the centre would be unreachable")
    _validate_gates(k, wall, diameter)


def _validate_gates(k: int, wall: Wall, diameter: float) -> None:
    """Check the gates of ``walls[k]``: each wide enough for the marble, none overlapping another."""
    for j, gate in enumerate(wall.gates):
        if not isinstance(gate, Gate):
            raise MazeSpecError(f"walls[{k}].gates[{j}] must be a Gate, got {gate!r}")
        if not (math.isfinite(gate.angle) and math.isfinite(gate.width)):
            raise MazeSpecError(f"walls[{k}].gates[{j}] has a non-finite angle or width: {gate!r}")
        chord = 2 * wall.inner_radius * math.sin(min(gate.width, math.pi) / 2)
        if gate.width >= 2 * math.pi or chord <= diameter:
            min_width = 2 * math.degrees(math.asin(min(1.0, diameter / (2 * wall.inner_radius))))
            raise MazeSpecError(
                f"walls[{k}].gates[{j}] is {math.degrees(gate.width):.2f}° wide: its opening at "
                f"the wall's inner face ({chord * 1e3:.2f} mm) must exceed the marble's "
                f"diameter ({diameter * 1e3:.2f} mm), i.e. width > {min_width:.2f}° "
                "(and below 360°)"
            )
    gates = sorted(wall.gates, key=lambda g: wrap_angle_one(g.angle))
    for a, b in zip(gates, gates[1:] + gates[:1], strict=True):
        if len(gates) == 1:
            break
        gap = wrap_angle_one(b.angle - a.angle) % (2 * math.pi)
        if gap < (a.width + b.width) / 2:
            raise MazeSpecError(
                f"walls[{k}]: gates at {math.degrees(a.angle):.1f}° and "
                f"{math.degrees(b.angle):.1f}° overlap; merge them into one wider gate"
            )


@dataclasses.dataclass(frozen=True)
class MazeSpec:
    """A circular ball-in-maze puzzle, in SI units. See the module docstring for the layout.

    Attributes:
        walls: ring walls from the innermost (wall 0) outwards.
        rim_radius: inner radius of the closed outer rim (m): the board's playable edge.
        rim_thickness: radial thickness of the rim (m).
        wall_height: height of walls and rim above the floor (m).
        marble_radius: marble radius (m).
        marble_mass: marble mass (kg).
        max_tilt: largest board tilt about either axis (rad).
        tilt_step: tilt change of one discrete action (rad).
        friction: contact and static friction of the marble.
        arc_tolerance: largest distance (m) between a wall's true circular face and the flat
            faces of the box pieces that approximate it in the physics model.
    """

    walls: tuple[Wall, ...]
    rim_radius: float
    rim_thickness: float = 5e-3
    wall_height: float = 20e-3
    marble_radius: float = 6.35e-3
    marble_mass: float = 8.4e-3
    max_tilt: float = math.radians(5.0)
    tilt_step: float = math.radians(1.0)
    friction: Friction = dataclasses.field(default_factory=Friction)
    arc_tolerance: float = 0.1e-3

    def __post_init__(self) -> None:
        object.__setattr__(self, "walls", tuple(self.walls))
        self.validate()

    # ------------------------------------------------------------------ construction
    @classmethod
    def merl(cls, **overrides) -> MazeSpec:
        """MERL's circular maze, the paper's: 4 walls, 1/4/4/4 gates, 6.35 mm steel marble."""
        walls = (
            Wall(16.0e-3, 21.2e-3, (Gate.deg(180, 50.0),)),
            Wall(36.0e-3, 41.3e-3, tuple(Gate.deg(a, 21.4) for a in (45, 135, 225, 315))),
            Wall(56.2e-3, 61.4e-3, tuple(Gate.deg(a, 14.6) for a in (0, 90, 180, 270))),
            Wall(76.2e-3, 81.7e-3, tuple(Gate.deg(a, 11.1) for a in (45, 135, 225, 315))),
        )
        return cls(walls=walls, rim_radius=96.8e-3, **overrides)

    def replace(self, **changes) -> MazeSpec:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------------ validation
    def validate(self) -> None:
        """Raise :class:`MazeSpecError` naming the first problem found."""
        self._validate_scalars()
        diameter = 2 * self.marble_radius
        previous_outer = 0.0
        for k, wall in enumerate(self.walls):
            _validate_wall(k, wall, previous_outer, diameter)
            previous_outer = wall.outer_radius
        room = self.rim_radius - previous_outer
        if room <= diameter:
            raise MazeSpecError(
                f"the outermost channel is {room * 1e3:.2f} mm wide, narrower than the marble "
                f"({diameter * 1e3:.2f} mm): rim_radius must exceed {(previous_outer + diameter) * 1e3:.2f} mm"
            )

    def _validate_scalars(self) -> None:
        for name in (
            "rim_radius",
            "rim_thickness",
            "wall_height",
            "marble_radius",
            "marble_mass",
            "max_tilt",
            "tilt_step",
            "arc_tolerance",
        ):
            _require_positive(name, getattr(self, name))
        if self.max_tilt > math.radians(30):
            raise MazeSpecError(f"max_tilt must be at most 30° (0.5236 rad), got {self.max_tilt!r} rad")
        if self.tilt_step > self.max_tilt:
            raise MazeSpecError(f"tilt_step ({self.tilt_step!r} rad) must not exceed max_tilt ({self.max_tilt!r} rad)")
        if self.wall_height < 2 * self.marble_radius:
            raise MazeSpecError(
                f"wall_height ({self.wall_height!r} m) must be at least the marble's diameter "
                f"({2 * self.marble_radius!r} m) or the marble could hop over walls"
            )
        if not isinstance(self.friction, Friction):
            raise MazeSpecError(f"friction must be a Friction, got {type(self.friction).__name__}")
        self.friction.validate()

    # ------------------------------------------------------------------ derived quantities
    @property
    def n_channels(self) -> int:
        """Number of channels including the centre (goal) region: ``len(walls) + 1``."""
        return len(self.walls) + 1

    @property
    def outermost_channel(self) -> int:
        return len(self.walls)

    def channel_bounds(self, channel: int) -> tuple[float, float]:
        """Radii ``(low, high)`` of a channel's open floor (between its walls)."""
        if not 0 <= channel <= self.outermost_channel:
            raise MazeSpecError(f"channel must be in 0..{self.outermost_channel}, got {channel!r}")
        low = 0.0 if channel == 0 else self.walls[channel - 1].outer_radius
        high = self.rim_radius if channel == self.outermost_channel else self.walls[channel].inner_radius
        return low, high

    def channel_centre_radius(self, channel: int) -> float:
        """Radius midway between a channel's walls (where the marble starts, for the outermost)."""
        low, high = self.channel_bounds(channel)
        return 0.0 if channel == 0 else 0.5 * (low + high)

    def channel_of(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Channel index (0 = centre … ``outermost_channel``) of board-frame points.

        A point inside a wall's gate belongs to the side of the wall's mid-radius it is on.
        (Tasks use :meth:`update_channel`, which adds hysteresis across the wall's thickness.)
        """
        return np.searchsorted(self._tables["mids"], np.hypot(x, y), side="right").astype(np.int64)

    def update_channel(self, previous: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Channel of a moving marble given the channel it was in.

        The marble counts as having passed through a wall only once its centre has cleared the
        wall's far face; while its centre is inside the wall's thickness (i.e. in a gate) it keeps
        its previous channel. This hysteresis means jitter inside a gate never counts as a
        crossing.
        """
        previous = np.asarray(previous, dtype=np.int64)
        r = np.hypot(x, y)
        tables = self._tables
        prev = np.clip(previous, 0, self.outermost_channel)
        held = (r >= tables["hold_low"][prev]) & (r <= tables["hold_high"][prev])
        return np.where(held, prev, np.searchsorted(tables["mids"], r, side="right"))

    def next_channel(self, previous: int, r: float) -> int:
        """Scalar :meth:`update_channel` for one marble at radius ``r`` (the env's fast path)."""
        tables = self._tables
        if tables["hold_low_list"][previous] <= r <= tables["hold_high_list"][previous]:
            return previous
        channel = 0
        for mid in tables["mids_list"]:
            if r >= mid:
                channel += 1
            else:
                break
        return channel

    @functools.cached_property
    def _tables(self) -> dict:
        """Channel lookup tables derived once from the (immutable) geometry."""
        # Channel k is held while r is in [inner face of wall k-1, outer face of wall k].
        hold_low = [0.0] + [w.inner_radius for w in self.walls]
        hold_high = [w.outer_radius for w in self.walls] + [math.inf]
        mids = [w.mid_radius for w in self.walls]
        return {
            "hold_low": np.array(hold_low),
            "hold_high": np.array(hold_high),
            "mids": np.array(mids),
            "hold_low_list": hold_low,
            "hold_high_list": hold_high,
            "mids_list": mids,
            "geodesic": {},
        }

    def _geodesic_tables(self, to_channel: int) -> dict:
        """Per-target geodesic tables (built once per target and cached)."""
        cache = self._tables["geodesic"]
        if to_channel in cache:
            return cache[to_channel]
        if not (isinstance(to_channel, (int, np.integer)) and 0 <= to_channel < max(self.outermost_channel, 1)):
            raise MazeSpecError(
                f"to_channel must be an integer in 0..{max(self.outermost_channel - 1, 0)}, got {to_channel!r}"
            )
        tables = geodesic_tables(self._gate_portals(), [w.mid_radius for w in self.walls], int(to_channel))
        cache[to_channel] = tables
        return tables

    # ------------------------------------------------------------------ geodesic distance
    def geodesic_distance(self, x: np.ndarray | float, y: np.ndarray | float, to_channel: int = 0) -> np.ndarray:
        """Length (m) of the shortest path for the marble's centre from board-frame points to the
        board's centre (``to_channel=0``) or, for ``to_channel=j > 0``, until it has passed
        through wall ``j`` into channel ``j`` (the goal of task STG(n_walls - j)), through the gates.

        Within a channel the marble's centre moves in an annulus whose inner boundary is the inner
        wall's outer face plus the marble radius; the shortest path between two points of an
        annulus is either straight or wraps around that inner circle (tangent, arc, tangent), which
        :func:`annulus_path_length` computes exactly. Each gate is crossed radially at its centre
        angle. Distances from each gate to the goal are found by dynamic programming from the
        inside out (:meth:`gate_distances`), so the whole computation is exact for this model of the
        gates and vectorised over points. A point whose centre is inside a wall's band (within a
        marble radius of the wall, so inside a gate) moves radially to the gate's inner end first:
        the distance falls steadily while the marble passes through a gate.
        """
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        tables = self._geodesic_tables(to_channel)
        r = np.hypot(x, y)
        theta = np.arctan2(y, x)
        channel = np.searchsorted(tables["bounds"], r, side="right")
        # Within a wall's band, outside its gates and beyond its mid radius, the marble is pressed
        # into the solid wall from outside (soft contacts let it sink in by up to v/150 s): it is
        # still outside. Otherwise a planner would be rewarded for ramming walls.
        in_band = r > tables["band_start"][channel]
        into_wall = np.zeros(r.shape, dtype=bool)
        if np.any(in_band):
            for w, wall in enumerate(self.walls):
                mask = in_band & (channel == w)
                if np.any(mask):
                    into_wall[mask] = ~wall.in_gate(theta[mask])
        from_outside = into_wall & (r >= tables["mids"][np.minimum(channel, len(self.walls) - 1)])
        channel = np.where(from_outside, channel + 1, channel)
        # Per point, the table row of its channel (row 0, the centre region, is unused): the
        # obstacle radius, where the next wall's band starts, and the inner wall's gates (padded
        # with infinite distances) — one vectorised pass over all points and gates.
        obstacle = tables["obstacle"][channel]
        band_start = tables["band_start"][channel]
        r_eff = np.minimum(r, band_start)
        lengths = annulus_path_length(
            r_eff[..., None], theta[..., None], obstacle[..., None], tables["gate_angle"][channel], obstacle[..., None]
        )
        best = np.min(lengths + tables["gate_dist"][channel], axis=-1) + (r - r_eff)
        arrived = r if to_channel == 0 else np.maximum(r - tables["target_end"], 0.0)
        return np.where(channel <= to_channel, arrived, best)

    def geodesic_distance_one(self, x: float, y: float, to_channel: int = 0) -> float:
        """Scalar :meth:`geodesic_distance` of one point (the env's per-step fast path; plain
        floats and precomputed per-channel tuples, ~4x faster than numpy on one point)."""
        tables = self._geodesic_tables(to_channel)
        r, theta, channel = self._locate_one(x, y, tables)
        return _distance_from(r, theta, channel, tables, to_channel)

    def geodesic_distances_one(self, x: float, y: float, to_channels: tuple[int, ...]) -> list[float]:
        """:meth:`geodesic_distance_one` to each of ``to_channels``: where the point lies (its channel,
        the same for every target) is found once, then each target's gates are searched."""
        targets = [self._geodesic_tables(c) for c in to_channels]
        r, theta, channel = self._locate_one(x, y, targets[0])
        return [
            _distance_from(r, theta, channel, tables, to_channel)
            for tables, to_channel in zip(targets, to_channels, strict=True)
        ]

    def _locate_one(self, x: float, y: float, tables: dict) -> tuple[float, float, int]:
        """Radius, angle and channel (for the geodesic distance: a point pressed into a wall from
        outside is still outside) of one point; the channels' radii are every target's."""
        r = math.hypot(x, y)
        channel = 0
        for bound in tables["bounds_list"]:
            if r >= bound:
                channel += 1
        theta = math.atan2(y, x)
        if channel < len(self.walls) and r > tables["band_start_list"][channel]:
            wall = self.walls[channel]
            if r >= wall.mid_radius and not wall.in_gate(theta):
                channel += 1  # pressed into the wall from outside: still outside (rare: in a band)
        return r, theta, channel

    def gate_distances(self, to_channel: int = 0) -> list[np.ndarray]:
        """For each wall, the geodesic distance (m) from each gate's outer portal to the goal
        (walls at or inside the target get infinite distances: they are never needed)."""
        return [d.copy() for d in self._geodesic_tables(to_channel)["gate_distances"]]

    def _gate_portals(self) -> list[dict]:
        """Per wall: gate centre angles and the radii where the marble's centre enters the gate
        from outside (``outer_radius``) and leaves it inside (``inner_radius``)."""
        portals = []
        for wall in self.walls:
            portals.append(
                {
                    "angles": [g.angle for g in wall.gates],
                    "outer_radius": wall.outer_radius + self.marble_radius,
                    "inner_radius": max(wall.inner_radius - self.marble_radius, 0.0),
                }
            )
        return portals


def _distance_from(r: float, theta: float, channel: int, tables: dict, to_channel: int) -> float:
    """The geodesic distance to ``to_channel`` (its ``tables``) of a point at radius ``r`` and angle
    ``theta`` in ``channel``: :meth:`MazeSpec.geodesic_distance_one` once the channel is known."""
    if channel <= to_channel:
        return r if to_channel == 0 else max(r - tables["target_end"], 0.0)
    a, band_start, gates = tables["channels"][channel - 1]
    extra = 0.0
    if r > band_start:
        extra, r = r - band_start, band_start
    r1 = r if r > a else a
    alpha1 = math.acos(a / r1)
    tangent = math.sqrt(r1 * r1 - a * a)
    best = math.inf
    pi, two_pi = math.pi, 2 * math.pi
    for angle, dist in gates:
        dtheta = abs((theta - angle + pi) % two_pi - pi)
        if dtheta <= alpha1:  # straight to the gate portal (which lies on the obstacle circle)
            length = math.sqrt(max(r1 * r1 + a * a - 2 * r1 * a * math.cos(dtheta), 0.0))
        else:
            length = tangent + a * (dtheta - alpha1)
        length += dist
        if length < best:
            best = length
    return best + extra
