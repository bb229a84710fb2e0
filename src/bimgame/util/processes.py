"""Worker processes: :func:`exit_when_parent_dies` ends a worker or helper process as soon as the
process that started it is gone (e.g. killed with ``kill -9``), so nothing is left waiting forever on
pipes nobody reads; :func:`results_as_they_finish` runs independent jobs on spawned single-threaded
workers (the benchmarks' episodes)."""

from __future__ import annotations

import multiprocessing
import multiprocessing.connection
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import TypeVar

__all__ = ["exit_when_parent_dies", "ORPHANED_EXIT", "THREAD_VARS", "one_thread", "results_as_they_finish"]

#: The numerics libraries' thread counts, set to 1 in single-threaded workers.
THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMEXPR_NUM_THREADS")
_Job = TypeVar("_Job")
_Result = TypeVar("_Result")

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


def one_thread() -> None:
    """Make this process single-threaded: the numerics libraries (through :data:`THREAD_VARS`, read
    when they start) and torch, if anything imported it."""
    for name in THREAD_VARS:
        os.environ[name] = "1"
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


def results_as_they_finish(
    function: Callable[[_Job], _Result], jobs: Sequence[_Job], workers: int
) -> Iterator[_Result]:
    """``function(job)`` for every job, yielded as they finish, on ``workers`` spawned single-threaded
    processes (1: in this process, made single-threaded, in order). ``function`` must be picklable (a
    module-level function). The caller's thread variables are restored afterwards."""
    if workers == 1:
        one_thread()
        for job in jobs:
            yield function(job)
        return
    saved = {name: os.environ.get(name) for name in THREAD_VARS}
    os.environ.update({name: "1" for name in THREAD_VARS})  # inherited by the spawned workers
    context = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=context, initializer=one_thread)
    try:
        pending = {pool.submit(function, job) for job in jobs}
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in finished:
                yield future.result()
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
    pool.shutdown(wait=True)
