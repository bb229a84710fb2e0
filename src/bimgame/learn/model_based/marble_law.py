"""The marble's one-step law, fitted from experience: the change of its state over one action step
is linear in what drives it.

Features: vx, vy (m/s), tilt x, tilt y (rad), the commanded tilt change and the one before it (rad,
the servo's lag), and 1. Targets: the change of x, y, vx, vy, tilt x, tilt y. Fitted by least
squares on the *free* transitions only — the marble's centre farther than its radius plus
``free_margin`` from every wall at both ends of the step — because a wall contact is not linear;
:class:`~bimgame.learn.model_based.contacts.WallContacts` handles those (see the package notes for
why). Rolling on a tilted floor, the marble's acceleration is (5/7)·g·sin(tilt) for a solid ball:
the law finds the simulator's own coefficient, whatever its contact model makes of it.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from bimgame.learn.model_based.transitions import STATE_SIZE, Transitions
from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.util.files import write_json

__all__ = ["MarbleLaw", "FEATURES", "MIN_FREE_TRANSITIONS"]

#: Columns of the law's input, in order.
FEATURES = ("vx", "vy", "tilt_x", "tilt_y", "change_x", "change_y", "previous_x", "previous_y", "one")
#: Fewest free transitions a fit accepts: a few times the 9 unknowns of each target.
MIN_FREE_TRANSITIONS = 50
#: Format tag of a saved law.
_FORMAT = "bimgame-marble-law-1"


def _features(state: np.ndarray, change: np.ndarray, previous: np.ndarray) -> np.ndarray:
    ones = np.ones((*state.shape[:-1], 1))
    return np.concatenate([state[..., 2:STATE_SIZE], change, previous, ones], axis=-1)


class MarbleLaw:
    """A fitted law: ``coefficients`` (9, 6) map :data:`FEATURES` to the state's change; ``max_tilt``
    (rad) bounds the predicted tilt as the board's servos do. ``r2`` (6,) and ``free_transitions`` say
    how well and from how much it was fitted."""

    def __init__(
        self, coefficients: np.ndarray, max_tilt: float, *, r2: np.ndarray | None = None, free_transitions: int = 0
    ):
        coefficients = np.asarray(coefficients, dtype=np.float64)
        if coefficients.shape != (len(FEATURES), STATE_SIZE) or not np.all(np.isfinite(coefficients)):
            raise ValueError(
                f"coefficients must be finite, of shape ({len(FEATURES)}, {STATE_SIZE}); got {coefficients.shape}"
            )
        if not (isinstance(max_tilt, (int, float)) and math.isfinite(max_tilt) and max_tilt > 0):
            raise ValueError(f"max_tilt must be a positive number (rad), got {max_tilt!r}")
        self.coefficients, self.max_tilt = coefficients, float(max_tilt)
        self.r2 = np.full(STATE_SIZE, np.nan) if r2 is None else np.asarray(r2, dtype=np.float64)
        self.free_transitions = int(free_transitions)

    @classmethod
    def fit(cls, transitions: Transitions, board: LabyrinthSpec, *, free_margin: float = 0.002) -> MarbleLaw:
        """The least-squares law of ``transitions`` on ``board`` (its walls decide which are free).
        ``ValueError`` when fewer than :data:`MIN_FREE_TRANSITIONS` are free."""
        if not (isinstance(free_margin, (int, float)) and math.isfinite(free_margin) and free_margin >= 0):
            raise ValueError(f"free_margin must be a non-negative number (m), got {free_margin!r}")
        state, change, previous, next_state = transitions.arrays()
        reach = board.marble_radius + free_margin
        free = (board.clearance(state[:, :2]) > reach) & (board.clearance(next_state[:, :2]) > reach)
        if free.sum() < MIN_FREE_TRANSITIONS:
            raise ValueError(
                f"{int(free.sum())} of {len(state)} transitions are free of the walls (clearance above the marble's "
                f"radius + {free_margin} m); the law needs at least {MIN_FREE_TRANSITIONS}: explore longer"
            )
        x = _features(state[free], change[free], previous[free])
        y = next_state[free] - state[free]
        coefficients = np.linalg.lstsq(x, y, rcond=None)[0]
        residual = y - x @ coefficients
        spread = y.var(axis=0)
        r2 = 1.0 - residual.var(axis=0) / np.where(spread > 0, spread, np.nan)
        return cls(coefficients, board.max_tilt, r2=r2, free_transitions=int(free.sum()))

    def step(self, state: np.ndarray, change: np.ndarray, previous: np.ndarray) -> np.ndarray:
        """The next states (K, 6) of states (K, 6) under tilt changes (K, 2) after ``previous`` (K, 2)."""
        following = state + _features(state, change, previous) @ self.coefficients
        following[..., 4:6] = np.clip(following[..., 4:6], -self.max_tilt, self.max_tilt)
        return following

    def acceleration_per_tilt(self, control_hz: float) -> float:
        """The marble's acceleration (m/s²) per radian of tilt the law implies, the mean of the two axes'
        magnitudes: comparable with (5/7)·g for a rolling ball on a small tilt."""
        return float(np.mean(np.abs([self.coefficients[3, 2], self.coefficients[2, 3]]))) * control_hz

    def save(self, path: str | Path) -> Path:
        """Write the law as JSON (atomically); :meth:`load` reads it back."""
        return write_json(
            path,
            {
                "format": _FORMAT,
                "features": list(FEATURES),
                "coefficients": self.coefficients.tolist(),
                "max_tilt": self.max_tilt,
                "r2": [None if not math.isfinite(v) else float(v) for v in self.r2],
                "free_transitions": self.free_transitions,
            },
        )

    @classmethod
    def load(cls, path: str | Path) -> MarbleLaw:
        """A law saved by :meth:`save`; ``ValueError`` naming what is wrong with any other file."""
        try:
            values = json.loads(Path(path).read_text())
        except (OSError, ValueError) as error:
            raise ValueError(f"{path} is not a readable JSON marble law ({error})") from None
        if not isinstance(values, dict) or values.get("format") != _FORMAT:
            raise ValueError(f"{path} is not a marble law (format {_FORMAT!r} expected)")
        try:
            r2 = [np.nan if v is None else v for v in values.get("r2", [None] * STATE_SIZE)]
            return cls(
                np.asarray(values["coefficients"], dtype=np.float64),
                values["max_tilt"],
                r2=np.asarray(r2, dtype=np.float64),
                free_transitions=int(values.get("free_transitions", 0)),
            )
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f"{path} is a broken marble law: {error}") from None
