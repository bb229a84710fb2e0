"""The MuJoCo model of a :class:`~bimgame.sim.maze.MazeSpec` as MJCF text (:func:`build_mjcf`), which
:class:`~bimgame.sim.physics.MazeSim` compiles; the module docstring of :mod:`bimgame.sim.physics`
describes the model.
"""

from __future__ import annotations

import math

import numpy as np

from bimgame.sim.maze import Friction, MazeSpec

__all__ = [
    "build_mjcf",
    "check_slot_counts",
    "contact_condim",
    "hinged_board_mjcf",
    "servo_mjcf",
    "slotted_boxes",
    "wall_box_arrays",
    "wall_boxes",
    "wall_pieces",
    "wall_slots",
    "PHYSICS_HZ",
    "PARKED_Z",
]

PHYSICS_HZ = 150.0

# Board and servo constants: the board is stiffly position-controlled, so its own inertia only
# sets how tightly it tracks the commanded tilt (natural frequency SERVO_OMEGA, critically damped).
BOARD_MASS = 1.0
BOARD_INERTIA = (1e-2, 1e-2, 2e-2)
GIMBAL_INERTIA = 1e-6
SERVO_OMEGA = 100.0
FLOOR_THICKNESS = 4e-3
# Contact softness: time constant at MuJoCo's stable minimum of two physics steps, critically
# damped, with high impedance so a resting marble sinks only ~0.1 mm into the floor.
CONTACT_SOLREF = "0.0134 1"
CONTACT_SOLIMP = "0.95 0.99 0.001"
# Static friction (frictionloss) with MuJoCo's default softness lets a marble below its breakaway
# tilt creep at ~0.5 mm/s; a high impedance makes it hold (0.06 mm in 1 s at half the breakaway).
STATIC_FRICTION_SOLIMP = "0.99 0.999 0.001"
#: Height (m, board frame) of a wall piece not used by the current maze: a metre below the floor,
#: where no marble comes near (MuJoCo's bounding-sphere test drops its pair at once).
PARKED_Z = -1.0
#: Half sizes (m) of a parked piece.
PARKED_HALF_SIZE = 1e-3

#: A wall piece: centre ``(cx, cy)`` (m), half length along the wall, half depth across it (m) and
#: the yaw (rad) of its depth axis.
Box = tuple[float, float, float, float, float]


def _arc_boxes(
    inner: float,
    outer: float,
    start: float,
    end: float,
    tolerance: float,
) -> list[tuple[float, float, float, float, float]]:
    """Boxes ``(cx, cy, half_length, half_depth, yaw)`` covering the annular sector
    ``[inner, outer] x [start, end]``.

    Interior pieces span angle ``delta`` with faces placed so the circle deviates at most
    ``inner * (1/cos(delta/2) - 1) / 2`` from them; the end pieces are narrow enough that their
    flat end face stays within ``tolerance`` of the sector's radial edge (the gate edge), which is
    what decides whether the marble fits through a gate.
    """
    depth = outer - inner
    # Largest interior span keeping both faces within tolerance (circle vs. symmetric chord).
    delta_max = 2 * math.acos(1.0 / (1.0 + 2 * tolerance / outer))
    # End pieces: flat end face vs. radial edge differ by depth/2 * tan(delta/2).
    delta_end = min(delta_max, 2 * math.atan(2 * tolerance / depth))
    span = end - start
    pieces: list[tuple[float, float]] = []
    if span <= 2 * delta_end:
        pieces.append((start, end))
    else:
        middle = span - 2 * delta_end
        n_mid = max(1, math.ceil(middle / delta_max))
        edges = [start, start + delta_end]
        edges += [start + delta_end + middle * (i + 1) / n_mid for i in range(n_mid)]
        edges += [end]
        pieces = list(zip(edges[:-1], edges[1:], strict=True))
    boxes = []
    for a0, a1 in pieces:
        half = 0.5 * (a1 - a0)
        c = math.cos(half)
        # Faces at distances placing the circle symmetrically about each flat face.
        d_in = 2 * inner / (1 + 1 / c)
        d_out = 2 * outer / (1 + 1 / c)
        # Half length reaches the radial edge line at the face's mid-depth (outer face for
        # interior pieces so neighbours overlap without gaps).
        half_len = d_out * math.tan(half)
        mid = 0.5 * (a0 + a1)
        rc = 0.5 * (d_in + d_out)
        boxes.append((rc * math.cos(mid), rc * math.sin(mid), half_len, 0.5 * (d_out - d_in), mid))
    # End pieces: pull their outer ends back so the end face passes through the radial edge at
    # mid-depth instead of overhanging into the gate.
    return [_trim_end_box(b, inner, outer, a0, a1, start, end) for b, (a0, a1) in zip(boxes, pieces, strict=True)]


def _trim_end_box(box, inner, outer, a0, a1, start, end):
    cx, cy, half_len, half_depth, yaw = box
    if a0 != start and a1 != end:
        return box
    half = 0.5 * (a1 - a0)
    rm = 0.5 * (inner + outer)
    # Tangential coordinate (along the box) of the radial edge at mid-depth, relative to the box
    # centre: the edge point at radius rm sits at angle +-half from the bisector.
    t_edge = rm * math.sin(half)
    lo = -t_edge if a0 == start else -half_len
    hi = t_edge if a1 == end else half_len
    new_half = 0.5 * (hi - lo)
    shift = 0.5 * (hi + lo)
    tx, ty = -math.sin(yaw), math.cos(yaw)
    return (cx + shift * tx, cy + shift * ty, new_half, half_depth, yaw)


def _box_geom(name: str, box: Box, height: float, exact: bool = False) -> str:
    """The MJCF geom of one wall piece (its x axis radial, its y axis along the wall); ``exact``
    writes every float so that it reads back bit for bit (slotted models: see :func:`build_mjcf`)."""
    cx, cy, hl, hd, yaw = box
    if exact:
        return (
            f'<geom name="{name}" class="wall" pos="{cx!r} {cy!r} {height / 2!r}" '
            f'size="{hd!r} {hl!r} {height / 2!r}" euler="0 0 {yaw!r}"/>'
        )
    return (
        f'<geom name="{name}" class="wall" pos="{cx:.9g} {cy:.9g} {height / 2:.9g}" '
        f'size="{hd:.9g} {hl:.9g} {height / 2:.9g}" euler="0 0 {yaw:.12g}"/>'
    )


def wall_boxes(spec: MazeSpec) -> list[list[Box]]:
    """The pieces of each ring wall of ``spec`` (not the rim), in the order the model lists them."""
    return [[tuple(box) for box in pieces.tolist()] for pieces in wall_box_arrays(spec)]


def _math_map(function, values: np.ndarray) -> np.ndarray:
    """``function`` (from :mod:`math`) of each value: libm's results, which numpy's vectorised
    transcendental functions need not match bit for bit (they differ for ``tan`` on AVX-512)."""
    return np.fromiter(map(function, values.tolist()), dtype=np.float64, count=values.size)


def wall_box_arrays(spec: MazeSpec) -> list[np.ndarray]:
    """Per ring wall of ``spec``, its pieces as rows ``(cx, cy, half_length, half_depth, yaw)``: the
    boxes of :func:`_arc_boxes` over the wall's solid arcs (:func:`wall_pieces`, split by wall)."""
    boxes, counts = wall_pieces(spec)
    return np.split(boxes, np.cumsum(counts)[:-1]) if counts else []


def wall_pieces(spec: MazeSpec) -> tuple[np.ndarray, list[int]]:
    """Every ring wall's pieces of ``spec``, wall 0's first, as rows ``(cx, cy, half_length,
    half_depth, yaw)``, and each wall's number of pieces: what switching a model to a new maze needs
    per episode, every arc of every wall in one vectorised pass.

    Bit for bit :func:`_arc_boxes`' numbers (a test compares them over many mazes): the same IEEE
    operations on the same operands, elementwise, and the transcendental functions from :mod:`math`
    as there (numpy's vectorised ones need not match libm: ``tan`` differs on AVX-512).
    """
    tolerance = spec.arc_tolerance
    arcs: list[tuple[float, ...]] = []  # per arc: start, end, start + delta_end, middle, n_mid, radii, first piece
    counts, total = [], 0
    for wall in spec.walls:
        inner, outer = wall.inner_radius, wall.outer_radius
        delta_max = 2 * math.acos(1.0 / (1.0 + 2 * tolerance / outer))
        delta_end = min(delta_max, 2 * math.atan(2 * tolerance / (outer - inner)))
        before = total
        for start, end in wall.solid_arcs():
            span = end - start
            if span <= 2 * delta_end:  # one piece: n_mid = -1 makes its end the arc's end
                middle, n_mid, pieces = 0.0, -1, 1
            else:
                middle = span - 2 * delta_end
                n_mid = max(1, math.ceil(middle / delta_max))
                pieces = n_mid + 2
            arcs.append((start, end, start + delta_end, middle, n_mid, inner, outer, total, pieces))
            total += pieces
        counts.append(total - before)
    if not arcs:
        return np.zeros((0, 5)), counts
    table = np.array(arcs)
    rep = np.repeat(table[:, :8], table[:, 8].astype(np.int64), axis=0)
    s, e, sd, m, n, r_in, r_out = rep[:, 0], rep[:, 1], rep[:, 2], rep[:, 3], rep[:, 4], rep[:, 5], rep[:, 6]
    # The piece's index j in its arc; its edges are the arc's edges j and j + 1: the start, then
    # start + delta_end + middle * i / n_mid (i = 0 … n_mid), then the end.
    j = np.arange(total) - rep[:, 7]
    a0 = np.where(j == 0, s, sd + m * (j - 1) / n)
    a1 = np.where(j == n + 1, e, sd + m * j / n)
    half = 0.5 * (a1 - a0)
    c = _math_map(math.cos, half)
    d_in = 2 * r_in / (1 + 1 / c)
    d_out = 2 * r_out / (1 + 1 / c)
    half_len = d_out * _math_map(math.tan, half)
    mid = 0.5 * (a0 + a1)
    rc = 0.5 * (d_in + d_out)
    cos_mid, sin_mid = _math_map(math.cos, mid), _math_map(math.sin, mid)
    cx, cy = rc * cos_mid, rc * sin_mid
    # _trim_end_box: the arc's end pieces pulled back to the gate edge at mid-depth.
    first, last = a0 == s, a1 == e
    trim = first | last
    t_edge = 0.5 * (r_in + r_out) * _math_map(math.sin, half)
    lo = np.where(first, -t_edge, -half_len)
    hi = np.where(last, t_edge, half_len)
    shift = 0.5 * (hi + lo)
    boxes = np.empty((total, 5))
    boxes[:, 0] = np.where(trim, cx + shift * -sin_mid, cx)
    boxes[:, 1] = np.where(trim, cy + shift * cos_mid, cy)
    boxes[:, 2] = np.where(trim, 0.5 * (hi - lo), half_len)
    boxes[:, 3] = 0.5 * (d_out - d_in)
    boxes[:, 4] = mid
    return boxes, counts


def wall_slots(spec: MazeSpec, max_gates: int) -> tuple[int, ...]:
    """Per wall of ``spec``, the most pieces any gates on it can need with up to ``max_gates`` gates.

    :func:`_arc_boxes` covers an arc of span ``a`` with one piece, or with two end pieces (``delta_end``
    each) and ``ceil((a - 2 delta_end) / delta_max)`` interior ones: at most
    ``3 + (a - 2 delta_end) / delta_max`` either way. A wall with ``G`` gates has ``G`` arcs whose
    spans add up to ``2π`` less the gates, each wider than the marble's chord ``w``, so it needs at
    most ``3 G + (2π - G (w + 2 delta_end)) / delta_max`` pieces; the slots are the largest over
    ``G = 1 … max_gates``.
    """
    slots = []
    for wall in spec.walls:
        delta_max = 2 * math.acos(1.0 / (1.0 + 2 * spec.arc_tolerance / wall.outer_radius))
        delta_end = min(delta_max, 2 * math.atan(2 * spec.arc_tolerance / wall.thickness))
        chord = 2 * math.asin(min(1.0, spec.marble_radius / wall.inner_radius))
        slots.append(
            max(
                math.floor(3 * gates + (2 * math.pi - gates * (chord + 2 * delta_end)) / delta_max)
                for gates in range(1, max_gates + 1)
            )
        )
    return tuple(slots)


def _parked_geom(name: str) -> str:
    """The MJCF geom of a wall slot the maze does not use (see :data:`PARKED_Z`)."""
    size = PARKED_HALF_SIZE
    return f'<geom name="{name}" class="wall" pos="0 0 {PARKED_Z:.9g}" size="{size:.9g} {size:.9g} {size:.9g}"/>'


def slotted_boxes(spec: MazeSpec, slots: tuple[int, ...]) -> list[list[Box]]:
    """Each wall's pieces, refused if they do not fit in its slot count."""
    boxes = wall_boxes(spec)
    check_slot_counts([len(pieces) for pieces in boxes], slots)
    return boxes


def check_slot_counts(counts: list[int], slots: tuple[int, ...]) -> None:
    """Refuse walls' piece ``counts`` that do not fit in the model's ``slots`` (one count per wall)."""
    if len(slots) != len(counts):
        raise ValueError(f"wall_slots has {len(slots)} counts for a maze of {len(counts)} walls: give one per wall")
    for k, (pieces, count) in enumerate(zip(counts, slots, strict=True)):
        if pieces > count:
            raise ValueError(
                f"walls[{k}] of the new maze needs {pieces} pieces, more than the {count} slots of the "
                "model: build it with wall_slots from mjcf.wall_slots(spec, max_gates) (the most gates a wall has)"
            )


MUJOCO_MIN_FRICTION = 1e-5  # mjMINMU: MuJoCo raises smaller friction coefficients to this


def contact_condim(friction: Friction) -> int:
    """Contact dimensionality for a friction setting.

    MuJoCo raises any friction coefficient below ``mjMINMU`` (1e-5) to 1e-5, so MERL's rolling
    friction of 1e-6 m would silently become ten times larger: on a 5° tilt that alone slows the
    marble by 2%. Friction terms below that floor are therefore left out: ``condim=3`` (sliding
    friction only, which still makes the marble roll without slipping), 4 (plus torsional) when
    only the spin coefficient reaches the floor, 6 (plus rolling) when the rolling one does.
    """
    if friction.roll >= MUJOCO_MIN_FRICTION:
        return 6
    if friction.spin >= MUJOCO_MIN_FRICTION:
        return 4
    return 3


def hinged_board_mjcf(board_geoms: list[str]) -> str:
    """The ``<body>`` elements of the board on two nested hinges (``tilt_x`` about the world x axis,
    then ``tilt_y`` about the board's y axis), carrying ``board_geoms``: what every puzzle's board is
    mounted on (:mod:`bimgame.sim.physics` describes the model)."""
    board_inertia = f"{BOARD_INERTIA[0]} {BOARD_INERTIA[1]} {BOARD_INERTIA[2]}"
    geoms = "\n        ".join(board_geoms)
    return f"""<body name="gimbal">
      <joint name="tilt_x" type="hinge" axis="1 0 0"/>
      <inertial pos="0 0 0" mass="0.001" diaginertia="{GIMBAL_INERTIA} {GIMBAL_INERTIA} {GIMBAL_INERTIA}"/>
      <body name="board">
        <joint name="tilt_y" type="hinge" axis="0 1 0"/>
        <inertial pos="0 0 0" mass="{BOARD_MASS}" diaginertia="{board_inertia}"/>
        {geoms}
      </body>
    </body>"""


def servo_mjcf(max_tilt: float) -> str:
    """The ``<actuator>`` block of the two hinges: per axis an integrator position servo (its
    activation is the target tilt, limited to ``±max_tilt``) and a velocity servo with the same
    control as feed-forward, critically damped at :data:`SERVO_OMEGA` for the inertia about that hinge."""
    lines = []
    for axis, inertia in (("x", BOARD_INERTIA[0] + GIMBAL_INERTIA), ("y", BOARD_INERTIA[1])):
        kp, kv = inertia * SERVO_OMEGA**2, 2 * inertia * SERVO_OMEGA
        lines.append(
            f'<general name="servo_{axis}" joint="tilt_{axis}" dyntype="integrator" gaintype="fixed" '
            f'gainprm="{kp:.9g}" biastype="affine" biasprm="0 {-kp:.9g} 0" actlimited="true" '
            f'actrange="{-max_tilt:.12g} {max_tilt:.12g}"/>'
        )
        lines.append(f'<velocity name="rate_{axis}" joint="tilt_{axis}" kv="{kv:.9g}"/>')
    return "<actuator>\n    " + "\n    ".join(lines) + "\n  </actuator>"


def build_mjcf(
    spec: MazeSpec, n_marbles: int = 1, physics_hz: float = PHYSICS_HZ, wall_slots: tuple[int, ...] | None = None
) -> str:
    """MJCF text of the maze with ``n_marbles`` marbles (placed at the origin; see
    :meth:`MazeSim.reset`).

    ``wall_slots`` (one count per wall; None: exactly the pieces ``spec`` needs) gives every wall a
    fixed number of pieces, named ``wall{k}_s{i}``: ``spec``'s pieces first, the rest parked at
    :data:`PARKED_Z`, so that :meth:`MazeSim.set_walls` can switch the model to another maze with
    the same walls' radii and other gates without building it again. Their numbers are written
    exactly (``repr``), so that :meth:`MazeSim.set_walls` writes the same values without formatting
    each one; models without slots keep 9 significant digits (their trajectories stay as they were)."""
    if not (isinstance(n_marbles, int) and n_marbles >= 1):
        raise ValueError(f"n_marbles must be an integer >= 1, got {n_marbles!r}")
    h = spec.wall_height
    f = spec.friction
    walls = []
    if wall_slots is None:
        arcs = [(w.inner_radius, w.outer_radius, w.solid_arcs(), f"wall{k}") for k, w in enumerate(spec.walls)]
    else:
        arcs = []
        for k, boxes in enumerate(slotted_boxes(spec, wall_slots)):
            walls += [_box_geom(f"wall{k}_s{i}", box, h, exact=True) for i, box in enumerate(boxes)]
            walls += [_parked_geom(f"wall{k}_s{i}") for i in range(len(boxes), wall_slots[k])]
    arcs.append((spec.rim_radius, spec.rim_radius + spec.rim_thickness, [(-math.pi, math.pi)], "rim"))
    for inner, outer, solid, name in arcs:
        for j, (a0, a1) in enumerate(solid):
            for i, box in enumerate(_arc_boxes(inner, outer, a0, a1, spec.arc_tolerance)):
                walls.append(_box_geom(f"{name}_{j}_{i}", box, h))
    half = spec.rim_radius + spec.rim_thickness
    floor = (
        f'<geom name="floor" type="box" size="{half:.9g} {half:.9g} {FLOOR_THICKNESS / 2:.9g}" '
        f'pos="0 0 {-FLOOR_THICKNESS / 2:.9g}" contype="0" conaffinity="0" rgba="0.2 0.3 0.25 1"/>'
    )
    board_geoms = ["floor"] + [w.split('"')[1] for w in walls]
    pair_attrs = (
        f'condim="{contact_condim(spec.friction)}" '
        f'friction="{f.slide:.9g} {f.slide:.9g} {f.spin:.9g} {f.roll:.9g} {f.roll:.9g}" '
        f'solref="{CONTACT_SOLREF}" solimp="{CONTACT_SOLIMP}"'
    )
    pairs = [f'<pair geom1="marble{i}" geom2="{g}" {pair_attrs}/>' for i in range(n_marbles) for g in board_geoms]
    pairs += [
        f'<pair geom1="marble{i}" geom2="marble{j}" {pair_attrs}/>'
        for i in range(n_marbles)
        for j in range(i + 1, n_marbles)
    ]
    marbles = []
    for i in range(n_marbles):
        marbles.append(
            f'<body name="marble{i}" pos="0 0 {spec.marble_radius:.9g}">'
            f'<joint name="marble{i}" type="free" frictionloss="{f.static:.9g}" '
            f'solimpfriction="{STATIC_FRICTION_SOLIMP}"/>'
            f'<geom name="marble{i}" class="marble"/></body>'
        )
    return f"""<mujoco model="bimgame">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{1.0 / physics_hz:.12g}" integrator="implicitfast" cone="elliptic"/>
  <visual><global offwidth="640" offheight="640"/></visual>
  <default>
    <default class="wall">
      <geom type="box" contype="0" conaffinity="0" rgba="0.55 0.55 0.6 1"/>
    </default>
    <default class="marble">
      <geom type="sphere" size="{spec.marble_radius:.9g}" mass="{spec.marble_mass:.9g}" contype="0"
            conaffinity="0" rgba="0.85 0.85 0.9 1"/>
    </default>
  </default>
  <worldbody>
    <light pos="0 0 0.6" dir="0 0 -1" directional="true"/>
    {hinged_board_mjcf([floor, *walls])}
    {"".join(marbles)}
  </worldbody>
  <contact>
    {chr(10).join("    " + p for p in pairs)}
  </contact>
  {servo_mjcf(spec.max_tilt)}
</mujoco>
"""
