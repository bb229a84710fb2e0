"""Numbered mazes: deterministic, and the test split never shares a maze with any training set."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.sim.generate import maze_hash
from bimgame.sim.maze_sets import MazeSet, is_test_hash, maze_number


def test_maze_numbers_are_deterministic_and_the_splits_disjoint_by_hash():
    assert maze_number(5) == maze_number.__wrapped__(5)  # the cache returns what a fresh draw gives
    train = {maze_hash(maze_number(i, "train")) for i in range(300)}
    test = {maze_hash(maze_number(i, "test")) for i in range(50)}
    assert len(train) == 300 and len(test) == 50
    assert not train & test
    assert all(is_test_hash(h) for h in test) and not any(is_test_hash(h) for h in train)


def test_maze_set_draws_within_its_numbers_and_refuses_bad_arguments():
    rng = np.random.default_rng(0)
    finite = MazeSet(num_mazes=3, start_maze=10)
    assert {finite.draw(rng) for _ in range(100)} == {10, 11, 12}
    assert list(finite.numbers()) == [10, 11, 12]
    unlimited = MazeSet(num_mazes=0)
    assert len({unlimited.draw(rng) for _ in range(100)}) == 100
    with pytest.raises(ValueError, match="unlimited maze set"):
        unlimited.numbers()
    with pytest.raises(ValueError, match="num_mazes must be an integer >= 0"):
        MazeSet(num_mazes=-1)
    with pytest.raises(ValueError, match="unknown maze split 'val'"):
        MazeSet(split="val")
    with pytest.raises(ValueError, match="an unlimited set starts at 0"):
        MazeSet(num_mazes=0, start_maze=4)
