"""The websocket protocol of ``bimgame play``, checked message by message.

Client → server: text frames, each one JSON object with a ``type``:

- ``{"type": "keys", "held": ["up", "right"]}`` — every key the client holds now, in press order
  (names of :data:`~bimgame.play.controls.KEY_NAMES`; ``[]`` when none is). Sent at every change.
- ``{"type": "reset"}`` — end the episode and begin the next (R).
- ``{"type": "control", "who": "human" | "agent"}`` — who plays (H toggles; needs ``--agent``).
- ``{"type": "greedy", "value": true | false}`` — the agent's most likely action, or sampled.

Server → client: a JSON ``hello`` when the client connects (task, puzzle, limits, tick rate, keys,
agent, recording, the number of clients), then for every tick a JSON ``state``
(:meth:`PlaySession.snapshot`) followed by a binary frame (a JPEG of the board: the maze with its
tilt gauge, or the labyrinth); ``{"type": "error", "message": …}`` answers a message that is not
understood (not JSON, not an object, unknown type, unknown key or field, wrong value, too long,
binary) — the message is then ignored and nothing else changes;
``{"type": "bye", "message": …}`` before the server closes the socket when it stops.
"""

from __future__ import annotations

import json
from collections.abc import Hashable
from typing import Any

from bimgame.play.controls import KEY_NAMES, MAX_HELD
from bimgame.play.session import CONTROLLERS, PlaySession

__all__ = ["ProtocolError", "MAX_MESSAGE_CHARS", "parse_message", "apply_message", "error_reply"]

#: Longest text message accepted (the longest valid one is about 100 characters).
MAX_MESSAGE_CHARS = 2048
_FIELDS = {"keys": {"held"}, "reset": set(), "control": {"who"}, "greedy": {"value"}}


class ProtocolError(ValueError):
    """A client message that is not understood; its text is sent back to the client."""


def parse_message(text: Any) -> dict[str, Any]:
    """The checked message of a websocket text frame; raises :class:`ProtocolError` saying why not."""
    if not isinstance(text, str):
        raise ProtocolError(
            'binary messages are not understood; send JSON text such as {"type": "keys", "held": ["up"]}'
        )
    if len(text) > MAX_MESSAGE_CHARS:
        raise ProtocolError(f"message too long ({len(text)} characters, at most {MAX_MESSAGE_CHARS})")
    try:
        message = json.loads(text)
    except ValueError as error:
        raise ProtocolError(f"not JSON ({error})") from None
    if not isinstance(message, dict):
        raise ProtocolError(f"expected a JSON object with a 'type', got {type(message).__name__}")
    kind = message.get("type")
    if not isinstance(kind, str) or kind not in _FIELDS:
        raise ProtocolError(f"unknown message type {kind!r}; allowed: {', '.join(_FIELDS)}")
    extra = set(message) - _FIELDS[kind] - {"type"}
    missing = _FIELDS[kind] - set(message)
    if extra or missing:
        parts = ([f"unknown fields {sorted(extra)}"] if extra else []) + (
            [f"missing fields {sorted(missing)}"] if missing else []
        )
        raise ProtocolError(f"{kind!r} message: {'; '.join(parts)}")
    if kind == "keys":
        held = message["held"]
        if not isinstance(held, list) or len(held) > MAX_HELD:
            raise ProtocolError(f"'keys' message: 'held' must be a list of at most {MAX_HELD} key names")
        wrong = [k for k in held if not isinstance(k, str) or k not in KEY_NAMES]
        if wrong:
            raise ProtocolError(f"'keys' message: unknown keys {wrong}; allowed: {', '.join(KEY_NAMES)}")
    elif kind == "control" and message["who"] not in CONTROLLERS:
        raise ProtocolError(f"'control' message: 'who' must be one of {', '.join(CONTROLLERS)}, got {message['who']!r}")
    elif kind == "greedy" and not isinstance(message["value"], bool):
        raise ProtocolError(f"'greedy' message: 'value' must be true or false, got {message['value']!r}")
    return message


def apply_message(session: PlaySession, client: Hashable, text: Any) -> dict[str, Any] | None:
    """Carry out one client message on ``session``; returns the error reply to send, or None. A
    message that is not understood, or that the session refuses (e.g. control to an agent when
    there is none), changes nothing."""
    try:
        message = parse_message(text)
        kind = message["type"]
        if kind == "keys":
            session.set_keys(client, message["held"])
        elif kind == "reset":
            session.reset()
        elif kind == "control":
            session.set_controller(message["who"])
        elif kind == "greedy":
            session.set_greedy(message["value"])
    except ValueError as error:  # ProtocolError, or the session refusing a valid message
        return error_reply(str(error), text)
    return None


def error_reply(message: str, received: Any = None) -> dict[str, Any]:
    """The ``error`` message for the client (with the start of what it sent)."""
    reply: dict[str, Any] = {"type": "error", "message": message}
    if received is not None:
        shown = received if isinstance(received, str) else f"<{len(received)} bytes>"
        reply["received"] = shown[:120]
    return reply
