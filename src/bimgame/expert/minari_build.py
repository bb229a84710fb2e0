"""The episode files of a dataset generation run and the Minari dataset built from them (used by
:mod:`bimgame.expert.datasets`).

Each finished episode is one ``.npz`` file (:func:`episode_bytes`, read back checked by
:func:`read_episode`; another puzzle's datasets name their own arrays, ``keys``, and read the file
with :func:`load_episode_arrays`); an episode of a dataset on many mazes also holds ``maze``, its maze number
(:func:`episode_maze`), which the Minari dataset keeps as the episode's reset options
(``{"maze": number}``, next to its ``seed``) and as ``infos["maze"]``.

The Minari (HDF5) file is written by a child process (:func:`run_build_process`): HDF5 does not
survive a failed write cleanly (errors from every object it frees, then often a segmentation
fault), so only that process fails; its error output is captured here and a full disk is
recognised in it (or in its exit status, the errno).
"""

from __future__ import annotations

import errno
import importlib
import io
import json
import os
import subprocess
import sys
import traceback
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import gymnasium as gym
import minari
import numpy as np
from minari.data_collector import EpisodeBuffer

from bimgame.expert.references import references_for
from bimgame.util.files import disk_full_errno
from bimgame.util.processes import exit_when_parent_dies
from bimgame.util.seeding import episode_seed

__all__ = [
    "DatasetError",
    "ALGORITHM_NAME",
    "EPISODES_DIR",
    "EPISODE_KEYS",
    "episode_path",
    "episode_bytes",
    "read_episode",
    "load_episode_arrays",
    "hash_arrays",
    "run_build_process",
    "episode_buffer",
    "write_minari",
    "write_expert_minari",
    "EXPERT_WRITER",
    "MAZE_KEY",
    "episode_maze",
]

ALGORITHM_NAME = "RandomShootingMPC"
EPISODES_DIR = "episodes"
EPISODE_KEYS = (
    "actions",
    "rewards",
    "terminations",
    "truncations",
    "observations",
    "sim_states",
    "channels",
    "seed",
    "success",
)
#: The episode file's array of a dataset on many mazes: the maze number the episode was played on.
MAZE_KEY = "maze"


class DatasetError(ValueError):
    """A dataset directory that is missing, incomplete, truncated or tampered with."""


# ---------------------------------------------------------------------------------- episode files
def episode_path(out_dir: Path, index: int) -> Path:
    return out_dir / EPISODES_DIR / f"episode_{index:06d}.npz"


def episode_maze(manifest: dict, index: int) -> int | None:
    """The training maze episode ``index`` of a dataset is played on: ``start_maze + index mod
    num_mazes`` for a dataset generated with ``num_mazes`` (its manifest names them), None — MERL's
    maze — otherwise. Fixed by the index alone, so the dataset does not depend on the workers."""
    num_mazes = manifest.get("num_mazes")
    if num_mazes is None:
        return None
    return int(manifest["start_maze"]) + index % int(num_mazes)


def _keys(data: Any, keys: tuple[str, ...] | None) -> tuple[str, ...]:
    """The arrays of an episode file: ``keys``, or None for the maze expert's (with the maze number
    where there is one)."""
    if keys is not None:
        return keys
    return (*EPISODE_KEYS, MAZE_KEY) if MAZE_KEY in data else EPISODE_KEYS


def episode_bytes(
    index: int, episode: dict[str, np.ndarray | np.generic], keys: tuple[str, ...] | None = None
) -> bytes:
    """The ``.npz`` file of episode ``index``: its arrays ``keys`` (None: the maze expert's,
    :data:`EPISODE_KEYS`) and the index, none of them pickled."""
    buffer = io.BytesIO()
    keys = _keys(episode, keys)
    arrays: dict[str, Any] = {key: episode[key] for key in keys}  # not savez's allow_pickle
    np.savez(buffer, index=np.int64(index), **arrays)
    return buffer.getvalue()


def read_episode(
    path: Path, index: int, expected_seed: int | None, expected_maze: int | None = None
) -> dict[str, np.ndarray]:
    """An episode file's arrays, checked for completeness and consistency (else DatasetError);
    ``expected_seed`` None accepts the file's own seed (a human recording's episodes have no seed
    derived from the run's). ``expected_maze``: the maze number the file's episode must have been
    played on (:func:`episode_maze`); None: MERL's maze, the file names none."""
    data = load_episode_arrays(path, EPISODE_KEYS)
    if int(data["index"]) != index or (expected_seed is not None and int(data["seed"]) != expected_seed):
        raise DatasetError(
            f"episode file {path} holds episode {int(data['index'])} with seed "
            f"{int(data['seed'])}, expected episode {index} with seed {expected_seed}"
        )
    maze = int(data[MAZE_KEY]) if MAZE_KEY in data else None
    if maze != expected_maze:
        raise DatasetError(
            f"episode file {path} holds an episode on {_maze_name(maze)}, expected {_maze_name(expected_maze)}"
        )
    steps = len(data["actions"])
    ends = data["terminations"] | data["truncations"]
    if (
        steps < 1
        or any(len(data[k]) != steps for k in ("rewards", "terminations", "truncations"))
        or any(len(data[k]) != steps + 1 for k in ("observations", "sim_states", "channels"))
        or not ends[-1]
        or ends[:-1].any()
        or data["actions"].min() < 0
        or data["actions"].max() > 4
    ):
        raise DatasetError(f"episode file {path} is inconsistent (lengths, episode end or actions)")
    return data


def load_episode_arrays(path: Path, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Every array of the episode file ``path`` (nothing unpickled); DatasetError if the file cannot
    be read or lacks one of ``keys`` or the ``index``."""
    try:
        with open(path, "rb") as handle, np.load(handle, allow_pickle=False) as archive:
            data = {key: archive[key] for key in archive.files}
    except Exception as exc:  # noqa: BLE001 - zipfile.BadZipFile, EOFError, ValueError, OSError …
        raise DatasetError(f"episode file {path} is unreadable ({type(exc).__name__}: {exc})") from None
    missing = [key for key in (*keys, "index") if key not in data]
    if missing:
        raise DatasetError(f"episode file {path} lacks {', '.join(missing)}")
    return data


def _maze_name(number: int | None) -> str:
    return "MERL's maze" if number is None else f"maze {number}"


def hash_arrays(digest, data: dict[str, np.ndarray], keys: tuple[str, ...] | None = None) -> None:
    """Feed an episode's arrays ``keys`` (None: the maze expert's, with the maze number where there
    is one) — names, dtypes, shapes, bytes — to a hash: identical episodes hash identically however
    their files were written."""
    for key in _keys(data, keys):
        array = np.ascontiguousarray(data[key])
        digest.update(f"{key}:{array.dtype.str}:{array.shape};".encode())
        digest.update(array.tobytes())


# ---------------------------------------------------------------------------- the build process
#: What the build process runs: the job comes on stdin as JSON (with this process's sys.path).
_BUILD_SCRIPT = (
    "import json, sys\n"
    "job = json.load(sys.stdin)\n"
    "sys.path[:] = job['sys_path']\n"
    "from bimgame.expert.minari_build import _build_process_main\n"
    "_build_process_main(job)\n"
)
#: Lines of a failed build process's error output kept in the error raised here.
_BUILD_ERROR_LINES = 30
#: Exit statuses of the build process for a full disk and an exceeded quota: the errno itself.
_DISK_FULL_EXITS = (errno.ENOSPC, errno.EDQUOT)
#: The writer of the expert's datasets (``module:function``, see :func:`run_build_process`).
EXPERT_WRITER = "bimgame.expert.minari_build:write_expert_minari"


def run_build_process(
    out_dir: Path,
    manifest: dict,
    build_root: Path,
    chunk: int,
    *,
    episodes: int | None = None,
    writer: str = EXPERT_WRITER,
    timeout: float | None = None,
    own_session: bool = False,
) -> None:
    """Write the Minari dataset of the episode files 0 … ``episodes``−1 (default
    ``manifest["episodes"]``) in ``out_dir`` into the datasets root ``build_root`` with a child
    process, handing Minari ``chunk`` episodes per write. ``writer`` names the function the child
    calls, ``writer(out_dir, manifest, episodes, chunk)`` (the expert's by default; human
    recordings have their own); ``timeout`` (s) gives a hung child up; ``own_session`` keeps a
    terminal's Ctrl-C from reaching the child.

    HDF5 does not survive a failed write cleanly: after a full disk every object it frees prints
    an error and the interpreter then often dies of a segmentation fault. In a child, that kills
    only the child; its error output stays here (captured) and is read for the cause: a full disk
    raises ``OSError(ENOSPC)``, anything else a RuntimeError with the output's last lines."""
    job = {
        "sys_path": sys.path,
        "parent_pid": os.getpid(),
        "out_dir": str(out_dir),
        "manifest": manifest,
        "episodes": manifest["episodes"] if episodes is None else int(episodes),
        "chunk": chunk,
        "writer": writer,
    }
    result = subprocess.run(
        [sys.executable, "-c", _BUILD_SCRIPT],
        input=json.dumps(job).encode(),
        capture_output=True,
        env={**os.environ, "MINARI_DATASETS_PATH": str(build_root)},
        start_new_session=own_session,
        timeout=timeout,
        check=False,
    )
    output = result.stderr.decode(errors="replace")
    if result.returncode == 0:
        sys.stderr.write(output)  # warnings, if any
        return
    code = result.returncode if result.returncode in _DISK_FULL_EXITS else disk_full_errno(output)
    if code is not None:
        raise OSError(code, os.strerror(code))
    how = f"killed by signal {-result.returncode}" if result.returncode < 0 else f"exit status {result.returncode}"
    tail = "\n".join(output.rstrip().splitlines()[-_BUILD_ERROR_LINES:])
    raise RuntimeError(f"building the Minari dataset of {out_dir} failed ({how}):\n{tail}")


def _build_process_main(job: dict) -> None:
    """The build process: run the job's writer, or exit with the errno of a full disk (else 1 with
    the traceback on stderr) without the interpreter's cleanup, which HDF5 objects left by a failed
    write can crash."""
    exit_when_parent_dies(job["parent_pid"])
    try:
        module, name = job["writer"].split(":")
        write = getattr(importlib.import_module(module), name)
        write(Path(job["out_dir"]), job["manifest"], int(job["episodes"]), int(job["chunk"]))
    except BaseException as error:  # noqa: BLE001 - the process's last word: every failure is an exit code
        code = disk_full_errno(error)
        if code is None:
            traceback.print_exc()
            code = 1
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def episode_buffer(index: int, data: dict[str, np.ndarray]) -> EpisodeBuffer:
    """An episode file's arrays as Minari's buffer (the physics states and channels as infos). An
    episode on one of many mazes gets its maze number as its reset options (with its seed, what
    ``reset(seed=seed, options=options)`` of the dataset's environment replays it from) and, per
    step, as ``infos["maze"]`` (as the env's ``info["maze"]``, which Minari's ``DataCollector``
    would record)."""
    infos = {"sim_state": data["sim_states"], "channel": data["channels"]}
    options = None
    if MAZE_KEY in data:
        number = int(data[MAZE_KEY])
        options = {"maze": number}
        infos["maze"] = np.full(len(data["observations"]), number, dtype=np.int64)
    return EpisodeBuffer(
        id=index,
        seed=int(data["seed"]),
        options=options,
        observations=data["observations"],
        actions=data["actions"],
        rewards=data["rewards"],
        terminations=data["terminations"],
        truncations=data["truncations"],
        infos=infos,
    )


def write_minari(
    manifest: dict,
    episodes: int,
    chunk: int,
    read: Callable[[int], dict[str, np.ndarray]],
    *,
    algorithm_name: str,
    description: str,
    author: str | None = None,
    buffer: Callable[[int, dict[str, np.ndarray]], EpisodeBuffer] = episode_buffer,
    env_kwargs: dict[str, Any] | None = None,
) -> None:
    """Write the Minari dataset of episodes 0 … ``episodes``−1 (``read(index)`` gives each file's
    arrays, ``buffer(index, arrays)`` their Minari buffer: the maze expert's by default) into the
    datasets root ``MINARI_DATASETS_PATH``, ``chunk`` episodes per write; the environment
    (``gym.make(manifest["env_id"], **env_kwargs)``; None: the maze's state env with the manifest's
    time limit and mazes) and the reference scores come from ``manifest``."""
    if env_kwargs is not None:
        kwargs = dict(env_kwargs)
    else:
        kwargs = {"obs_mode": "state"}
        if manifest["max_steps"] is not None:
            kwargs["max_episode_steps"] = manifest["max_steps"]
        if manifest.get("num_mazes") is not None:  # the env a dataset on many mazes was played in
            kwargs.update(num_mazes=manifest["num_mazes"], start_maze=manifest["start_maze"])
    env = gym.make(manifest["env_id"], **kwargs)
    if env.spec is None:  # gym.make always sets it
        raise RuntimeError(f"gym.make({manifest['env_id']!r}) made an env without a spec")
    env.spec.to_json()  # raises if the spec cannot be stored

    def buffers(indices: Iterable[int]) -> list[EpisodeBuffer]:
        return [buffer(index, read(index)) for index in indices]

    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r"`(code_permalink|author|author_email)` is set to None")
            dataset = minari.create_dataset_from_buffers(
                dataset_id=manifest["dataset_id"],
                buffer=buffers(range(min(chunk, episodes))),
                env=env,
                eval_env=env.spec,
                algorithm_name=algorithm_name,
                author=author,
                description=description,
                data_format="hdf5",
                **_reference_scores(manifest),
                requirements=[f"bimgame=={manifest['bimgame_version']}"],
            )
            for start in range(chunk, episodes, chunk):
                dataset.update_dataset_from_buffer(buffers(range(start, min(start + chunk, episodes))))
    finally:
        env.close()


def write_expert_minari(out_dir: Path, manifest: dict, episodes: int, chunk: int) -> None:
    """The expert dataset's writer (the build process runs it): episode i's file holds the episode
    of seed ``episode_seed(manifest["seed"], i)``, on maze ``episode_maze(manifest, i)``."""
    seed = manifest["seed"]
    write_minari(
        manifest,
        episodes,
        chunk,
        lambda index: read_episode(
            episode_path(out_dir, index), index, episode_seed(seed, index), episode_maze(manifest, index)
        ),
        algorithm_name=ALGORITHM_NAME,
        description=_description(manifest),
    )


def _reference_scores(manifest: dict) -> dict[str, float]:
    """Minari's ``ref_min_score``/``ref_max_score``: the task's random and expert reference returns
    (:mod:`bimgame.expert.references`), so that ``minari.get_normalized_score`` gives bimgame's
    normalised score; none for a run with its own time limit (the references use the task's), on
    random mazes (they are MERL's maze's) or on another puzzle (they are the maze's tasks')."""
    comparable = (
        manifest.get("max_steps") is None
        and manifest.get("num_mazes") is None
        and manifest.get("puzzle", "maze") == "maze"
    )
    pair = references_for(manifest["task"]) if comparable else None
    return {} if pair is None else {"ref_min_score": pair[0], "ref_max_score": pair[1]}


def _description(manifest: dict) -> str:
    limit = manifest["max_steps"] if manifest["max_steps"] is not None else "the task's registered limit"
    text = (
        f"Expert trajectories of bimgame's random-shooting MPC expert ({ALGORITHM_NAME}, acting on "
        f"simulator states) on {manifest['env_id']}: {manifest['episodes']} episodes; episode i starts "
        f"from reset(seed=bimgame.util.seeding.episode_seed({manifest['seed']}, i)); time limit {limit} steps; "
        f"MPC config {json.dumps(manifest['mpc_config'])}; bimgame {manifest['bimgame_version']}. "
        "Observations are state observations; infos['sim_state'] (T+1, S) MuJoCo physics states and "
        "infos['channel'] (T+1, n) task channels re-render pixel observations exactly "
        "(bimgame.expert.datasets.iterate_sequences(..., obs='pixels'))."
    )
    if manifest.get("num_mazes") is None:
        return text
    num_mazes, start = manifest["num_mazes"], manifest["start_maze"]
    return text + (
        f" Random mazes: episode i is played on training maze {start} + (i mod {num_mazes}) "
        f"(bimgame.sim.maze_sets.maze_number), in the environment made with num_mazes={num_mazes}, "
        f"start_maze={start}, from reset(seed=..., options={{'maze': number}}) (each episode's seed and "
        "options are its metadata, its maze number also infos['maze']); the state observations end "
        "with the maze's encoding (bimgame.envs.mazes.maze_encoding)."
    )
