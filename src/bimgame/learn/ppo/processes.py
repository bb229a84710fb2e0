"""How PPO's learning process talks with its child processes — the ranks of
:mod:`~bimgame.learn.ppo.parallel` and the collectors of :mod:`~bimgame.learn.ppo.collectors`: commands
down one queue per child, messages up one shared queue, and a child that ends without a word is
noticed rather than waited for forever.

Every message up is ``(kind, index, payload)``; a child that fails sends ``("error", index,
traceback)`` before it exits. Children ignore Ctrl-C (the terminal sends it to the whole process group):
the learning process decides when a run stops; a child whose learning process is killed without a
word ends itself (:func:`~bimgame.util.processes.exit_when_parent_dies`), so a child blocks on its
command queue with no timeout.
"""

from __future__ import annotations

import queue
from collections.abc import Sequence
from typing import Any

from bimgame.learn.run_dir import TrainingError

__all__ = ["POLL_SECONDS", "next_message", "stop_children"]

#: How often a waiting process checks that the process it waits for is still alive.
POLL_SECONDS = 1.0


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
