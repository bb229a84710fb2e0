"""The learner's experience on the labyrinth: one row per action step — the marble's observed state
before and after, the commanded tilt change and the one before it — and random exploration to
start it.

A state is the first six values of the labyrinth's ``state`` observation
(:class:`~bimgame.envs.labyrinth_env.LabyrinthEnv`): the marble's board-frame x, y (m), vx, vy (m/s)
and the board's tilt about x and y (rad). Tilt changes are what the env commands per action
(``action * env.tilt_step``, rad), the unit the planner rolls out in.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["STATE_SIZE", "Transitions", "explore", "marble_state"]

#: Values of a marble state (x, y, vx, vy, tilt x, tilt y).
STATE_SIZE = 6
#: Random exploration holds one action for this many steps (inclusive): one step of a random tilt
#: rate barely moves the board, and a held one sends the marble across a passage and into its walls.
HOLD_STEPS = (3, 11)


def marble_state(observation: Any) -> np.ndarray:
    """The marble state (6,) of a labyrinth ``state`` observation; ``ValueError`` for anything else."""
    obs = np.asarray(observation, dtype=np.float64)
    if obs.ndim != 1 or obs.shape[0] < 17 or not np.all(np.isfinite(obs[:STATE_SIZE])):
        raise ValueError(
            "the model-based learner reads the labyrinth's obs_mode 'state' (a vector of 17 or 33 values, "
            f"the marble's x, y, vx, vy and the tilt first), got an observation of shape {obs.shape}"
        )
    return obs[:STATE_SIZE].copy()


class Transitions:
    """A growing table of action steps (:meth:`add`), read as arrays (:meth:`arrays`)."""

    def __init__(self) -> None:
        self._rows: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self._rows)

    def add(
        self, state: np.ndarray, tilt_change: np.ndarray, previous_change: np.ndarray, next_state: np.ndarray
    ) -> None:
        """One step: from ``state`` (6,) the env commanded ``tilt_change`` (2,) rad, after
        ``previous_change`` (2,) the step before (zeros at an episode's start), and reached ``next_state``."""
        row = np.concatenate([state, tilt_change, previous_change, next_state]).astype(np.float64)
        if row.shape != (2 * STATE_SIZE + 4,) or not np.all(np.isfinite(row)):
            raise ValueError(f"a transition is finite states (6,), tilt changes (2,) and (2,): got {row.shape} values")
        self._rows.append(row)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(states (N, 6), tilt changes (N, 2), previous changes (N, 2), next states (N, 6))."""
        table = np.array(self._rows, dtype=np.float64).reshape(-1, 2 * STATE_SIZE + 4)
        s = STATE_SIZE
        return table[:, :s], table[:, s : s + 2], table[:, s + 2 : s + 4], table[:, s + 4 :]


def explore(env: Any, steps: int, rng: np.random.Generator, transitions: Transitions) -> int:
    """Play ``steps`` random action steps on ``env`` (a labyrinth env with continuous actions and
    ``state`` observations), adding each to ``transitions``: each action a random direction and
    magnitude in [-1, 1]², held for :data:`HOLD_STEPS` steps; episodes restart from seeds drawn from
    ``rng`` when they end. Returns the episodes started."""
    inner = env.unwrapped
    obs, _ = env.reset(seed=int(rng.integers(2**31)))
    state, previous, episodes = marble_state(obs), np.zeros(2), 1
    action, held = np.zeros(2), 0
    for _ in range(steps):
        if held == 0:
            action = rng.uniform(-1.0, 1.0, 2) * rng.uniform(0.0, 1.0)
            held = int(rng.integers(HOLD_STEPS[0], HOLD_STEPS[1] + 1))
        held -= 1
        obs, _, terminated, truncated, _ = env.step(action.astype(np.float32))
        change = action * inner.tilt_step
        next_state = marble_state(obs)
        transitions.add(state, change, previous, next_state)
        state, previous = next_state, change
        if terminated or truncated:
            obs, _ = env.reset(seed=int(rng.integers(2**31)))
            state, previous, held, episodes = marble_state(obs), np.zeros(2), 0, episodes + 1
    return episodes
