"""Numbered random mazes split into training and held-out test mazes (Procgen's levels, for mazes).

Maze number ``i`` of a split is a pure function of ``(split, i, base board, gate rules)``: its
generator is seeded with ``(MAZE_SEED_SALT, split, i, attempt)``. Every maze belongs to one
*partition* by its :func:`~bimgame.sim.generate.maze_hash`: one hash in :data:`TEST_SHARE_DENOMINATOR`
is a test maze, every other one a training maze. A split's maze ``i`` is the first draw
(``attempt`` 0, 1, …) that lands in the split's partition. So no test maze's hash occurs in any
training set — however many training mazes are used, unlimited included — even though both splits
draw from the same distribution (the partition is by hash, not by anything the mazes look like).

A :class:`MazeSet` is what an env draws its episodes' mazes from: ``num_mazes`` mazes from
``start_maze`` on (``num_mazes=0``: unlimited, a fresh maze number per episode, as Procgen's
``num_levels=0``).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from bimgame.sim.generate import GateRules, maze_hash, random_maze
from bimgame.sim.maze import MazeSpec
from bimgame.util.settings import is_integer

__all__ = ["MAZE_SPLITS", "MazeSet", "maze_number", "is_test_hash", "UNLIMITED_MAZE_NUMBERS"]

MAZE_SPLITS = ("train", "test")
MAZE_SEED_SALT = 0xB1_4A_2E
#: One maze hash in this many belongs to the test partition.
TEST_SHARE_DENOMINATOR = 10
#: Unlimited sets draw maze numbers below this (2³¹: numbers never repeat in practice).
UNLIMITED_MAZE_NUMBERS = 2**31
#: Maze numbers kept built (spec, geodesic tables) per process: a training set of up to this size
#: is generated once; larger ones and unlimited sets regenerate evicted mazes (≈ 0.1–0.2 ms each).
CACHE_SIZE = 4096


def is_test_hash(digest: str) -> bool:
    """Whether a maze with this :func:`maze_hash` belongs to the held-out test partition."""
    return int(digest[:15], 16) % TEST_SHARE_DENOMINATOR == 0


def _check_split(split: str) -> None:
    if split not in MAZE_SPLITS:
        raise ValueError(f"unknown maze split {split!r}; allowed: {', '.join(MAZE_SPLITS)}")


@functools.lru_cache(maxsize=CACHE_SIZE)
def maze_number(
    index: int, split: str = "train", base: MazeSpec | None = None, rules: GateRules | None = None
) -> MazeSpec:
    """Maze ``index`` (≥ 0) of ``split`` on ``base``'s board (default MERL's) under ``rules``."""
    _check_split(split)
    if not (is_integer(index) and index >= 0):
        raise ValueError(f"maze index must be an integer >= 0, got {index!r}")
    split_id = MAZE_SPLITS.index(split)
    attempt = 0
    while True:
        rng = np.random.default_rng([MAZE_SEED_SALT, split_id, int(index), attempt])
        spec = random_maze(rng, base, rules)
        if is_test_hash(maze_hash(spec)) == (split == "test"):
            return spec
        attempt += 1


@dataclasses.dataclass(frozen=True)
class MazeSet:
    """The mazes an env's episodes are drawn from: ``num_mazes`` numbers of ``split`` from
    ``start_maze`` on, each episode's drawn uniformly; ``num_mazes=0`` draws any number (unlimited)."""

    num_mazes: int = 0
    """How many mazes (0: unlimited)."""
    start_maze: int = 0
    """The first maze number."""
    split: str = "train"
    """``train`` or ``test`` (the held-out partition)."""
    rules: GateRules = dataclasses.field(default_factory=GateRules)
    """How the mazes' gates are drawn."""

    def __post_init__(self) -> None:
        _check_split(self.split)
        if not (is_integer(self.num_mazes) and self.num_mazes >= 0):
            raise ValueError(f"num_mazes must be an integer >= 0 (0: unlimited), got {self.num_mazes!r}")
        if not (is_integer(self.start_maze) and 0 <= self.start_maze < UNLIMITED_MAZE_NUMBERS):
            raise ValueError(
                f"start_maze must be an integer in 0..{UNLIMITED_MAZE_NUMBERS - 1}, got {self.start_maze!r}"
            )
        if self.num_mazes == 0 and self.start_maze != 0:
            raise ValueError(f"start_maze {self.start_maze} with num_mazes=0: an unlimited set starts at 0")
        self.rules.check()

    def draw(self, rng: np.random.Generator) -> int:
        """One episode's maze number, drawn from ``rng``."""
        if self.num_mazes == 0:
            return int(rng.integers(UNLIMITED_MAZE_NUMBERS))
        return self.start_maze + int(rng.integers(self.num_mazes))

    def maze(self, number: int, base: MazeSpec | None = None) -> MazeSpec:
        """The maze of ``number`` on ``base``'s board."""
        return maze_number(number, self.split, base, self.rules)

    def numbers(self) -> range:
        """Every maze number of a finite set (raises for an unlimited one)."""
        if self.num_mazes == 0:
            raise ValueError("an unlimited maze set (num_mazes=0) has no finite list of mazes")
        return range(self.start_maze, self.start_maze + self.num_mazes)
