"""Random mazes: valid, solvable, reproducible, named up to a rotation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bimgame.sim.generate import GateRules, maze_hash, random_maze, rotate_maze
from bimgame.sim.maze import MazeSpec, MazeSpecError


def test_random_mazes_keep_the_board_and_draw_1_to_4_gates_a_marble_fits_through():
    base = MazeSpec.merl()
    counts = set()
    for seed in range(200):
        maze = random_maze(np.random.default_rng(seed))
        assert [(w.inner_radius, w.outer_radius) for w in maze.walls] == [
            (w.inner_radius, w.outer_radius) for w in base.walls
        ]
        assert (maze.rim_radius, maze.marble_radius, maze.friction) == (
            base.rim_radius,
            base.marble_radius,
            base.friction,
        )
        for wall in maze.walls:
            counts.add(len(wall.gates))
            for gate in wall.gates:
                chord = 2 * wall.inner_radius * math.sin(gate.width / 2)
                clearance = chord - 2 * maze.marble_radius
                assert 0.7e-3 - 1e-12 <= clearance <= 2.0e-3 + 1e-12  # MERL's 0.7–2 mm
            # solid arcs between gates at least min_solid at the inner face
            for start, end in wall.solid_arcs():
                assert (end - start) * wall.inner_radius >= 8e-3 - 1e-9
    assert counts == {1, 2, 3, 4}


def test_same_generator_state_same_maze_and_different_seeds_differ():
    a = random_maze(np.random.default_rng(7))
    b = random_maze(np.random.default_rng(7))
    assert a == b and maze_hash(a) == maze_hash(b)
    hashes = {maze_hash(random_maze(np.random.default_rng(seed))) for seed in range(100)}
    assert len(hashes) == 100


def test_hash_is_the_same_for_a_rotated_maze_and_differs_for_a_changed_one():
    maze = random_maze(np.random.default_rng(3))
    for angle in (0.1, 1.0, -2.5, math.pi):
        assert maze_hash(rotate_maze(maze, angle)) == maze_hash(maze)
    wall = maze.walls[2]
    moved = type(wall)(
        wall.inner_radius,
        wall.outer_radius,
        tuple(type(g)(g.angle + (0.05 if i == 0 else 0.0), g.width) for i, g in enumerate(wall.gates)),
    )
    changed = maze.replace(walls=maze.walls[:2] + (moved,) + maze.walls[3:])
    assert maze_hash(changed) != maze_hash(maze)
    assert maze_hash(maze.replace(marble_mass=0.01)) != maze_hash(maze)
    # MERL's walls 1–3 are symmetric under quarter turns: turning wall 0 alone by 90° is turning the
    # others by -90°, the same maze; by 45° it is another maze.
    merl = MazeSpec.merl()
    for angle, same in ((math.pi / 2, True), (math.pi / 4, False)):
        turned = rotate_maze(merl, angle)
        assert maze_hash(turned) == maze_hash(merl)
        assert (maze_hash(merl.replace(walls=turned.walls[:1] + merl.walls[1:])) == maze_hash(merl)) is same


def test_gate_rules_are_checked_and_too_many_gates_are_dropped():
    with pytest.raises(MazeSpecError, match="max_gates"):
        random_maze(np.random.default_rng(0), rules=GateRules(min_gates=3, max_gates=2))
    with pytest.raises(MazeSpecError, match="margin must be positive"):
        random_maze(np.random.default_rng(0), rules=GateRules(margin=0.0))
    with pytest.raises(TypeError, match="numpy.random.Generator"):
        random_maze(0)  # type: ignore[arg-type]
    # Wall 0 (16 mm) cannot hold 8 gates of ~50° each: fewer are drawn, and the maze is valid.
    maze = random_maze(np.random.default_rng(0), rules=GateRules(min_gates=8, max_gates=8))
    assert 1 <= len(maze.walls[0].gates) < 8
    assert len(maze.walls[3].gates) == 8
