"""The actions both puzzles take (MERL's maze and the labyrinth): five discrete tilt steps or a
continuous 2-vector, checked and turned into a tilt change (rad) of the board's two axes."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.utils import seeding

from bimgame.util.settings import is_integer

__all__ = [
    "ACTION_TYPES",
    "ACTION_MEANINGS",
    "ACTIONS_HELP",
    "DISCRETE_TILTS",
    "action_to_tilt_delta",
    "actions_to_tilt_deltas",
    "sub_env_generators",
]

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


def actions_to_tilt_deltas(actions: Any, num_envs: int, action_type: str, tilt_step: float) -> np.ndarray:
    """(N, 2) tilt changes (rad) of a vector env's N actions, checked as :func:`action_to_tilt_delta`
    checks one, vectorised (a vector env's step calls it once, not N times)."""
    if action_type == "discrete":
        array = np.asarray(actions)
        valid = (
            array.shape == (num_envs,)
            and np.issubdtype(array.dtype, np.integer)
            and bool(np.all((array >= 0) & (array < 5)))
        )
        if not valid:
            raise ValueError(
                f"invalid actions {actions!r}: discrete actions are {num_envs} integers in 0..4 ({ACTIONS_HELP})"
            )
        return DISCRETE_TILTS[array] * tilt_step
    try:
        array = np.asarray(actions, dtype=np.float64)
    except (TypeError, ValueError):  # e.g. strings: not numbers at all
        array = np.full(0, np.nan)
    if array.shape != (num_envs, 2) or not np.all(np.isfinite(array)) or np.any(np.abs(array) > 1.0):
        raise ValueError(
            f"invalid actions {actions!r}: continuous actions are shape ({num_envs}, 2), finite numbers in "
            "[-1, 1] (tilt change about x and y, in units of the tilt step)"
        )
    return array * tilt_step


def sub_env_generators(seed: Any, num_envs: int, current: list[np.random.Generator]) -> list[np.random.Generator]:
    """The N sub-envs' generators after a vector env's ``reset(seed=...)``: an int gives sub-env i
    ``seed + i`` (as Gymnasium's vector envs seed theirs), a list one seed (or None) per sub-env,
    None fresh entropy at the first reset; a sub-env without a seed keeps ``current``'s generator."""
    if seed is None:
        seeds: list[Any] = [None] * num_envs
    elif is_integer(seed):
        seeds = [int(seed) + i for i in range(num_envs)]
    else:
        seeds = list(seed)
        if len(seeds) != num_envs:
            raise ValueError(f"seed list must have {num_envs} entries (one per env), got {len(seeds)}")
    if not current:
        return [seeding.np_random(s)[0] for s in seeds]
    return [seeding.np_random(s)[0] if s is not None else rng for s, rng in zip(seeds, current, strict=True)]
