"""Processes seen through /proc (Linux): their state, parent and start time (which tells a reused pid
apart), for the tests that kill a parent and check that no child outlives it."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path


def stat(pid: int) -> tuple[str, int, int] | None:
    """(state, parent pid, start time) of a process from /proc, or None if it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text.rsplit(")", 1)[1].split()  # after "pid (comm)": state, ppid, ..., starttime (22nd field)
    return fields[0], int(fields[1]), int(fields[19])


def descendants(pid: int) -> dict[int, int]:
    """Every process below ``pid`` → its start time (which tells a reused pid apart)."""
    stats = {int(name): stat(int(name)) for name in os.listdir("/proc") if name.isdigit()}
    found, frontier = {}, [pid]
    while frontier:
        parent = frontier.pop()
        for child, info in stats.items():
            if info is not None and info[1] == parent and child not in found:
                found[child] = info[2]
                frontier.append(child)
    return found


def children(pid: int) -> dict[int, int]:
    """The processes whose parent is ``pid`` → their start time (which tells a reused pid apart)."""
    stats = {int(name): stat(int(name)) for name in os.listdir("/proc") if name.isdigit()}
    return {child: info[2] for child, info in stats.items() if info is not None and info[1] == pid}


def running(pid: int, start: int) -> bool:
    """Whether the process ``pid`` that started at ``start`` is still running (a zombie has exited)."""
    info = stat(pid)
    return info is not None and info[2] == start and info[0] not in "ZX"


def still_running_after(processes: dict[int, int], seconds: float) -> list[int]:
    """Wait up to ``seconds`` for the processes (pid → start time) to end; the pids still running."""
    deadline = time.monotonic() + seconds
    while any(running(pid, start) for pid, start in processes.items()) and time.monotonic() < deadline:
        time.sleep(0.05)
    return [pid for pid, start in processes.items() if running(pid, start)]


def kill_left(processes: dict[int, int]) -> None:
    """SIGKILL those of the processes still running (after a failed test: only the ones it started)."""
    for pid, start in processes.items():
        if running(pid, start):
            os.kill(pid, signal.SIGKILL)
