"""The actions both puzzles take (MERL's maze and the labyrinth): five discrete tilt steps or a
continuous 2-vector, checked and turned into a tilt change (rad) of the board's two axes."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["ACTION_TYPES", "ACTION_MEANINGS", "ACTIONS_HELP", "DISCRETE_TILTS", "action_to_tilt_delta"]

ACTION_TYPES = ("discrete", "continuous")
#: Discrete actions as (sign about x, sign about y) of one tilt step.
DISCRETE_TILTS = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]], dtype=np.float64)
ACTION_MEANINGS = ("noop", "tilt +x", "tilt -x", "tilt +y", "tilt -y")
#: What the discrete actions mean, for error messages.
ACTIONS_HELP = ", ".join(f"{i}={m}" for i, m in enumerate(ACTION_MEANINGS))


def action_to_tilt_delta(action: Any, action_type: str, tilt_step: float) -> np.ndarray:
    """Tilt change (rad, shape (2,)) commanded by one action, ``tilt_step`` per unit (one discrete
    step, or a continuous component of 1); raises ``ValueError`` naming what is allowed."""
    if action_type == "discrete":
        try:
            index = int(action)
            ok = index == action and 0 <= index < 5 and not isinstance(action, (bool, np.bool_))
        except (TypeError, ValueError, OverflowError):
            ok = False
        if not ok:
            raise ValueError(f"invalid action {action!r}: discrete actions are integers 0..4 ({ACTIONS_HELP})")
        return DISCRETE_TILTS[index] * tilt_step
    try:
        array = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError):  # e.g. a string: not a number at all
        array = np.full(0, np.nan)
    if array.shape != (2,) or not np.all(np.isfinite(array)) or np.any(np.abs(array) > 1.0):
        raise ValueError(
            f"invalid action {action!r}: continuous actions are 2 finite numbers in "
            "[-1, 1] (tilt change about x and y, in units of the tilt step)"
        )
    return array * tilt_step
