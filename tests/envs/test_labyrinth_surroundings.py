"""The labyrinth's surroundings (nearest holes, wall distances): exact against a brute-force march,
batched equal to one at a time, in the env's and the vector env's state observations, refused where
they do not apply."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.envs.labyrinth_surroundings import (
    NO_HOLE,
    RAY_RANGE,
    SURROUNDING_HOLES,
    SURROUNDINGS_SIZE,
    WALL_RAYS,
    Surroundings,
)
from bimgame.envs.labyrinth_vector import LabyrinthVectorEnv
from bimgame.sim.labyrinth import LabyrinthSpec

EASY = LabyrinthSpec.layout("easy")


def marched_distance(board: LabyrinthSpec, p: np.ndarray, angle: float, step: float = 2e-5) -> float:
    """Walk from ``p`` along ``angle`` until the centre is inside a wall or past the rim."""
    direction = np.array([np.cos(angle), np.sin(angle)])
    ts = np.arange(0.0, RAY_RANGE, step)
    inside = board.clearance(p + ts[:, None] * direction) <= 0
    return float(ts[np.argmax(inside)]) if inside.any() else RAY_RANGE


def free_points(board: LabyrinthSpec, count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    points = rng.uniform(-0.5, 0.5, (count * 4, 2)) * np.asarray(board.board_size)
    return points[board.clearance(points) > 0][:count]


@pytest.mark.parametrize("layout", ["easy", "hard"])
def test_wall_distances_equal_a_march_along_each_ray(layout):
    board = LabyrinthSpec.layout(layout)
    around = Surroundings(board)
    for p in free_points(board, 12, seed=1):
        distances = around.of(p)[2 * SURROUNDING_HOLES :]
        marched = [marched_distance(board, p, 2 * np.pi * k / WALL_RAYS) for k in range(WALL_RAYS)]
        np.testing.assert_allclose(distances, marched, atol=5e-5)


def test_a_marble_beside_a_wall_reads_the_gap_and_the_rim_stops_rays():
    around = Surroundings(EASY)
    beside = [  # 1 cm left of each wall's left face, where nothing else is nearer
        np.array([x_min - 0.01, (y_min + y_max) / 2]) for x_min, y_min, _, y_max in EASY.walls
    ]
    beside = [p for p in beside if EASY.clearance(p) >= 0.01 - 1e-9]
    assert len(beside) >= 3
    for p in beside:
        assert around.of(p)[2 * SURROUNDING_HOLES] == pytest.approx(0.01)  # ray 0 points along +x
    hx = EASY.board_size[0] / 2
    near_rim = free_points(EASY, 2000, seed=2)
    near_rim = near_rim[near_rim[:, 0] > hx - 0.02]
    for q in near_rim:
        assert around.of(q)[2 * SURROUNDING_HOLES] <= hx - q[0] + 1e-9


def test_holes_are_the_nearest_first_relative_to_the_marble():
    around = Surroundings(EASY)
    holes = np.asarray(EASY.holes)
    for p in free_points(EASY, 20, seed=3):
        offsets = around.of(p)[: 2 * SURROUNDING_HOLES].reshape(SURROUNDING_HOLES, 2)
        expected = holes - p
        expected = expected[np.argsort(np.hypot(*expected.T), kind="stable")][:SURROUNDING_HOLES]
        np.testing.assert_allclose(offsets, expected, atol=1e-6)
        assert np.all(np.diff(np.hypot(*offsets.T)) >= -1e-7)


def test_a_board_with_fewer_holes_reads_no_hole_for_the_missing():
    board = EASY.replace(holes=EASY.holes[:2])
    values = Surroundings(board).of(np.asarray(board.start))
    offsets = values[: 2 * SURROUNDING_HOLES].reshape(SURROUNDING_HOLES, 2)
    assert np.all(offsets[2:] == np.float32(NO_HOLE))
    assert not np.any(offsets[:2] == np.float32(NO_HOLE))


def test_a_batch_equals_one_at_a_time():
    around = Surroundings(EASY)
    points = free_points(EASY, 16, seed=4)
    batch = around.of(points.reshape(4, 4, 2))
    assert batch.shape == (4, 4, SURROUNDINGS_SIZE) and batch.dtype == np.float32
    np.testing.assert_array_equal(batch.reshape(16, -1), np.stack([around.of(p) for p in points]))


def test_the_env_appends_them_to_its_state_and_the_vector_env_matches_single_envs():
    env = LabyrinthEnv("easy", surroundings=True)
    check_env(env, skip_render_check=True)
    plain = LabyrinthEnv("easy")
    obs, _ = env.reset(seed=3)
    assert obs.shape == (17 + SURROUNDINGS_SIZE,) and env.observation_space.contains(obs)
    np.testing.assert_array_equal(obs[:17], plain.reset(seed=3)[0])
    np.testing.assert_allclose(obs[17:], Surroundings(EASY).of(obs[:2].astype(np.float64)), atol=1e-6)
    vector = LabyrinthVectorEnv(3, "easy", surroundings=True)
    singles = [LabyrinthEnv("easy", surroundings=True) for _ in range(3)]
    batch, _ = vector.reset(seed=[0, 1, 2])
    firsts = np.stack([single.reset(seed=i)[0] for i, single in enumerate(singles)])
    np.testing.assert_array_equal(batch, firsts)
    rng, ended, compared = np.random.default_rng(0), [False] * 3, 0
    for _ in range(150):
        actions = rng.uniform(-1, 1, (3, 2)).astype(np.float32)
        batch, *_ = vector.step(actions)
        for i, single in enumerate(singles):
            if ended[i]:
                continue
            obs, _, terminated, _, _ = single.step(actions[i])
            ended[i] = terminated
            if not terminated:
                np.testing.assert_allclose(obs, batch[i], atol=1e-6)
                compared += 1
    assert compared > 100
    assert env.observe_state(env.sim.get_state(), 0.0).shape == obs.shape  # re-rendering keeps them


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"obs_mode": "pixels", "surroundings": True}, "surroundings are part of obs_mode 'state', not 'pixels'"),
        ({"obs_mode": "cyberrunner", "surroundings": True}, "not 'cyberrunner'"),
        ({"surroundings": "yes"}, "surroundings must be True or False, got 'yes'"),
    ],
)
def test_surroundings_are_refused_where_they_do_not_apply(kwargs, message):
    with pytest.raises(ValueError, match=message):
        LabyrinthEnv("easy", **kwargs)
