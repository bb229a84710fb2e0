"""Expert trajectories on CyberRunner's labyrinth as `Minari <https://minari.farama.org>`_ datasets:
parallel, resumable generation, and whole episodes for pre-training a policy (behaviour cloning).

The labyrinth's counterpart of :mod:`bimgame.expert.datasets` (the circular maze's), with the same
directory and guarantees::

    generation.json                  what is generated: puzzle "labyrinth", task, layout, action type,
                                     control rate, run seed, episodes, MPC config, versions
    episodes/episode_000000.npz …    one file per finished episode, written atomically (the
                                     resumable source: a restart skips the episodes already here)
    minari/                          a Minari datasets root (point MINARI_DATASETS_PATH here)
      bimgame/labyrinth-easy-expert-v0/data/{metadata.json, main_data.hdf5}
    COMPLETE                         written last: counts, a content hash and every file's SHA-256

Episode ``i`` is the labyrinth's MPC expert (:class:`~bimgame.expert.labyrinth_mpc.LabyrinthMPC`) on
a state-observation :class:`~bimgame.envs.labyrinth_env.LabyrinthEnv` from
``reset(seed=episode_seed(seed, i))``, its generator seeded with the same number: the dataset does
not depend on the number of workers, the backend or how often the run was interrupted. What an
episode file holds is :mod:`bimgame.expert.labyrinth_episodes`'s; the Minari dataset holds the same
per episode: ``observations`` (T+1, 17), ``actions`` ((T, 2) float32 or (T,) int64), ``rewards``,
``terminations``, ``truncations``, and infos ``sim_state``, ``tilt``, ``segment``, ``progress`` (T+1
each). A rerun with other arguments on an existing directory is refused naming them; a lock keeps
two runs from writing one directory; a full disk stops the run with
:class:`~bimgame.util.files.DiskFullError`, losing no finished episode.

:func:`load_labyrinth_sequences` gives the episodes as :class:`~bimgame.expert.episode.Episode`
records with state observations, or pixels or CyberRunner's observation re-rendered exactly from the
stored physics states and path progress (:meth:`LabyrinthEnv.observe_state`).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import minari
import numpy as np

import bimgame
from bimgame.envs.labyrinth_cyberrunner import MOTION_OBS_MODES
from bimgame.envs.labyrinth_env import LABYRINTH_ACTION_TYPES, LABYRINTH_CONTROL_RATES, LabyrinthEnv
from bimgame.envs.labyrinth_surroundings import Surroundings
from bimgame.envs.puzzles import LABYRINTH, LABYRINTH_TASKS
from bimgame.expert.dataset_files import (
    FORMAT_NAME,
    FORMAT_VERSION,
    read_manifest,
    verify_marker,
)
from bimgame.expert.datasets import dataset_summary, load_dataset
from bimgame.expert.episode import Episode
from bimgame.expert.generation import EpisodeFormat, run_generation
from bimgame.expert.labyrinth_episodes import (
    EPISODE_KEYS,
    LABYRINTH_WRITER,
    episode_time_limit,
    labyrinth_episode_job,
    read_labyrinth_episode,
)
from bimgame.expert.labyrinth_mpc import LabyrinthMPCConfig
from bimgame.expert.minari_build import DatasetError, episode_path
from bimgame.expert.pool import EpisodeOutcome, check_generation, run_jobs
from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.util.progress import ProgressBar
from bimgame.util.seeding import episode_seed

__all__ = [
    "generate_labyrinth_dataset",
    "load_labyrinth_sequences",
    "load_labyrinth_demonstrations",
    "load_labyrinth_dataset",
    "labyrinth_dataset_manifest",
    "read_dataset_episode",
    "labyrinth_dataset_summary",
    "labyrinth_dataset_id",
    "LABYRINTH_MANIFEST_KEYS",
    "SEQUENCE_OBS",
]

#: The manifest fields that decide the episodes' content: a resumed run must match them.
LABYRINTH_MANIFEST_KEYS = (
    "format_version",
    "puzzle",
    "task",
    "action_type",
    "control_hz",
    "episodes",
    "seed",
    "max_steps",
    "mpc_config",
    "bimgame_version",
)
#: The observations :func:`load_labyrinth_sequences` gives: the stored state observations, or one
#: re-rendered by the env's observation mode of that name; ``cyberrunner`` (a learner's name for it,
#: :data:`~bimgame.envs.puzzles.LABYRINTH_OBS`) is the flat form, as the learners' envs step it.
SEQUENCE_OBS = {
    "state": "state",
    "pixels": "pixels",
    "cyberrunner": "cyberrunner_flat",
    "cyberrunner_flat": "cyberrunner_flat",
}
#: What a labyrinth run stores (:func:`~bimgame.expert.generation.run_generation`).
LABYRINTH_FORMAT = EpisodeFormat(
    manifest_keys=LABYRINTH_MANIFEST_KEYS, episode_keys=EPISODE_KEYS, writer=LABYRINTH_WRITER
)
# The expert's default settings (frozen: one instance serves every call).
_DEFAULT_CONFIG = LabyrinthMPCConfig()


# ---------------------------------------------------------------------------------- generation
def labyrinth_dataset_id(task: str, action_type: str = "continuous", control_hz: int = 55) -> str:
    """The Minari dataset id of the expert's episodes on a labyrinth task, e.g.
    ``bimgame/labyrinth-easy-expert-v0`` (continuous actions at 55 Hz, CyberRunner's);
    ``-discrete`` and ``-30hz`` mark the other action type and rate."""
    name = _labyrinth_task(task).lower()
    name += "-discrete" if action_type == "discrete" else ""
    name += "" if control_hz == 55 else f"-{control_hz}hz"
    return f"bimgame/{name}-expert-v0"


def generate_labyrinth_dataset(
    out_dir: str | Path,
    task: str = "LABYRINTH-EASY",
    episodes: int = 100,
    *,
    seed: int = 0,
    action_type: str = "continuous",
    control_hz: int = 55,
    config: LabyrinthMPCConfig = _DEFAULT_CONFIG,
    workers: int | None = None,
    backend: str = "local",
    ray_address: str | None = None,
    progress: bool = True,
    max_steps: int | None = None,
) -> Path:
    """Generate ``episodes`` expert episodes on the labyrinth ``task`` into ``out_dir`` and build the
    Minari dataset from them; returns ``out_dir`` (absolute).

    Resumable: every finished episode is saved at once; run again with the same arguments after an
    interruption and only the missing (or damaged) episodes are generated; a finished dataset is
    verified and returned as is. Different arguments on an existing run, or a directory holding
    anything else, raise an error naming them and change nothing.

    Args:
        out_dir: the run's directory (created; must be new, empty or this run's).
        task: LABYRINTH-EASY, LABYRINTH-MEDIUM or LABYRINTH-HARD (any case).
        episodes: number of episodes; episode ``i`` starts from ``reset(seed=episode_seed(seed, i))``.
        seed: the run seed (a non-negative integer).
        action_type: "continuous" (tilt-rate fractions, CyberRunner's) or "discrete" (0..4).
        control_hz: action rate, 55 (CyberRunner's) or 30 Hz.
        config: the expert's settings (``nthread`` is forced to 1: each worker plans on one thread;
            it does not change the actions).
        workers: parallel episodes (default ``os.cpu_count()``): local processes started with
            "spawn" (a script calling this needs the ``if __name__ == "__main__":`` guard), or the
            CPUs Ray starts locally; 1 runs the episodes in this process.
        backend: ``"local"`` (a process pool) or ``"ray"`` (Ray tasks; this process writes every file).
        ray_address: a Ray cluster to join (with ``backend="ray"``); None starts Ray locally.
        progress: show a progress bar (episodes done, success so far, ETA) on stderr.
        max_steps: time limit per episode (default: CyberRunner's 54.5 s, 3000 steps at 55 Hz).

    Raises:
        DiskFullError: (an ``OSError``) the disk filled up; the message names the file. Every
            episode saved before stays; run again with the same arguments once there is room.
    """
    out_dir = Path(out_dir).absolute()  # Minari joins relative dataset paths onto its root
    task = _labyrinth_task(task)
    workers = check_generation(
        "generate_labyrinth_dataset",
        episodes=episodes,
        seed=seed,
        workers=workers,
        backend=backend,
        ray_address=ray_address,
        max_steps=max_steps,
        progress=progress,
    )
    if action_type not in LABYRINTH_ACTION_TYPES:
        raise ValueError(f"unknown action_type {action_type!r}; allowed: {', '.join(LABYRINTH_ACTION_TYPES)}")
    if isinstance(control_hz, bool) or control_hz not in LABYRINTH_CONTROL_RATES:
        raise ValueError(f"control_hz must be one of {LABYRINTH_CONTROL_RATES} (Hz), got {control_hz!r}")
    if not isinstance(config, LabyrinthMPCConfig):
        raise TypeError(f"config must be a LabyrinthMPCConfig, got {type(config).__name__}")
    config = dataclasses.replace(config, nthread=1)
    manifest = _manifest(task, action_type, int(control_hz), int(episodes), int(seed), config, max_steps)
    _generate(out_dir, manifest, config, progress, int(workers), backend, ray_address)
    return out_dir


def _manifest(
    task: str, action_type: str, control_hz: int, episodes: int, seed: int, config: LabyrinthMPCConfig, max_steps: Any
) -> dict[str, Any]:
    layout = LABYRINTH_TASKS[task]
    return {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "puzzle": LABYRINTH,
        "task": task,
        "layout": layout,
        "action_type": action_type,
        "control_hz": control_hz,
        "episodes": episodes,
        "seed": seed,
        "max_steps": None if max_steps is None else int(max_steps),
        "time_limit": episode_time_limit(control_hz, max_steps),
        "mpc_config": dataclasses.asdict(config),
        "bimgame_version": bimgame.__version__,
        "dataset_id": labyrinth_dataset_id(task, action_type, control_hz),
        "env_id": f"BiMGame/Labyrinth-{layout.capitalize()}-v0",
        "minari_version": minari.__version__,
    }


def _generate(
    out_dir: Path,
    manifest: dict[str, Any],
    config: LabyrinthMPCConfig,
    progress: bool,
    workers: int,
    backend: str,
    ray_address: str | None,
) -> None:
    """The labyrinth expert's run on :func:`~bimgame.expert.generation.run_generation`'s protocol."""

    def play(todo: list[int]) -> Iterator[EpisodeOutcome]:
        arguments = [
            (manifest["layout"], manifest["action_type"], manifest["control_hz"], index, manifest["seed"], config,
             manifest["max_steps"])
            for index in todo
        ]  # fmt: skip
        return run_jobs(labyrinth_episode_job, arguments, workers=workers, backend=backend, ray_address=ray_address)

    read = functools.partial(read_dataset_episode, out_dir, manifest)
    run_generation(out_dir, manifest, LABYRINTH_FORMAT, read=read, play=play, progress=progress)


def read_dataset_episode(out_dir: Path, manifest: dict[str, Any], index: int) -> dict[str, np.ndarray]:
    """Episode ``index``'s file in ``out_dir`` (its arrays), checked against the run's manifest
    (:func:`labyrinth_dataset_manifest`)."""
    return read_labyrinth_episode(
        episode_path(out_dir, index), index, episode_seed(manifest["seed"], index), manifest["action_type"]
    )


# ------------------------------------------------------------------------------------- loading
def labyrinth_dataset_manifest(data_dir: str | Path) -> dict[str, Any]:
    """What a labyrinth dataset directory holds (its ``generation.json``); DatasetError if it is no
    dataset directory or a dataset of the circular maze."""
    data_dir = Path(data_dir).absolute()
    if not data_dir.is_dir():
        raise DatasetError(f"dataset directory {data_dir} does not exist or is not a directory")
    manifest = read_manifest(data_dir)
    if manifest.get("puzzle") != LABYRINTH:
        raise DatasetError(
            f"{data_dir} holds a dataset of the circular maze (task {manifest.get('task')}), not of the labyrinth; "
            "read it with bimgame.expert.datasets"
        )
    return manifest


def load_labyrinth_dataset(data_dir: str | Path, *, verify: bool = True) -> minari.MinariDataset:
    """A finished labyrinth dataset as a ``minari.MinariDataset``, after the checks of
    :func:`bimgame.expert.datasets.load_dataset` (the marker, every file's size and, with ``verify``,
    SHA-256)."""
    labyrinth_dataset_manifest(data_dir)
    return load_dataset(data_dir, verify=verify)


def labyrinth_dataset_summary(data_dir: str | Path) -> dict[str, Any]:
    """Counts and disk use of a finished labyrinth dataset (:func:`bimgame.expert.datasets.dataset_summary`:
    episodes, steps, success rate, mean length, bytes) with its task, action type and control rate."""
    manifest = labyrinth_dataset_manifest(data_dir)
    fields = ("task", "layout", "action_type", "control_hz", "time_limit")
    return {**{key: manifest[key] for key in fields}, **dataset_summary(data_dir)}


def load_labyrinth_sequences(
    data_dir: str | Path,
    *,
    obs: str = "state",
    gamma: float,
    progress: bool = False,
    surroundings: bool = False,
    motion: bool = False,
) -> list[Episode]:
    """Every episode of a finished labyrinth dataset as an :class:`~bimgame.expert.episode.Episode`
    (what pre-training learns from), after checking the COMPLETE marker and every file's SHA-256.

    ``obs`` (:data:`SEQUENCE_OBS`): ``"state"``, the stored (T, 17) float32 observations;
    ``"pixels"`` (T, 1, 84, 84) uint8 (T, 2, 84, 84 with ``motion``) or ``"cyberrunner"`` /
    ``"cyberrunner_flat"`` (T, 4110) float32, re-rendered from each step's physics state and path
    progress by the env's own observation code (:meth:`LabyrinthEnv.observe_state`: equal to what
    the env returned). ``actions`` are the executed ones ((T, 2) float32 continuous, (T,) int64
    discrete), ``tilt`` the board's tilt (rad) at each action, ``state_obs`` the state observations
    whatever ``obs`` is, ``returns`` discounted by ``gamma``, ``id`` the episode's index.
    ``progress``: a progress bar while reading. ``surroundings`` (``obs="state"`` only): each
    observation ends with the marble's surroundings, computed from its stored position
    (:mod:`bimgame.envs.labyrinth_surroundings`; what ``LabyrinthEnv(surroundings=True)`` observes).
    ``motion`` (``obs="cyberrunner"`` or ``"pixels"``): each observation ends with the marble's
    observed velocity (CyberRunner's) or begins with the previous step's frame (pixels), from the
    stored physics states of it and the step before (what ``LabyrinthEnv(motion=True)`` observes).
    """
    if obs not in SEQUENCE_OBS:
        raise ValueError(f"unknown obs {obs!r}; allowed: {', '.join(SEQUENCE_OBS)}")
    if not (isinstance(gamma, (int, float)) and not isinstance(gamma, bool) and 0.0 <= gamma <= 1.0):
        raise ValueError(f"gamma must be a number in [0, 1], got {gamma!r}")
    if surroundings and obs != "state":
        raise ValueError(f"surroundings are part of the state observation, not of obs {obs!r}")
    if motion and SEQUENCE_OBS[obs] not in MOTION_OBS_MODES:
        raise ValueError(
            "motion is part of CyberRunner's observation (obs 'cyberrunner') and of pixels (obs 'pixels'), "
            f"not of obs {obs!r}"
        )
    data_dir = Path(data_dir).absolute()
    manifest = labyrinth_dataset_manifest(data_dir)
    around = Surroundings(LabyrinthSpec.layout(manifest["layout"])) if surroundings else None
    verify_marker(data_dir, manifest, hashes=True)
    renderer = None
    if obs != "state":
        renderer = LabyrinthEnv(
            manifest["layout"],
            action_type=manifest["action_type"],
            control_hz=manifest["control_hz"],
            obs_mode=SEQUENCE_OBS[obs],
            motion=motion,
        )
    sequences = []
    try:
        with ProgressBar(f"reading {obs} episodes", manifest["episodes"], enabled=progress, transient=True) as bar:
            for index in range(manifest["episodes"]):
                sequence = _sequence(read_dataset_episode(data_dir, manifest, index), index, gamma, renderer)
                if around is not None:
                    observed = np.concatenate([sequence.obs, around.of(sequence.obs[:, :2])], axis=1)
                    sequence = dataclasses.replace(sequence, obs=observed)
                sequences.append(sequence)
                bar.update(advance=1)
    finally:
        if renderer is not None:
            renderer.close()
    return sequences


def load_labyrinth_demonstrations(data_dir: str | Path) -> tuple[str, list[tuple[np.ndarray, np.ndarray]]]:
    """The task of a finished labyrinth dataset and, per episode that reached the goal, its physics
    states and path progress (m) before every step and after the last: ``(sim_states (T+1, S),
    progress (T+1,))``, what demonstration starts are made of
    (:class:`~bimgame.learn.path_starts.DemoPathStarts`). Every file is verified first."""
    data_dir = Path(data_dir).absolute()
    manifest = labyrinth_dataset_manifest(data_dir)
    verify_marker(data_dir, manifest, hashes=True)
    demonstrations = []
    for index in range(manifest["episodes"]):
        data = read_dataset_episode(data_dir, manifest, index)
        if bool(data["success"]):
            demonstrations.append((data["sim_states"], data["progress"]))
    return str(manifest["task"]), demonstrations


def _sequence(data: dict[str, np.ndarray], index: int, gamma: float, renderer: LabyrinthEnv | None) -> Episode:
    """One episode file's arrays as an :class:`Episode`: the observation before each action, from
    the file (state) or rendered by ``renderer``."""
    steps = len(data["actions"])
    states = data["observations"][:steps]
    if renderer is None:
        frames = states
    else:
        sim_states = data["sim_states"][:steps]
        previous = [None, *sim_states[:-1]]  # the first observation has no motion
        pairs = zip(sim_states, data["progress"][:steps], previous, strict=True)
        frames = np.stack([renderer.observe_state(state, float(progress), before) for state, progress, before in pairs])
    return Episode.from_steps(
        obs=frames,
        actions=data["actions"],
        rewards=data["rewards"],
        tilt=data["tilt"][:steps],
        gamma=gamma,
        terminated=bool(data["terminations"][-1]),
        truncated=bool(data["truncations"][-1]),
        id=index,
        state_obs=states,
    )


# ------------------------------------------------------------------------------------- checks
def _labyrinth_task(task: Any) -> str:
    """The canonical name of a labyrinth task (any case); ValueError naming the allowed ones."""
    name = task.upper() if isinstance(task, str) else ""
    if name not in LABYRINTH_TASKS:
        raise ValueError(
            f"unknown labyrinth task {task!r}; allowed: {', '.join(LABYRINTH_TASKS)} "
            "(the circular maze's tasks: bimgame.expert.datasets.generate_dataset)"
        )
    return name
