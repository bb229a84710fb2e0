"""SIGTERM as Ctrl-C, for long jobs.

Batch schedulers, ``kill`` and background shells send SIGTERM (and often ignore SIGINT); a training
run or a reproduction should stop on it exactly as on Ctrl-C: a final checkpoint, the piece marked
interrupted, resumable. One helper, used by A3C and the reproduction runner alike.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType

__all__ = ["sigterm_as_interrupt"]


def _interrupt(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM raises ``KeyboardInterrupt``; the previous handler is restored after.
    Only the main thread may set handlers: elsewhere the block runs unchanged."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
