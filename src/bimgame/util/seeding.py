"""Seeds derived from a run seed."""

from __future__ import annotations

import numpy as np

__all__ = ["episode_seed"]


def episode_seed(run_seed: int, index: int) -> int:
    """Seed of episode ``index`` of a run: derived from the run seed alone, so a dataset does not
    depend on how many workers generated it or in which order."""
    return int(np.random.SeedSequence([int(run_seed), int(index)]).generate_state(1, dtype=np.uint32)[0])
