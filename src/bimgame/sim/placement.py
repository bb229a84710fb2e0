"""Where marbles may be put on a maze: random starts, how many fit, and checking given positions.

- :func:`sample_start` draws the environments' random starts: marbles at rest on the outermost
  channel's centre circle, at least two marble diameters apart along it. :func:`max_start_marbles`
  is how many fit there; more are refused (:func:`check_n_marbles`) instead of looping forever.
- :func:`check_marble_xy` refuses positions a marble cannot occupy: overlapping a wall's solid part,
  the rim (or off the board) or another marble. The contact solver would push such a marble out
  through the nearest face — possibly through a wall, which the tasks would count as a crossing.
- :func:`check_sim_state` refuses a physics state (``MazeSim.get_state``) an episode cannot start
  from: not finite, the wrong length, a board or servo target tilted beyond ``max_tilt``, or marbles
  inside a wall, the rim or each other (beyond what the soft contacts of a real run allow), or off
  the floor. It returns the marbles' board-frame positions, what the tasks' state is derived from.
- :func:`finite_array` converts an input to a float array of a given shape, with an error that
  says whether the shape or the values (not finite) are wrong.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from bimgame.sim.maze import MazeSpec
from bimgame.util.settings import is_integer

__all__ = [
    "start_radius",
    "start_separation",
    "max_start_marbles",
    "check_n_marbles",
    "sample_start",
    "finite_array",
    "check_marble_xy",
    "check_sim_state",
    "MAX_START_DRAWS",
    "STATE_OVERLAP",
    "STATE_TILT_TOLERANCE",
]

#: Random draws :func:`sample_start` makes one marble at a time before it places all marbles at once
#: instead (see there). Far more than any start that does not jam needs (≤ 14 marbles on MERL's maze:
#: at most ~500 draws in 300 seeds; 16 marbles: up to ~41,000).
MAX_START_DRAWS = 100_000
#: Slack (m) for round-off when a marble exactly touches a wall, the rim or another marble.
TOUCH_TOLERANCE = 1e-9
#: Overlap (in marble radii) :func:`check_sim_state` allows between a marble and a wall, the rim or
#: another marble. Contacts are found only once bodies overlap, at 150 Hz: on impact a marble sinks
#: into a wall by about one physics step of travel (up to 1.3 mm seen in 190,000 states of random
#: play on MERL's maze, 5% of them overlapping a wall by some amount; 2.8 mm at 0.5 m/s, 4.2 mm at
#: 0.7 m/s in tests/sim/test_physics.py), and the walls' flat box faces lie up to ``arc_tolerance``
#: inside the true circles. Three quarters of a radius (4.8 mm on MERL's maze) accepts such states
#: while keeping the marble's centre outside the wall, so the contact pushes it back out on the side
#: it came from, never through the wall.
STATE_OVERLAP = 0.75
#: How far (as a share of ``max_tilt``) :func:`check_sim_state` lets the board's tilt exceed
#: ``±max_tilt``: the servo overshoots its clamped target slightly (≤ 1.1% measured).
STATE_TILT_TOLERANCE = 0.05


def start_radius(spec: MazeSpec) -> float:
    """Radius (m) of the circle the random starts lie on: the outermost channel's centre circle."""
    return spec.channel_centre_radius(spec.outermost_channel)


def start_separation(spec: MazeSpec) -> float:
    """Smallest angle (rad) between two random starts: two marble diameters along the start circle."""
    return 2 * (2 * spec.marble_radius) / start_radius(spec)


def max_start_marbles(spec: MazeSpec) -> int:
    """How many marbles fit on the start circle more than :func:`start_separation` apart."""
    if not spec.walls:
        return 0
    return math.ceil(2 * math.pi / start_separation(spec)) - 1


def check_n_marbles(spec: MazeSpec, n_marbles: Any) -> int:
    """``n_marbles`` as an int, or a ``ValueError`` if it is not an integer ≥ 1 or more marbles
    than :func:`max_start_marbles` (random starts could never be drawn)."""
    if not (is_integer(n_marbles) and n_marbles >= 1):
        raise ValueError(f"n_marbles must be an integer >= 1, got {n_marbles!r}")
    if not spec.walls:
        raise ValueError(
            "maze has no walls: random starts need a maze with at least one wall: they lie on "
            "the centre circle of the outermost channel, and without walls the whole board is "
            "the goal region (channel 0)"
        )
    limit = max_start_marbles(spec)
    if n_marbles > limit:
        radius = start_radius(spec)
        raise ValueError(
            f"n_marbles={int(n_marbles)} is too many: at most {limit} marbles fit on the outermost channel, "
            f"where reset() places them at rest on its centre circle (radius {radius * 1e3:.2f} mm, "
            f"circumference {2 * math.pi * radius * 1e3:.1f} mm) at least two marble diameters "
            f"({4 * spec.marble_radius * 1e3:.2f} mm) apart"
        )
    return int(n_marbles)


def sample_start(spec: MazeSpec, n_marbles: int, rng: np.random.Generator) -> np.ndarray:
    """Random board-frame start positions (n_marbles, 2) on the outermost channel's centre circle,
    at least two marble diameters apart (:func:`start_separation`).

    Marbles are placed one at a time, each at an angle drawn uniformly and redrawn while it is too
    close to one already placed. Placed at random like this, marbles can leave no room for the next
    one (from ~15 marbles on MERL's maze, long before the 22 that fit) or leave a sliver that takes
    ages to hit. So once no gap is wide enough for another marble, or after :data:`MAX_START_DRAWS`
    draws, all marbles are placed again at once with the rest of ``rng``: the gaps beyond the minimum
    spacing are drawn uniformly (uniform over all valid arrangements, and it cannot fail). Starts
    placed one at a time make the same draws as before this fallback existed: seeds keep their starts.

    Raises ``ValueError`` if ``n_marbles`` is not an integer in 1..:func:`max_start_marbles`.
    """
    n_marbles = check_n_marbles(spec, n_marbles)
    radius = start_radius(spec)
    min_separation = start_separation(spec)
    angles: list[float] = []
    draws = 0
    while len(angles) < n_marbles:
        if draws >= MAX_START_DRAWS:
            angles = _spaced_angles(n_marbles, min_separation, rng)
            break
        draws += 1
        candidate = float(rng.uniform(-math.pi, math.pi))
        if all(abs((candidate - a + math.pi) % (2 * math.pi) - math.pi) > min_separation for a in angles):
            angles.append(candidate)
            if len(angles) < n_marbles and _jammed(angles, min_separation):
                angles = _spaced_angles(n_marbles, min_separation, rng)
    angles_arr = np.array(angles)
    return np.stack([radius * np.cos(angles_arr), radius * np.sin(angles_arr)], axis=-1)


def _jammed(angles: list[float], min_separation: float) -> bool:
    """Whether no angle is more than ``min_separation`` from all of ``angles`` (no gap between
    neighbours exceeds twice the separation)."""
    ordered = sorted(angles)
    gaps = [b - a for a, b in zip(ordered, ordered[1:], strict=False)] + [ordered[0] + 2 * math.pi - ordered[-1]]
    return max(gaps) <= 2 * min_separation


def _spaced_angles(n: int, min_separation: float, rng: np.random.Generator) -> list[float]:
    """``n`` angles (rad) at least ``min_separation`` apart on the circle, uniformly over all such
    arrangements: the slack ``2π − n·separation`` is split into n gaps by n − 1 uniform cuts, each
    gap widened by the separation, the whole turned by a uniform angle; marbles in random order."""
    slack = 2 * math.pi - n * min_separation
    cuts = np.sort(rng.uniform(0.0, slack, n - 1))
    offsets = np.concatenate([[0.0], cuts + min_separation * np.arange(1, n)])
    angles = (rng.uniform(-math.pi, math.pi) + offsets + math.pi) % (2 * math.pi) - math.pi
    return angles[rng.permutation(n)].tolist()


def finite_array(name: str, value: Any, shape: tuple[int, ...], what: str = "") -> np.ndarray:
    """``value`` as a float64 array of ``shape``; a ``ValueError`` naming ``name`` says whether it
    is not numbers, has the wrong shape or holds non-finite values (``what`` explains the shape)."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be numbers of shape {shape}{what}, got {value!r} ({error})") from None
    if array.shape != shape:
        raise ValueError(f"{name} must have shape {shape}{what}, got shape {array.shape}: {value!r}")
    if not np.all(np.isfinite(array)):
        bad = [tuple(int(i) for i in index) for index in np.argwhere(~np.isfinite(array))]
        raise ValueError(f"{name} is not finite at {', '.join(map(str, bad))}: {array.tolist()}")
    return array


def check_marble_xy(spec: MazeSpec, marble_xy: np.ndarray, name: str = "marble_xy", *, overlap: float = 0.0) -> None:
    """Raise ``ValueError`` unless every marble at board-frame positions ``marble_xy`` (n, 2) (m,
    finite) lies on the board clear of the walls' solid parts, the rim and the other marbles
    (touching is allowed; ``overlap`` (m) more is, for positions from the simulator's soft
    contacts). The message names the marble and the wall (its index and radial span) or the two
    marbles that overlap."""
    rm = spec.marble_radius
    slack = TOUCH_TOLERANCE + overlap
    allowed = f" (overlaps up to {overlap * 1e3:.2f} mm are allowed)" if overlap > 0 else ""
    for i, (x, y) in enumerate(np.asarray(marble_xy, dtype=np.float64).tolist()):
        r = math.hypot(x, y)
        where = f"{name}[{i}] = ({x * 1e3:.2f}, {y * 1e3:.2f}) mm, {r * 1e3:.2f} mm from the centre,"
        if r + rm > spec.rim_radius + slack:
            raise ValueError(
                f"{where} overlaps the rim or lies off the board: a marble's centre must be within "
                f"{(spec.rim_radius - rm) * 1e3:.2f} mm of the centre (rim_radius − marble_radius){allowed}"
            )
        for k, wall in enumerate(spec.walls):
            if r + rm <= wall.inner_radius or r - rm >= wall.outer_radius:
                continue
            clearance = min(
                _distance_to_sector(x, y, wall.inner_radius, wall.outer_radius, a0, a1) for a0, a1 in wall.solid_arcs()
            )
            if clearance < rm - slack:
                raise ValueError(
                    f"{where} overlaps walls[{k}] (solid from {wall.inner_radius * 1e3:.2f} to "
                    f"{wall.outer_radius * 1e3:.2f} mm from the centre; gates at "
                    f"{', '.join(f'{math.degrees(g.angle):.1f}°' for g in wall.gates)}): its centre is "
                    f"{max(clearance, 0.0) * 1e3:.2f} mm from the wall, less than the marble radius "
                    f"({rm * 1e3:.2f} mm){allowed}. Place marbles inside a channel or a gate, e.g. on a "
                    "channel's centre circle (MazeSpec.channel_centre_radius)"
                )
    xy = np.asarray(marble_xy, dtype=np.float64)
    for i in range(len(xy)):
        for j in range(i + 1, len(xy)):
            distance = math.hypot(*(xy[i] - xy[j]))
            if distance < 2 * rm - slack:
                raise ValueError(
                    f"marbles {i} and {j} overlap: {name}[{i}] and {name}[{j}] are {distance * 1e3:.2f} mm "
                    f"apart, less than the marble diameter ({2 * rm * 1e3:.2f} mm){allowed}"
                )


def check_sim_state(
    spec: MazeSpec,
    layout: Any,
    state: Any,
    name: str = "sim_state",
) -> tuple[np.ndarray, np.ndarray]:
    """Check a physics state an episode is to start from; return it as a float64 array (a copy) and
    the marbles' board-frame positions ``(n, 2)`` (m), from which the task's state is derived.

    ``layout`` is the :class:`~bimgame.sim.physics.StateLayout` of the sim the state is for
    (``MazeSim.layout``). Raises ``ValueError`` naming ``name`` unless the state is finite numbers
    of the layout's length (a ``MazeSim.get_state()`` vector of a maze with as many marbles), the
    board's tilt and the servos' target tilt lie within ``±max_tilt`` (the board's with
    :data:`STATE_TILT_TOLERANCE`), every marble lies on the floor clear of the walls, the rim and the
    other marbles up to the contacts' :data:`STATE_OVERLAP`, and its centre sits between
    ``(1 − STATE_OVERLAP)`` radii above the floor and the walls' tops."""
    n = layout.n_marbles
    array = finite_array(
        name, state, (layout.size,), f" (a MazeSim.get_state() vector of a maze with {n} marble(s))"
    ).copy()
    limit = spec.max_tilt
    for what, index, slack in (
        ("board tilt", layout.tilt, STATE_TILT_TOLERANCE * limit),
        ("target tilt", layout.target_tilt, TOUCH_TOLERANCE),
    ):
        values = array[index]
        if np.any(np.abs(values) > limit + slack):
            raise ValueError(
                f"{name}: the {what} ({', '.join(f'{math.degrees(v):.3f}°' for v in values)} about x, y) "
                f"exceeds ±max_tilt = ±{math.degrees(limit):.3f}°"
                + (f" (by more than the servo's overshoot, {math.degrees(slack):.3f}°)" if slack > 1e-6 else "")
            )
    positions, _ = layout.board_frame(array)
    rm = spec.marble_radius
    low, high = rm * (1.0 - STATE_OVERLAP), spec.wall_height
    for i, z in enumerate(positions[:, 2].tolist()):
        if not low <= z <= high:
            raise ValueError(
                f"{name}: marble {i}'s centre is {z * 1e3:.2f} mm above the floor; allowed: "
                f"{low * 1e3:.2f} to {high * 1e3:.2f} mm (resting: the marble radius, {rm * 1e3:.2f} mm)"
            )
    xy = np.ascontiguousarray(positions[:, :2])
    check_marble_xy(spec, xy, f"{name}: marble_xy", overlap=STATE_OVERLAP * rm)
    return array, xy


def _distance_to_sector(x: float, y: float, inner: float, outer: float, start: float, end: float) -> float:
    """Distance (m) from a point to the annular sector ``[inner, outer] × [start, end]`` (angles
    as :meth:`~bimgame.sim.maze.Wall.solid_arcs` gives them); 0 inside it."""
    r = math.hypot(x, y)
    if (math.atan2(y, x) - start) % (2 * math.pi) <= end - start:
        return max(inner - r, r - outer, 0.0)
    best = math.inf
    for edge in (start, end):  # outside the sector's angles: the nearest point is on a radial edge
        ux, uy = math.cos(edge), math.sin(edge)
        t = min(max(x * ux + y * uy, inner), outer)
        best = min(best, math.hypot(x - t * ux, y - t * uy))
    return best
