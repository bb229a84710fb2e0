"""Policies named as ``module:callable`` in the scoring tests."""

from __future__ import annotations

import numpy as np


def always_noop(obs: np.ndarray) -> int:
    """Never tilts the board."""
    return 0


class Counting:
    """Counts its episodes (``reset`` is called at each start) and tilts one way."""

    def __init__(self) -> None:
        self.episodes = 0

    def reset(self) -> None:
        self.episodes += 1

    def __call__(self, obs: np.ndarray) -> int:
        return 1


counting = Counting()
