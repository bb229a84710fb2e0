"""Many MPC expert episodes at once, on local worker processes or Ray tasks, and the progress bar
(episodes done, success so far) shown while they run. Dataset generation
(:mod:`bimgame.expert.datasets`, :mod:`bimgame.expert.labyrinth_datasets`) and expert evaluation
(:mod:`bimgame.expert.evaluation`) run their episodes through here.

:func:`run_jobs` runs any picklable episode function, one call per episode; :func:`expert_episodes`
runs the circular maze's expert with it. Episode ``i`` of a maze run is
``run_expert_episode(task, episode_seed(seed, i), config)`` (on maze ``mazes[i]`` when the caller
gives mazes): it depends on the run seed, its index and its maze only, so results do not depend on
the backend, the number of workers or the order in which episodes finish.

Local workers end when their parent dies (:func:`bimgame.util.processes.exit_when_parent_dies`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import multiprocessing
import os
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from bimgame.envs.randomization import Randomization
from bimgame.expert.mpc import MPCConfig, run_expert_episode
from bimgame.util.processes import exit_when_parent_dies
from bimgame.util.progress import ProgressBar
from bimgame.util.seeding import episode_seed
from bimgame.util.settings import is_integer

__all__ = [
    "check_generation",
    "BACKENDS",
    "MAIN_GUARD",
    "EpisodeOutcome",
    "run_jobs",
    "expert_episodes",
    "episode_progress",
    "environment",
    "import_ray",
]

BACKENDS = ("local", "ray")
_THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMEXPR_NUM_THREADS")
MAIN_GUARD = (
    "workers are started with multiprocessing's 'spawn' method, which imports the main "
    'script again: put the call under `if __name__ == "__main__":` (or use workers=1)'
)

#: What a worker returns: (episode index, the episode's arrays, seconds it took).
EpisodeOutcome = tuple[int, dict[str, Any], float]


def _episode_job(
    task: str,
    index: int,
    seed: int,
    config: MPCConfig,
    max_steps: int | None,
    randomize: Randomization | None,
    maze: int | None = None,
) -> EpisodeOutcome:
    start = time.perf_counter()
    episode = run_expert_episode(
        task, episode_seed(seed, index), config, maze_number=maze, max_steps=max_steps, randomize=randomize
    )
    return index, episode, time.perf_counter() - start


def expert_episodes(
    task: str,
    indices: list[int],
    seed: int,
    config: MPCConfig,
    *,
    max_steps: int | None = None,
    workers: int = 1,
    backend: str = "local",
    ray_address: str | None = None,
    randomize: Randomization | None = None,
    mazes: Mapping[int, int] | None = None,
) -> Iterator[EpisodeOutcome]:
    """Expert episodes ``indices`` of the run ``seed``, yielded as they finish; with ``randomize``,
    played on a randomised board while the expert plans with the nominal model; with ``mazes``
    (episode index → training maze number, one for each of ``indices``), episode ``i`` is played on
    maze ``mazes[i]`` (``run_expert_episode(..., maze_number=mazes[i])``), else on MERL's maze.

    ``config.nthread`` is forced to 1 (each worker plans on one thread; the actions do not
    change). ``backend="local"`` runs ``workers`` processes, started with "spawn" (fresh
    interpreters, no fork of a process with threads, single-threaded numerics) — a script calling
    this with workers > 1 needs the ``if __name__ == "__main__":`` guard; 1 runs the episodes in
    this process. ``backend="ray"`` runs Ray tasks of one CPU each, on ``ray_address`` or a local
    Ray started with ``num_cpus=workers`` (an already initialised Ray is used as is).
    """
    _check_backend(workers, backend)
    if mazes is not None:
        missing = [index for index in indices if index not in mazes]
        if missing:
            raise ValueError(f"mazes names no maze for episodes {missing[:5]}: give one for each of indices")
    config = dataclasses.replace(config, nthread=1)
    arguments = [
        (task, index, seed, config, max_steps, randomize, None if mazes is None else int(mazes[index]))
        for index in indices
    ]
    yield from run_jobs(_episode_job, arguments, workers=workers, backend=backend, ray_address=ray_address)


def run_jobs(
    job: Callable[..., EpisodeOutcome],
    arguments: Sequence[tuple[Any, ...]],
    *,
    workers: int = 1,
    backend: str = "local",
    ray_address: str | None = None,
) -> Iterator[EpisodeOutcome]:
    """``job(*args)`` for every ``args`` of ``arguments``, yielded as they finish: one episode each,
    returned as (episode index, its arrays, seconds). ``job`` must be a module-level function and
    its arguments picklable (they travel to other processes).

    ``backend="local"`` runs ``workers`` processes, started with "spawn" (fresh interpreters, no
    fork of a process with threads) with one numerics thread each (``OMP_NUM_THREADS=1`` …) — a
    script calling this with workers > 1 needs the ``if __name__ == "__main__":`` guard; 1 runs the
    jobs in this process, in order. ``backend="ray"`` runs Ray tasks of one CPU each, on
    ``ray_address`` or a local Ray started with ``num_cpus=workers`` (an already initialised Ray is
    used as is). A job's result must not depend on where it ran: then neither does a run's.
    """
    _check_backend(workers, backend)
    if backend == "ray":
        yield from _ray_episodes(job, arguments, workers, ray_address)
    else:
        yield from _local_episodes(job, arguments, workers)


def _check_backend(workers: Any, backend: Any) -> None:
    if not (is_integer(workers) and workers >= 1):
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; allowed: {', '.join(BACKENDS)}")


@contextlib.contextmanager
def environment(**values: str) -> Iterator[None]:
    """Set environment variables for the duration (inherited by processes started meanwhile)."""
    saved = {key: os.environ.get(key) for key in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def _local_episodes(
    job: Callable[..., EpisodeOutcome], todo: Sequence[tuple[Any, ...]], workers: int
) -> Iterator[EpisodeOutcome]:
    if workers == 1 or len(todo) == 1:
        for arguments in todo:
            yield job(*arguments)
        return
    context = multiprocessing.get_context("spawn")
    with environment(**{name: "1" for name in _THREAD_VARS}):
        pool = ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=context, initializer=_worker_started)
        try:
            pending = {pool.submit(job, *arguments) for arguments in todo}
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    yield future.result()
        except BrokenProcessPool as error:
            pool.shutdown(wait=False, cancel_futures=True)
            raise RuntimeError(f"a worker process died ({error}). If this runs in a script, {MAIN_GUARD}") from error
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise
        pool.shutdown(wait=True)


def _worker_started() -> None:
    """Each local worker ends when the process that started it dies: after a ``kill -9`` of the
    parent nobody reads the pool's pipes any more, and the workers would wait on them forever."""
    parent = multiprocessing.parent_process()
    exit_when_parent_dies(parent.pid if parent is not None else None)


def import_ray():
    """The ``ray`` module, or an ImportError that says how to install it."""
    try:
        import ray  # optional (the "ray" extra) and slow to import: only when backend="ray" is asked for
    except ImportError:
        raise ImportError(
            'backend="ray" needs Ray, which is not installed: pip install "bimgame[ray]" (or pip install ray)'
        ) from None
    return ray


def _ray_episodes(
    job: Callable[..., EpisodeOutcome], todo: Sequence[tuple[Any, ...]], workers: int, ray_address: str | None
) -> Iterator[EpisodeOutcome]:
    ray = import_ray()
    started = False
    if not ray.is_initialized():
        if ray_address is None:  # a new Ray on this machine, even if a cluster runs here too
            ray.init(address="local", num_cpus=workers, include_dashboard=False)
        else:
            ray.init(address=ray_address)
        started = True
    try:
        remote = ray.remote(num_cpus=1)(job)
        pending = [remote.remote(*arguments) for arguments in todo]
        try:
            while pending:
                finished, pending = ray.wait(pending, num_returns=1)
                yield ray.get(finished[0])
        except BaseException:
            for ref in pending:
                ray.cancel(ref)
            raise
    finally:
        if started:
            ray.shutdown()


@contextlib.contextmanager
def episode_progress(
    enabled: bool, description: str, total: int, done: int = 0, successes: int = 0, transient: bool = False
) -> Iterator[Callable[[bool], None]]:
    """A :class:`~bimgame.util.progress.ProgressBar` over episodes (episodes done, success so far,
    elapsed, ETA); yields ``update(success)`` to call once per finished episode. ``done``/``successes``
    count episodes finished before (a resumed run); ``transient`` removes the bar when done."""
    counts = {"done": done, "success": successes}

    def info() -> str:
        return f"success {counts['success'] / counts['done']:.0%}" if counts["done"] else "success -"

    with ProgressBar(
        description, total, completed=done, enabled=enabled, eta=True, transient=transient, info=info()
    ) as bar:

        def update(success: bool) -> None:
            counts["done"] += 1
            counts["success"] += success
            bar.update(advance=1, info=info())

        yield update


def check_generation(
    caller: str,
    *,
    episodes: Any,
    seed: Any,
    workers: Any,
    backend: Any,
    ray_address: Any,
    max_steps: Any,
    progress: Any,
) -> int:
    """Refuse, naming the value and what is allowed, the run options every dataset generation
    (either puzzle's) takes, before anything touches the disk; returns the number of workers (None:
    ``os.cpu_count()``). ``caller`` names the function for the spawn-guard error, and Ray is imported
    now when it is the backend so that a missing install fails first."""
    if getattr(multiprocessing.current_process(), "_inheriting", False):
        raise RuntimeError(f"{caller} was called while a worker process was starting; {MAIN_GUARD}")
    _check_count("episodes", episodes, minimum=1)
    _check_count("seed", seed, minimum=0)
    workers = (os.cpu_count() or 1) if workers is None else workers
    _check_backend(workers, backend)
    if ray_address is not None and backend != "ray":
        raise ValueError(f"ray_address is only used with backend='ray' (got backend={backend!r})")
    if max_steps is not None:
        _check_count("max_steps", max_steps, minimum=1)
    if not isinstance(progress, bool):
        raise TypeError(f"progress must be True or False, got {progress!r}")
    if backend == "ray":
        import_ray()
    return int(workers)


def _check_count(name: str, value: Any, *, minimum: int) -> None:
    if not (is_integer(value) and value >= minimum):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
