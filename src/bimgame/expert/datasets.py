"""Expert trajectories as standard `Minari <https://minari.farama.org>`_ datasets: parallel,
resumable generation, verified loading, and whole-episode sequences for pre-training.

A generation run owns one directory, ``out_dir``::

    generation.json                  what is generated: task, run seed, episodes, MPC config, versions
    episodes/episode_000000.npz …    one file per finished episode, written atomically (the
                                     resumable source: a restart skips the episodes already here)
    minari/                          a Minari datasets root (point MINARI_DATASETS_PATH here)
      bimgame/<task>-expert-v0/data/{metadata.json, main_data.hdf5}
    COMPLETE                         written last: counts, a content hash and every file's SHA-256

A full disk stops the run with :class:`~bimgame.util.files.DiskFullError` ("no space left on device
while writing FILE; rerun the same command to resume"), losing no finished episode. The episode
files and the Minari (HDF5) file, written by a child process so that a failed HDF5 write kills only
that process, are :mod:`bimgame.expert.minari_build`'s; :mod:`bimgame.expert.dataset_files` holds
the manifest's and the marker's checks.

Episode ``i`` is ``run_expert_episode(task, episode_seed(seed, i), config)``: it depends on the run
seed and its index only, so the dataset is the same whatever the number of workers, the backend
(local processes or Ray) or how often the run was interrupted and resumed.

**Many mazes** (``num_mazes``, ``start_maze``; default: MERL's maze): episode ``i`` is played on
training maze ``start_maze + (i mod num_mazes)`` (:func:`bimgame.sim.maze_sets.maze_number`), as an
env built with ``num_mazes`` plays it, the expert planning in that maze
(``run_expert_episode(..., maze_number=...)``). The manifest records ``num_mazes`` and
``start_maze`` (a resumed run must match them); each episode file holds its ``maze``; the Minari
dataset's environment is made with the same ``num_mazes``/``start_maze``, each episode's reset
options are ``{"maze": number}`` and its ``infos["maze"]`` the number at every step; the state
observations end with the maze's encoding (135 values for one marble), as the env's do.

The Minari dataset holds, per episode of T steps: ``observations`` (T+1, 7) state observations,
``actions`` (T,), ``rewards``, ``terminations``, ``truncations`` (T,), and ``infos`` with
``sim_state`` (T+1, S) MuJoCo physics states and ``channel`` (T+1, n) task channels — T+1 like
the observations, as Minari's ``DataCollector`` records the info of ``reset`` and of every step.
From ``sim_state`` and ``channel`` (and the episode's maze), :class:`~bimgame.envs.observe.Observer`
re-renders the pixel observations exactly (:func:`iterate_sequences` with ``obs="pixels"``). Each
episode's reset seed is Minari's episode metadata ``seed``.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import minari
import numpy as np
from minari import MinariDataset

import bimgame
from bimgame.envs.gate_bearings import GateBearings
from bimgame.envs.mazes import maze_encoding_size
from bimgame.envs.observe import Observer
from bimgame.expert.dataset_files import (
    FORMAT_NAME,
    FORMAT_VERSION,
    LOCK_NAME,
    MANIFEST_NAME,
    MARKER_NAME,
    MINARI_DIR,
    data_path,
    episode_totals,
    maze_fields,
    read_manifest,
    verify_marker,
)
from bimgame.expert.episode import Episode
from bimgame.expert.generation import EpisodeFormat, run_generation, write_marker
from bimgame.expert.minari_build import (
    DatasetError,
    episode_maze,
    episode_path,
    read_episode,
)
from bimgame.expert.mpc import MPCConfig
from bimgame.expert.pool import BACKENDS, EpisodeOutcome, check_generation, expert_episodes
from bimgame.sim.maze import MazeSpec
from bimgame.sim.maze_sets import maze_number
from bimgame.sim.physics import MazeSim
from bimgame.sim.tasks import Task, parse_task
from bimgame.util.seeding import episode_seed

__all__ = [
    "DatasetError",
    "generate_dataset",
    "load_dataset",
    "iterate_sequences",
    "dataset_summary",
    "dataset_id_for",
    "dataset_manifest",
    "dataset_mazes",
    "episode_totals",
    "write_marker",
    "BACKENDS",
    "MINARI_DIR",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "MANIFEST_NAME",
    "MARKER_NAME",
    "LOCK_NAME",
]


# ---------------------------------------------------------------------------------- generation
def dataset_id_for(task: str | Task, source: str = "expert") -> str:
    """The Minari dataset id of a task's data from ``source`` (``expert``, or ``human`` for
    ``bimgame play`` recordings), e.g. ``bimgame/full-expert-v0``."""
    return f"bimgame/{parse_task(task).value.lower()}-{source}-v0"


def generate_dataset(
    out_dir: str | Path,
    task: str = "FULL",
    episodes: int = 500,
    *,
    seed: int = 0,
    config: MPCConfig = MPCConfig(),
    workers: int | None = None,
    backend: str = "local",
    ray_address: str | None = None,
    progress: bool = True,
    max_steps: int | None = None,
    num_mazes: int | None = None,
    start_maze: int = 0,
) -> Path:
    """Generate ``episodes`` expert episodes on ``task`` into ``out_dir`` and build the Minari
    dataset from them; returns ``out_dir``.

    Resumable: every finished episode is saved at once; run again with the same arguments after an
    interruption and only the missing episodes are generated (a finished dataset is verified and
    returned as is). Different arguments on an existing run, or a directory holding anything else,
    raise an error and change nothing.

    Args:
        out_dir: the run's directory (created; must be new, empty or this run's).
        task: FULL or STG1…STG4.
        episodes: number of episodes; episode ``i`` starts from ``reset(seed=episode_seed(seed, i))``.
        seed: the run seed (a non-negative integer).
        config: the MPC expert's settings (``nthread`` is forced to 1: each worker plans on one
            thread; it does not change the actions).
        workers: parallel episodes (default ``os.cpu_count()``): local processes, or the CPUs Ray
            starts locally. 1 runs the episodes in this process. Local workers are started with
            multiprocessing's "spawn" method: a script calling this needs the usual
            ``if __name__ == "__main__":`` guard.
        backend: ``"local"`` (a process pool) or ``"ray"`` (Ray tasks; ``pip install "bimgame[ray]"``;
            workers must have bimgame installed, results come back to this process, which writes
            every file).
        ray_address: a Ray cluster to connect to (``ray.init(address=...)``); None starts Ray
            locally with ``num_cpus=workers``. An already initialised Ray is used as is.
        progress: show a progress bar (episodes done, success so far, ETA) on stderr.
        max_steps: time limit per episode (default: the task's registered limit).
        num_mazes: play the episodes on this many random training mazes, episode ``i`` on maze
            ``start_maze + (i mod num_mazes)`` (see the module's "Many mazes"); at least 1 — a dataset
            must name its mazes, so the learners' unlimited ``0`` is refused. None (default): MERL's
            maze, the dataset exactly as without these arguments.
        start_maze: the first training maze's number (with ``num_mazes``).

    Raises:
        DiskFullError: (an ``OSError``) the disk filled up; the message names the file. Every
            episode saved before stays; run again with the same arguments once there is room.
    """
    out_dir = Path(out_dir).absolute()  # Minari joins relative dataset paths onto its root
    task_enum = parse_task(task)
    workers = check_generation(
        "generate_dataset",
        episodes=episodes,
        seed=seed,
        workers=workers,
        backend=backend,
        ray_address=ray_address,
        max_steps=max_steps,
        progress=progress,
    )
    if not isinstance(config, MPCConfig):
        raise TypeError(f"config must be an MPCConfig, got {type(config).__name__}")
    mazes = maze_fields(num_mazes, start_maze)
    config = dataclasses.replace(config, nthread=1)
    manifest = {**_manifest(task_enum, int(episodes), int(seed), config, max_steps), **mazes}

    _generate(out_dir, manifest, config, progress, workers, backend, ray_address)
    return out_dir


def _generate(
    out_dir: Path,
    manifest: dict,
    config: MPCConfig,
    progress: bool,
    workers: int,
    backend: str,
    ray_address: str | None,
) -> None:
    """The maze expert's run on :func:`~bimgame.expert.generation.run_generation`'s protocol:
    episode ``i`` played on its maze (:func:`episode_maze`) and read back checked against it."""
    task, seed, max_steps = manifest["task"], manifest["seed"], manifest["max_steps"]

    def read(index: int) -> dict[str, np.ndarray]:
        path = episode_path(out_dir, index)
        return read_episode(path, index, episode_seed(seed, index), episode_maze(manifest, index))

    def play(todo: list[int]) -> Iterator[EpisodeOutcome]:
        mazes = {i: number for i in todo if (number := episode_maze(manifest, i)) is not None} or None
        return expert_episodes(
            task,
            todo,
            seed,
            config,
            max_steps=max_steps,
            workers=workers,
            backend=backend,
            ray_address=ray_address,
            mazes=mazes,
        )

    run_generation(out_dir, manifest, EpisodeFormat(), read=read, play=play, progress=progress)


def _manifest(task: Task, episodes: int, seed: int, config: MPCConfig, max_steps: int | None) -> dict:
    return {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "task": task.value,
        "episodes": episodes,
        "seed": seed,
        "max_steps": max_steps,
        "mpc_config": dataclasses.asdict(config),
        "bimgame_version": bimgame.__version__,
        "dataset_id": dataset_id_for(task),
        "env_id": f"BiMGame/{task.value}-v0",
        "minari_version": minari.__version__,
    }


# ------------------------------------------------------------------------------------- loading
def load_dataset(out_dir: str | os.PathLike, *, verify: bool = True):
    """Open a finished dataset directory as a ``minari.MinariDataset``.

    Checks the COMPLETE marker, the episode count and every file's size, and with ``verify`` (the
    default) every file's SHA-256; an incomplete, truncated or modified dataset raises
    :class:`DatasetError` naming the problem. (Pointing ``MINARI_DATASETS_PATH`` at
    ``out_dir/minari`` also lets ``minari.load_dataset(dataset_id)`` open it, without these checks.)
    """
    out_dir = Path(out_dir).absolute()  # Minari joins relative dataset paths onto its root
    if not out_dir.is_dir():
        raise DatasetError(
            f"dataset directory {out_dir} does not exist" if not out_dir.exists() else f"{out_dir} is not a directory"
        )
    manifest = read_manifest(out_dir)
    marker = verify_marker(out_dir, manifest, hashes=verify)
    try:
        dataset = MinariDataset(data_path(out_dir, manifest["dataset_id"]))
    except Exception as exc:  # noqa: BLE001 - Minari raises many kinds on a damaged dataset; the message names it
        raise DatasetError(f"Minari cannot open the dataset in {out_dir} ({type(exc).__name__}: {exc})") from None
    if dataset.total_episodes != marker["episodes"] or dataset.total_steps != marker["steps"]:
        raise DatasetError(
            f"the Minari dataset in {out_dir} has {dataset.total_episodes} episodes and "
            f"{dataset.total_steps} steps, the marker {marker['episodes']} and {marker['steps']}"
        )
    return dataset


def dataset_manifest(out_dir: str | Path) -> dict[str, Any]:
    """What a dataset directory holds (its ``generation.json``: task, episodes, seed, MPC settings)."""
    return read_manifest(Path(out_dir))


def dataset_mazes(out_dir: str | Path) -> dict[str, int]:
    """The mazes a dataset was generated on, as the learners' settings and the envs' arguments name
    them (``num_mazes``, ``start_maze``); {} for MERL's maze."""
    manifest = read_manifest(Path(out_dir))
    return maze_fields(manifest.get("num_mazes"), manifest.get("start_maze", 0))


def dataset_summary(out_dir: str | Path) -> dict[str, Any]:
    """Counts and disk use of a finished dataset (from its marker, without re-hashing): episodes,
    steps, success rate, mean length, bytes of the episode files and of the Minari dataset, and
    both per 1000 steps."""
    out_dir = Path(out_dir).absolute()  # Minari joins relative dataset paths onto its root
    manifest = read_manifest(out_dir)
    marker = verify_marker(out_dir, manifest, hashes=False)
    sizes = {"episodes": 0, "minari": 0}
    for name, entry in marker["files"].items():
        sizes["minari" if name.startswith(MINARI_DIR + "/") else "episodes"] += entry["size"]
    steps = marker["steps"]
    return {
        "dataset_id": marker["dataset_id"],
        "episodes": marker["episodes"],
        "steps": steps,
        "success_rate": marker["successes"] / marker["episodes"],
        "mean_length": steps / marker["episodes"],
        "content_sha256": marker["content_sha256"],
        "bytes_episode_files": sizes["episodes"],
        "bytes_minari": sizes["minari"],
        "bytes_per_1000_steps_episode_files": 1000 * sizes["episodes"] / steps,
        "bytes_per_1000_steps_minari": 1000 * sizes["minari"] / steps,
    }


# ---------------------------------------------------------------------------- pre-training view
def iterate_sequences(
    dataset_or_dir,
    *,
    obs: str = "state",
    gamma: float = 0.99,
    gate_bearings: bool = False,
) -> Iterator[Episode]:
    """Whole episodes for sequence models (an LSTM sees each episode from its start).

    ``dataset_or_dir``: a ``MinariDataset`` (e.g. from :func:`load_dataset`) or a dataset directory
    (opened with :func:`load_dataset`). Yields one :class:`~bimgame.expert.episode.Episode` per
    episode: ``obs`` ``"state"`` is (T, 7) float32 from the stored observations ((T, 135) on many
    mazes: with the maze's encoding), ``"pixels"`` is (T, 1, 84, 84) uint8 re-rendered from the
    stored physics states, showing the episode's maze (identical to the env's own pixel
    observations); ``channels`` come from the stored infos (or the state observations);
    ``state_obs`` are the stored state observations without a maze's encoding (the marbles' and the
    board's state, as the vector env's ``infos["state"]``; also for pixels: the privileged targets
    of auxiliary losses); ``id`` is the episode's index in the dataset. ``gate_bearings``: state
    observations on many mazes also end with the marble's :mod:`~bimgame.envs.gate_bearings` in the
    episode's maze, computed from the stored positions as an env with ``gate_bearings=True`` computes
    them (datasets store the observations without them).
    """
    if obs not in ("state", "pixels"):
        raise ValueError(f"unknown obs {obs!r}; allowed: 'state', 'pixels'")
    if not (isinstance(gamma, (int, float)) and not isinstance(gamma, bool) and 0.0 <= gamma <= 1.0):
        raise ValueError(f"gamma must be a number in [0, 1], got {gamma!r}")
    if isinstance(dataset_or_dir, (str, os.PathLike)):
        dataset = load_dataset(dataset_or_dir)
    elif hasattr(dataset_or_dir, "iterate_episodes"):
        dataset = dataset_or_dir
    else:
        raise TypeError(f"expected a MinariDataset or a dataset directory, got {type(dataset_or_dir).__name__}")
    board, observer = MazeSpec.merl(), None
    for episode in dataset.iterate_episodes():
        steps = len(episode.rewards)
        states = np.asarray(episode.observations[:steps], dtype=np.float32)
        infos = episode.infos or {}
        # An episode on one of many mazes: its number at every step, its encoding after the marbles' state.
        maze = int(infos["maze"][0]) if "maze" in infos else None
        encoding = 0 if maze is None else maze_encoding_size(board)
        n_marbles = (states.shape[1] - 2 - encoding) // 5  # [x, y, vx, vy] * n, tilt_x, tilt_y, channel * n
        if obs == "pixels":
            if "sim_state" not in infos or "channel" not in infos:
                raise ValueError(
                    f"episode {episode.id} has no infos['sim_state'] / infos['channel'] "
                    "to render pixels from (not a bimgame expert dataset?)"
                )
            if observer is None:
                observer = _pixel_observer(infos["channel"].shape[1])
            observer.set_maze(board if maze is None else maze_number(maze, "train", board))
            frames = observer(
                np.asarray(infos["sim_state"][:steps], dtype=np.float64), np.asarray(infos["channel"][:steps])
            )
        elif gate_bearings:
            if maze is None:
                raise ValueError(
                    f"gate_bearings: episode {episode.id} is on MERL's maze alone (gate bearings are part of "
                    "the observations on many mazes)"
                )
            bearings = GateBearings.of(maze_number(maze, "train", board))(states[:, 0], states[:, 1])
            frames = np.concatenate([states, bearings], axis=1)
        else:
            frames = states
        if "channel" in infos:
            channels = np.asarray(infos["channel"][: steps + 1], dtype=np.int64)
        else:
            observed = np.asarray(episode.observations[: steps + 1])[:, 4 * n_marbles + 2 : 5 * n_marbles + 2]
            channels = np.rint(observed).astype(np.int64)
        yield Episode.from_steps(
            obs=frames,
            actions=episode.actions,
            rewards=episode.rewards,
            tilt=states[:, 4 * n_marbles : 4 * n_marbles + 2],
            gamma=gamma,
            channels=channels,
            terminated=bool(episode.terminations[-1]),
            truncated=bool(episode.truncations[-1]),
            id=int(episode.id),
            state_obs=states[:, : 5 * n_marbles + 2],
        )


def _pixel_observer(n_marbles: int) -> Observer:
    """The pixel observer of MERL's board: it shows MERL's maze, or any numbered maze on that board
    after ``set_maze`` (its raster drawn from the board's, as the envs with ``num_mazes`` draw it)."""
    maze = MazeSpec.merl()
    sim = MazeSim(maze, n_marbles=n_marbles)
    layout = sim.layout
    sim.close()
    return Observer(maze, n_marbles, "pixels", layout=layout, board=maze)
