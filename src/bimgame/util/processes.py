"""Processes that must not outlive their parent: :func:`exit_when_parent_dies` ends a worker or
helper process as soon as the process that started it is gone (e.g. killed with ``kill -9``), so
nothing is left waiting forever on pipes nobody reads."""

from __future__ import annotations

import multiprocessing
import multiprocessing.connection
import os
import threading
import time

__all__ = ["exit_when_parent_dies", "ORPHANED_EXIT"]

#: The exit status of a process that ended because its parent died.
ORPHANED_EXIT = 1


def exit_when_parent_dies(parent_pid: int | None = None, poll_seconds: float = 0.5) -> threading.Thread:
    """End this process (``os._exit``) as soon as its parent process is gone, from a daemon thread:
    wherever the main thread is (planning, blocked on a pipe nobody reads), a process started by a
    job that was killed with ``kill -9`` does not live on. ``parent_pid``: the parent to watch
    (default: the current parent; pass the pid the parent had if it may already be gone). A
    multiprocessing child waits on its parent's sentinel; other processes poll ``os.getppid()``."""
    expected = os.getppid() if parent_pid is None else parent_pid
    parent = multiprocessing.parent_process()

    def watch() -> None:
        if parent is not None and parent.pid == expected:
            multiprocessing.connection.wait([parent.sentinel])  # ready when the parent has exited
        else:
            while os.getppid() == expected:
                time.sleep(poll_seconds)
        os._exit(ORPHANED_EXIT)

    thread = threading.Thread(target=watch, name="bimgame-exit-with-parent", daemon=True)
    thread.start()
    return thread
