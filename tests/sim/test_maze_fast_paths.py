"""The per-maze fast paths (a new maze per episode) against the straightforward computations they
replace, bit for bit, over many maze numbers: angle wrapping, gates' tests, wall pieces and the model
``MazeSim.set_walls`` writes, gate-to-goal distances, the maze encoding and the redrawn background.

The ``_reference_*`` functions are the plain versions (a loop per gate, per arc, per pair of gates)
that the fast paths must reproduce exactly; the golden digest pins the mazes themselves.
"""

from __future__ import annotations

import copy
import hashlib
import math

import numpy as np
import pytest

from bimgame.envs.mazes import MAZE_ENCODING_ANGLES, maze_encoding
from bimgame.sim.generate import GateRules, maze_hash
from bimgame.sim.geodesic import annulus_path_length, gate_distances, wrap_angle, wrap_angle_one
from bimgame.sim.maze import Gate, MazeSpec, Wall
from bimgame.sim.maze_rows import MazeRows
from bimgame.sim.maze_sets import is_test_hash, maze_number
from bimgame.sim.mjcf import PARKED_HALF_SIZE, PARKED_Z, _arc_boxes, wall_box_arrays, wall_boxes, wall_slots
from bimgame.sim.physics import MazeSim
from bimgame.sim.render import MazeRenderer
from bimgame.sim.render_rings import GateSamples, open_samples

BASE = MazeSpec.merl()
MANY_GATES = GateRules(min_gates=1, max_gates=8)
#: Mazes compared: train and test numbers under the default rules and under up to 8 gates a wall.
MAZES = [maze_number(i, split) for split in ("train", "test") for i in range(150)] + [
    maze_number(i, "train", None, MANY_GATES) for i in range(100)
]
MODEL_FIELDS = ("geom_pos", "geom_quat", "geom_size", "geom_rbound", "geom_aabb", "geom_sameframe")


def _same_bits(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _reference_wrap(angle):
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def _reference_in_gate(wall: Wall, angle) -> np.ndarray:
    angle = np.asarray(angle, dtype=float)
    inside = np.zeros(angle.shape, dtype=bool)
    for gate in wall.gates:
        inside |= np.abs(_reference_wrap(angle - gate.angle)) <= gate.width / 2
    return inside


def _reference_solid_arcs(wall: Wall) -> list[tuple[float, float]]:
    gates = sorted(wall.gates, key=lambda g: float(_reference_wrap(g.angle)))
    arcs = []
    for i, gate in enumerate(gates):
        nxt = gates[(i + 1) % len(gates)]
        start = float(_reference_wrap(gate.angle + gate.width / 2))
        end = float(_reference_wrap(nxt.angle - nxt.width / 2))
        while end <= start:
            end += 2 * math.pi
        arcs.append((start, end))
    return arcs


def _reference_wall_boxes(spec: MazeSpec) -> list[list[tuple]]:
    return [
        [
            box
            for a0, a1 in _reference_solid_arcs(wall)
            for box in _arc_boxes(wall.inner_radius, wall.outer_radius, a0, a1, spec.arc_tolerance)
        ]
        for wall in spec.walls
    ]


def _reference_set_walls(sim: MazeSim, spec: MazeSpec, m) -> None:
    """``MazeSim.set_walls`` as a loop over walls, pieces from :func:`_reference_wall_boxes`."""
    for ids, boxes in zip(sim._slot_ids(), _reference_wall_boxes(spec), strict=True):
        cx, cy, half_length, half_depth, yaw = np.array(boxes, dtype=np.float64).reshape(-1, 5).T
        z = np.full(len(boxes), spec.wall_height / 2)
        sizes = np.stack([half_depth, half_length, z], axis=1)
        zero = np.zeros(len(boxes))
        quat = np.stack([np.cos(yaw / 2), zero, zero, np.sin(yaw / 2)], axis=1)
        used, parked = ids[: len(boxes)], ids[len(boxes) :]
        m.geom_pos[used], m.geom_quat[used], m.geom_size[used] = np.stack([cx, cy, z], axis=1), quat, sizes
        m.geom_rbound[used] = np.linalg.norm(sizes, axis=1)
        m.geom_aabb[used, :3], m.geom_aabb[used, 3:] = 0.0, sizes
        m.geom_pos[parked] = (0.0, 0.0, PARKED_Z)
        m.geom_quat[parked] = (1.0, 0.0, 0.0, 0.0)
        m.geom_size[parked] = PARKED_HALF_SIZE
        m.geom_rbound[parked] = math.sqrt(3) * PARKED_HALF_SIZE
        m.geom_aabb[parked] = (0.0, 0.0, 0.0, PARKED_HALF_SIZE, PARKED_HALF_SIZE, PARKED_HALF_SIZE)


def _reference_gate_distances(portals: list[dict], to_channel: int) -> list[np.ndarray]:
    distances: list[np.ndarray] = []
    for k, portal in enumerate(portals):
        through = portal["outer_radius"] - portal["inner_radius"]
        if k < to_channel:
            distances.append(np.full(len(portal["angles"]), np.inf))
            continue
        if k == to_channel:
            rest = portal["inner_radius"] if k == 0 else 0.0
            distances.append(np.full(len(portal["angles"]), through + rest))
            continue
        inner = portals[k - 1]
        per_gate = []
        for angle in portal["angles"]:
            best = min(
                float(
                    annulus_path_length(
                        portal["inner_radius"], angle, inner["outer_radius"], inner_angle, inner["outer_radius"]
                    )
                )
                + d
                for inner_angle, d in zip(inner["angles"], distances[k - 1], strict=True)
            )
            per_gate.append(through + best)
        distances.append(np.array(per_gate))
    return distances


def _reference_encoding(spec: MazeSpec) -> np.ndarray:
    width = 2 * math.pi / MAZE_ENCODING_ANGLES
    offsets = (np.arange(16) + 0.5) / 16 * width
    angles = -math.pi + np.arange(MAZE_ENCODING_ANGLES)[:, None] * width + offsets[None, :]
    return np.concatenate([_reference_in_gate(wall, angles).mean(axis=1) for wall in spec.walls]).astype(np.float32)


def test_mazes_unchanged():
    """Maze k of each split is the MazeSpec, hash and partition it always was (digest of the specs'
    reprs and hashes recorded before the fast paths; it depends on libm's asin, glibc x86-64 here)."""
    digest = hashlib.sha256()
    for split in ("train", "test"):
        for i in range(300):
            spec = maze_number(i, split)
            assert is_test_hash(maze_hash(spec)) == (split == "test")
            digest.update(repr(spec).encode())
            digest.update(maze_hash(spec).encode())
    assert digest.hexdigest() == "c081e049e1a2f0f799bda772987566702848685cc3df6d4e05736b7f9c9ed481"


def test_wrap_angle_fast_path_matches_remainder():
    rng = np.random.default_rng(0)
    edges = [0.0, -0.0, 1e-300, -1e-300, 1e-17, -1e-17, math.pi, -math.pi, 2 * math.pi, -2 * math.pi, 3 * math.pi]
    edges += [np.nextafter(v, d) for v in (math.pi, -math.pi, 3 * math.pi, -3 * math.pi) for d in (-10.0, 10.0)]
    near = [c + k * 1e-16 * abs(c) for c in (math.pi, -math.pi, 3 * math.pi, -3 * math.pi) for k in range(-300, 300)]
    for values in (rng.uniform(-3 * math.pi, 3 * math.pi, 100_000), np.array(edges * 10), np.array(near)):
        assert _same_bits(wrap_angle(values), _reference_wrap(values))
        assert all(_same_bits(wrap_angle_one(v), float(_reference_wrap(v))) for v in values[:2000].tolist())
    wide = rng.uniform(-100, 100, 1000)  # beyond the shift's range: the remainder
    assert _same_bits(wrap_angle(wide), _reference_wrap(wide))
    odd = np.array([np.inf, -np.inf, np.nan] + [0.5] * 100)
    with np.errstate(invalid="ignore"):
        assert _same_bits(np.isnan(wrap_angle(odd)), np.isnan(_reference_wrap(odd)))


def test_in_gate_and_solid_arcs_match_reference():
    rng = np.random.default_rng(1)
    small, large = rng.uniform(-4, 4, (32, 16)), rng.uniform(-4, 4, 40_000)
    for spec in MAZES[::5]:
        for wall in spec.walls:
            assert wall.solid_arcs() == _reference_solid_arcs(wall)
            for angles in (small, large, 0.3):
                assert _same_bits(wall.in_gate(angles), _reference_in_gate(wall, angles))


@pytest.mark.parametrize("spec", MAZES[::3])
def test_wall_pieces_match_arc_boxes(spec):
    reference = _reference_wall_boxes(spec)
    assert wall_boxes(spec) == reference
    for pieces, boxes in zip(wall_box_arrays(spec), reference, strict=True):
        assert _same_bits(pieces, np.array(boxes, dtype=np.float64).reshape(-1, 5))


def test_set_walls_writes_the_reference_model():
    """set_walls over many mazes, in place and on a copy, against the loop over walls and against a
    model built from each maze (wall_slots as the env's)."""
    for rules in (GateRules(), MANY_GATES):
        slots = wall_slots(BASE, rules.max_gates)
        sim = MazeSim(BASE, wall_slots=slots)
        model = copy.copy(sim.model)
        mazes = [m for m in MAZES if max(len(w.gates) for w in m.walls) <= rules.max_gates]
        for i, spec in enumerate(mazes):
            reference = copy.copy(sim.model)
            _reference_set_walls(sim, spec, reference)
            sim.set_walls(spec, model)
            sim.set_walls(spec)
            for field in MODEL_FIELDS:
                assert _same_bits(getattr(model, field), getattr(reference, field)), (i, field)
                assert _same_bits(getattr(sim.model, field), getattr(reference, field)), (i, field)
            if i % 40 == 0:  # and a model compiled from the maze (whose bounding radii MuJoCo rounds its own way)
                built = MazeSim(spec, wall_slots=slots).model
                for field in ("geom_pos", "geom_quat", "geom_size", "geom_aabb"):
                    assert _same_bits(getattr(model, field), getattr(built, field)), (i, field)


def test_gate_distances_match_the_loop_over_pairs():
    for spec in MAZES:
        portals = spec._gate_portals()
        for to_channel in range(len(spec.walls)):
            fast, reference = gate_distances(portals, to_channel), _reference_gate_distances(portals, to_channel)
            assert all(_same_bits(a, b) for a, b in zip(fast, reference, strict=True))


def test_maze_encoding_matches_reference():
    for spec in MAZES:
        assert _same_bits(maze_encoding(spec), _reference_encoding(spec))


def test_open_samples_on_edge_gates():
    """Gates across ±π, touching, far outside [-π, π), as wide as half the circle: the samples
    tested near each gate are exactly in_gate's, samples on a gate's edge included."""
    rng = np.random.default_rng(2)
    edge_angles = [math.pi, -math.pi, 0.0, 0.5 - 0.05, 0.5 + 0.05, 0.6 + 0.05, 3.0 + 0.4, 1.0]
    samples = np.sort(np.concatenate([rng.uniform(-math.pi, math.pi, 20_000), edge_angles]))
    walls = [
        Wall(0.04, 0.045, (Gate(math.pi - 0.01, 0.1),)),
        Wall(0.04, 0.045, (Gate(-math.pi, 0.2), Gate(1.0, 0.3))),
        Wall(0.04, 0.045, (Gate(0.5, 0.1), Gate(0.6, 0.1))),  # touching at 0.55
        Wall(0.04, 0.045, (Gate(3.0 + 4 * math.pi, 0.8),)),  # far out: every sample is tested
        Wall(0.04, 0.045, (Gate(3.0 + 2 * math.pi, 0.8), Gate(-1.0, 3.0))),
    ]
    for wall in walls:
        assert _same_bits(open_samples(wall, samples), np.flatnonzero(_reference_in_gate(wall, samples)))
    together = GateSamples.of([samples, samples[::3], samples] * 2).open_mask(tuple(walls) + (walls[0],))
    expected = [
        _reference_in_gate(w, a) for w, a in zip(walls + walls[:1], [samples, samples[::3], samples] * 2, strict=True)
    ]
    assert _same_bits(together, np.concatenate(expected))


@pytest.mark.parametrize("size", [16, 64, 84, 97])
def test_redrawn_background_matches_a_full_raster(size):
    board = MazeRenderer(BASE, size)
    mazes = MAZES[:: max(1, len(MAZES) // 12)]
    derived = board.for_maze(mazes[0])
    for spec in mazes:
        full = MazeRenderer(spec, size)
        assert _same_bits(board.for_maze(spec).background, full.background)
        assert _same_bits(derived.for_maze(spec).background, full.background)  # from another maze's renderer


def test_maze_rows_from_a_new_maze_match_its_tables():
    """MazeRows.set_row on a maze without geodesic tables yet (the gate distances only) fills the
    row as from the maze's tables."""
    fresh, cached = MazeRows(BASE, 2, 8), MazeRows(BASE, 2, 8)
    for index in range(100):
        new = maze_number.__wrapped__(index, "train", None, MANY_GATES if index % 2 else None)
        fresh.set_row(index % 2, new)
        new._geodesic_tables(0)
        cached.set_row(index % 2, new)
        for name in ("_gate_angle", "_gate_dist", "_gate_half_width"):
            assert _same_bits(getattr(fresh, name), getattr(cached, name)), (index, name)
