"""Keys to actions, and the keys every connected client holds.

The page sends the names of the keys a person holds (:data:`KEY_NAMES`), never actions: the one
mapping from keys to the env's discrete actions is :data:`KEY_ACTIONS`, here. "up" moves the marble
up on the screen: the screen shows the board from above with +y up and +x to the right (the maze's
:class:`~bimgame.sim.render.MazeRenderer`, the labyrinth's raster north up), and a discrete action
tilts the board about its x or y axis (:data:`~bimgame.envs.actions.ACTION_MEANINGS`): tilting +x
raises the board's +y edge, so the marble rolls towards -y (down on the screen); tilting +y lowers
the +x edge, so it rolls towards +x (right). Both puzzles' discrete actions mean the same: 0 the
no-op, 1/2 a tilt step +/- about x, 3/4 about y (:data:`~bimgame.envs.actions.DISCRETE_TILTS`), on
the same two nested hinges (the maze's step is 1° per 1/30 s action, the labyrinth's 30°/s over a
1/55 s action), so one mapping serves both; tests step each env with each key's action and check
the direction.

A held key repeats its action every step; with no key held the action is the no-op. With several
keys held (by one person, or by people in several tabs), the most recently pressed one counts —
the discrete action space has one tilt per step.
"""

from __future__ import annotations

import itertools
from collections.abc import Hashable, Iterable
from typing import Any

import numpy as np

from bimgame.envs.actions import DISCRETE_TILTS

__all__ = ["KEY_ACTIONS", "KEY_NAMES", "NOOP", "HeldKeys", "action_name"]

#: The key names the page sends and the discrete action each one repeats while held.
KEY_ACTIONS = {
    "noop": 0,  # space: hold the board as it is
    "down": 1,  # tilt +x: the +y (top) edge rises, the marble rolls down on the screen
    "up": 2,  # tilt -x: the top edge sinks, the marble rolls up
    "right": 3,  # tilt +y: the +x (right) edge sinks, the marble rolls right
    "left": 4,  # tilt -y: the right edge rises, the marble rolls left
}
KEY_NAMES = tuple(KEY_ACTIONS)
NOOP = KEY_ACTIONS["noop"]
#: Most keys one message may name (a person has ten fingers; more is a broken or hostile client).
MAX_HELD = 8


def action_name(action: Any) -> str:
    """The key name of a discrete action (``"up"`` for 2), or of a continuous one that is a key's tilt
    (``DISCRETE_TILTS[2]`` is "up" too); another continuous action as its two rates, ``"(+0.25, -1.00)"``."""
    if np.ndim(action) == 1 and np.shape(action) == (2,):
        rates = np.asarray(action, dtype=np.float64)
        for name, value in KEY_ACTIONS.items():
            if np.array_equal(rates, DISCRETE_TILTS[value]):
                return name
        return f"({rates[0]:+.2f}, {rates[1]:+.2f})"
    for name, value in KEY_ACTIONS.items():
        if value == action:
            return name
    raise ValueError(
        f"invalid action {action!r}: discrete actions are integers 0..4, continuous ones 2 numbers in [-1, 1]"
    )


class HeldKeys:
    """The keys each client holds, in the order they were pressed across all clients.

    :meth:`set` replaces a client's whole set (the page sends its full set at every change, so a
    lost message is corrected by the next one); keys it already held keep their press order, new
    ones count as pressed now. :meth:`drop` forgets a client (a closed tab releases its keys).
    """

    def __init__(self) -> None:
        self._pressed: dict[Hashable, dict[str, int]] = {}
        self._clock = itertools.count(1)

    def set(self, client: Hashable, names: Iterable[str]) -> bool:
        """Set the keys ``client`` holds (names of :data:`KEY_NAMES`, checked by the caller);
        returns whether a key was newly pressed."""
        before = self._pressed.get(client, {})
        now: dict[str, int] = {}
        pressed = False
        for name in names:
            if name in now:
                continue
            if name in before:
                now[name] = before[name]
            else:
                now[name] = next(self._clock)
                pressed = True
        if now:
            self._pressed[client] = now
        else:
            self._pressed.pop(client, None)
        return pressed

    def drop(self, client: Hashable) -> None:
        self._pressed.pop(client, None)

    def latest(self) -> str | None:
        """The most recently pressed key still held by anyone, or None."""
        best, best_time = None, 0
        for keys in self._pressed.values():
            for name, time in keys.items():
                if time > best_time:
                    best, best_time = name, time
        return best

    def action(self) -> int:
        """The action of this step: the latest held key's, or the no-op."""
        name = self.latest()
        return NOOP if name is None else KEY_ACTIONS[name]

    def any(self) -> bool:
        return bool(self._pressed)
