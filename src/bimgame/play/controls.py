"""Keys to actions, and the keys every connected client holds.

The page sends the names of the keys a person holds (:data:`KEY_NAMES`), never actions: the one
mapping from keys to the env's discrete actions is :data:`KEY_ACTIONS`, here. "up" moves the marble
up on the screen: the screen shows the board from above with +y up and +x to the right
(:class:`~bimgame.sim.render.MazeRenderer`), and a discrete action tilts the board about its x or
y axis (:data:`~bimgame.envs.env.ACTION_MEANINGS`): tilting +x raises the board's +y edge, so the
marble rolls towards -y (down on the screen); tilting +y lowers the +x edge, so it rolls towards +x
(right). A test steps the env with each key's action and checks the direction.

A held key repeats its action every step; with no key held the action is the no-op. With several
keys held (by one person, or by people in several tabs), the most recently pressed one counts —
the discrete action space has one tilt per step.
"""

from __future__ import annotations

import itertools
from collections.abc import Hashable, Iterable

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


def action_name(action: int) -> str:
    """The key name of a discrete action (``"up"`` for 2)."""
    for name, value in KEY_ACTIONS.items():
        if value == action:
            return name
    raise ValueError(f"invalid action {action!r}: discrete actions are integers 0..4")


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
