"""Where DAgger's rollouts start on the labyrinth (:attr:`DAggerConfig.demo_start_share`).

From the layout's start, the learner's rollouts get only as far as it can carry the marble: on the
hard layout ≈ 45 cm of the 1.95 m path after 20 iterations, so the expert labels the learner's
mistakes there and nowhere after; the rest of the path is known only from the expert's own
demonstrations, in states the learner does not reach the way the expert did. Starting a share of
the rollouts in the expert's own states along the whole path (the physics states of the successful
episodes of ``expert_data``: the marble in motion, the board tilted) lets the expert label what the
learner does everywhere on the path. The states are those of
:class:`~bimgame.learn.path_starts.DemoPathStarts` (the states the env's progress rule places where
the expert's run was), drawn uniformly, with no stages: DAgger needs coverage, not a curriculum.
``demo_start_window`` keeps only the states whose progress lies in a part of the path: coverage where
the learner fails.
"""

from __future__ import annotations

import numpy as np

from bimgame.learn.dagger.settings import DAggerConfig
from bimgame.learn.path_starts import DemoPathStarts

__all__ = ["demo_start_states", "draw_demo_starts"]


def demo_start_states(config: DAggerConfig) -> np.ndarray | None:
    """The physics states (K, S) DAgger's rollouts may start from: those of the successful episodes
    of ``config.expert_data`` (verified, of the run's task) whose progress lies within
    ``config.demo_start_window``; None when ``demo_start_share`` is 0."""
    if not config.demo_start_share:
        return None
    assert config.expert_data is not None  # DAggerConfig refuses a share without it
    starts = DemoPathStarts.from_dataset(config.expert_data, config.learner.task)
    fractions = starts.path_fractions
    low, high = config.demo_start_window
    inside = (fractions >= low) & (fractions <= high)
    if not inside.any():
        raise ValueError(
            f"demo_start_window {low:g}–{high:g}: none of the {len(fractions)} expert states in "
            f"{config.expert_data} lies there (their progress spans {fractions.min():.1%}–{fractions.max():.1%} "
            "of the path); widen the window"
        )
    return starts.states[inside]


def draw_demo_starts(
    states: np.ndarray | None, share: float, count: int, rng: np.random.Generator
) -> list[np.ndarray | None]:
    """The start of each of ``count`` rollouts: the first ``share · count`` (rounded half up) a state of
    ``states`` drawn uniformly by ``rng``, the others None (the task's own start)."""
    chosen = int(np.floor(share * count + 0.5))
    if not chosen:
        return [None] * count
    if states is None or not len(states):
        raise ValueError(f"demo_start_share {share} starts {chosen} of {count} rollouts from no states")
    picks = rng.integers(len(states), size=chosen)
    return [states[int(k)].copy() for k in picks] + [None] * (count - chosen)
