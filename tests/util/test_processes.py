"""A helper process ends when its parent is killed (exit_when_parent_dies)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from support import procfs

ORPHAN = """
import subprocess, sys, time
child = subprocess.Popen([sys.executable, "-c", "import os, sys, time; sys.path[:] = %r; "
                          "from bimgame.util.processes import exit_when_parent_dies; "
                          "exit_when_parent_dies(os.getppid(), poll_seconds=0.05); print('watching', flush=True); "
                          "time.sleep(60)"], stdout=sys.stdout)
time.sleep(60)
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds the processes in /proc")
def test_a_helper_process_exits_when_its_parent_is_killed():
    """A process that is not a multiprocessing child (the Minari build process) polls its parent."""
    parent = subprocess.Popen([sys.executable, "-c", ORPHAN % (sys.path,)], stdout=subprocess.PIPE, text=True)
    children: dict[int, int] = {}
    try:
        assert parent.stdout.readline() == "watching\n"
        children = procfs.children(parent.pid)
        assert len(children) == 1
    finally:
        parent.kill()
        parent.wait()
        parent.stdout.close()
    try:
        assert not procfs.still_running_after(children, 5)
    finally:
        procfs.kill_left(children)


CHILD = """
import multiprocessing, os, time
from bimgame.util.processes import exit_when_parent_dies

def child(queue):
    exit_when_parent_dies()
    queue.put(os.getpid())
    time.sleep(60)

if __name__ == "__main__":
    queue = multiprocessing.get_context("spawn").Queue()
    multiprocessing.get_context("spawn").Process(target=child, args=(queue,)).start()
    print(queue.get(), flush=True)
    time.sleep(60)
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds the processes in /proc")
def test_a_multiprocessing_child_exits_when_its_parent_is_killed(tmp_path):
    """A multiprocessing child waits on its parent's sentinel."""
    script = tmp_path / "parent.py"
    script.write_text(CHILD)
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    child = None
    try:
        pid = int(parent.stdout.readline())
        stat = procfs.stat(pid)
        assert stat is not None
        child = (pid, stat[2])
    finally:
        parent.kill()
        parent.wait()
        parent.stdout.close()
    try:
        assert not procfs.still_running_after(dict([child]), 5)
    finally:
        if child is not None:
            procfs.kill_left(dict([child]))


def test_results_as_they_finish_runs_every_job_once_on_single_threaded_workers(monkeypatch):
    """Every job's result comes back once, on spawned workers or in this process, and the caller's
    thread variables are as they were afterwards."""
    import math
    import os

    from bimgame.util.processes import results_as_they_finish

    monkeypatch.setenv("OMP_NUM_THREADS", "7")
    jobs = [1.0, 4.0, 9.0, 16.0]
    assert sorted(results_as_they_finish(math.sqrt, jobs, workers=2)) == [1.0, 2.0, 3.0, 4.0]
    assert os.environ["OMP_NUM_THREADS"] == "7"
    assert list(results_as_they_finish(math.sqrt, jobs, workers=1)) == [1.0, 2.0, 3.0, 4.0]
