"""How PPO's learning process talks with its child processes — the ranks of
:mod:`~bimgame.learn.ppo.parallel` and the collectors of :mod:`~bimgame.learn.ppo.collectors`: commands
down one queue per child, messages up one shared queue, and a child that ends without a word is
noticed rather than waited for forever.

Every message up is ``(kind, index, payload)``; a child that fails sends ``("error", index,
traceback)`` before it exits. Children ignore Ctrl-C (the terminal sends it to the whole process group):
the learning process decides when a run stops.
"""

from __future__ import annotations

import os
import queue
from collections.abc import Sequence
from typing import Any

from bimgame.learn.run_dir import TrainingError

__all__ = ["POLL_SECONDS", "next_command", "next_message", "stop_children"]

#: How often a waiting process checks that the process it waits for is still alive.
POLL_SECONDS = 1.0


def next_command(commands: Any, parent: int) -> tuple[str, int]:
    """The learning process's next command to a child; a child whose parent is gone (killed without a
    word) stops."""
    while True:
        try:
            return commands.get(timeout=POLL_SECONDS)
        except queue.Empty:
            if os.getppid() != parent:
                return "stop", 0


def next_message(messages: Any, processes: Sequence[Any], what: str, first: int = 0) -> tuple[str, int, Any]:
    """The next message from the children ``processes`` (numbered from ``first``, ``what`` naming
    them: "PPO worker"); a child's error report is raised as a :class:`TrainingError`, and so is a
    child that ended without a word."""
    while True:
        try:
            kind, index, payload = messages.get(timeout=POLL_SECONDS)
        except queue.Empty:
            for index, process in enumerate(processes, first):
                if not process.is_alive():
                    raise TrainingError(f"{what} {index} ended without a word (exit code {process.exitcode})") from None
            continue
        if kind == "error":
            raise TrainingError(f"{what} {index} failed:\n{payload}")
        return kind, index, payload


def stop_children(commands: Sequence[Any], processes: list[Any], *, terminate: bool, grace: float = 30.0) -> None:
    """End the children: each is told to stop, and one that has not ended within ``grace`` seconds
    (or at once, with ``terminate``: after a failure or an interruption) is terminated, then killed."""
    for child_commands in commands:
        child_commands.put(("stop", 0))
    for process in processes:
        if terminate:
            process.terminate()
        process.join(timeout=grace)
        if process.is_alive():
            process.terminate()
            process.join(timeout=5.0)
        if process.is_alive():
            process.kill()
            process.join()
    processes.clear()
