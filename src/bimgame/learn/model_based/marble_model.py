"""The planner's model of the labyrinth made of a fitted :class:`~bimgame.learn.model_based.marble_law.MarbleLaw`
and the layout's :class:`~bimgame.learn.model_based.contacts.WallContacts`: a
:class:`~bimgame.expert.planning_model.PlanningModel`, so the expert's MPC plans through it unchanged.

Its state (8,): the marble state (x, y, vx, vy, tilt x, tilt y) and the last commanded tilt change
(rad, 2), which the law reads as the servos' lag.
"""

from __future__ import annotations

import numpy as np

from bimgame.learn.model_based.contacts import WallContacts
from bimgame.learn.model_based.marble_law import MarbleLaw
from bimgame.learn.model_based.transitions import STATE_SIZE

__all__ = ["MarbleModel", "MODEL_STATE_SIZE"]

#: The model's state: the marble state and the last tilt change.
MODEL_STATE_SIZE = STATE_SIZE + 2


class MarbleModel:
    """Roll tilt-change sequences out through ``law``, resolving ``contacts`` after every step."""

    state_size = MODEL_STATE_SIZE

    def __init__(self, law: MarbleLaw, contacts: WallContacts):
        if not isinstance(law, MarbleLaw):
            raise TypeError(f"law must be a MarbleLaw, got {type(law).__name__}")
        if not isinstance(contacts, WallContacts):
            raise TypeError(f"contacts must be WallContacts, got {type(contacts).__name__}")
        self.law, self.contacts = law, contacts

    def rollout(self, state: np.ndarray, controls: np.ndarray, nthread: int = 1) -> np.ndarray:
        """(K, H, 8) states after each of the (K, H, 2) tilt changes (rad) from ``state`` (8,);
        ``nthread`` is accepted for the protocol and unused (numpy on the calling thread)."""
        start = np.asarray(state, dtype=np.float64)
        changes = np.asarray(controls, dtype=np.float64)
        if start.shape != (MODEL_STATE_SIZE,) or not np.all(np.isfinite(start)):
            raise ValueError(
                f"state must be {MODEL_STATE_SIZE} finite values (marble state, last tilt change), got {start.shape}"
            )
        if changes.ndim != 3 or changes.shape[-1] != 2 or not np.all(np.isfinite(changes)):
            raise ValueError(f"controls must be finite tilt changes (rad) of shape (K, H, 2), got {changes.shape}")
        k, horizon = changes.shape[:2]
        current = np.repeat(start[None, :STATE_SIZE], k, axis=0)
        previous = np.repeat(start[None, STATE_SIZE:], k, axis=0)
        out = np.empty((k, horizon, MODEL_STATE_SIZE))
        for t in range(horizon):
            current = self.law.step(current, changes[:, t], previous)
            current[:, 0:2], current[:, 2:4] = self.contacts.resolve(current[:, 0:2], current[:, 2:4])
            previous = changes[:, t]
            out[:, t, :STATE_SIZE], out[:, t, STATE_SIZE:] = current, previous
        return out

    def marble_xy_of(self, states: np.ndarray) -> np.ndarray:
        """The marble's (x, y) (m) of model states (..., 8)."""
        return np.asarray(states)[..., 0:2]

    def close(self) -> None:
        """Nothing to free (the protocol's)."""
