"""The expert's datasets as the learners read them: every episode of a dataset directory of either
puzzle for a task (relabelled on the maze), and the checks that a dataset can teach a task and a kind
of action. Shared by pre-training (:mod:`bimgame.learn.pretrain`) and DAgger's demonstrations
(:mod:`bimgame.learn.dagger`), which do not import each other.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bimgame.envs.puzzles import LABYRINTH, puzzle
from bimgame.expert.datasets import dataset_manifest, iterate_sequences, load_dataset
from bimgame.expert.episode import Episode, relabel
from bimgame.expert.labyrinth_datasets import load_labyrinth_sequences
from bimgame.sim.maze import MazeSpec
from bimgame.sim.tasks import Task, parse_task
from bimgame.util.progress import ProgressBar

__all__ = ["load_sequences", "check_dataset_task", "dataset_action_type"]


def load_sequences(
    data_dir: str | Path,
    task: str | Task,
    obs: str,
    gamma: float,
    spec: MazeSpec | None = None,
    *,
    progress: bool = False,
    gate_bearings: bool = False,
    surroundings: bool = False,
    motion: bool = False,
) -> list[Episode]:
    """Every episode of a dataset directory, relabelled for ``task`` (see
    :func:`~bimgame.expert.episode.relabel`); a labyrinth dataset's episodes as they are (its task is
    the dataset's own, see :func:`check_dataset_task`). ``gate_bearings``: state observations on many
    mazes end with them (:func:`~bimgame.expert.datasets.iterate_sequences`); ``surroundings``: the
    labyrinth's state observations end with the marble's (:func:`load_labyrinth_sequences`); ``motion``:
    CyberRunner's observations end with the marble's observed velocity, pixel observations are two frames."""
    manifest = dataset_manifest(data_dir)
    check_dataset_task(manifest, task, data_dir)
    if manifest.get("puzzle") == LABYRINTH:
        return load_labyrinth_sequences(
            data_dir, obs=obs, gamma=gamma, progress=progress, surroundings=surroundings, motion=motion
        )
    if surroundings or motion:
        name = "surroundings" if surroundings else "motion"
        raise ValueError(
            f"{name} is part of the labyrinth's observations; the dataset in {data_dir} is of the circular maze"
        )
    spec = spec or MazeSpec.merl()
    task = parse_task(task, spec)
    data_task = parse_task(manifest["task"], spec)
    if task.walls_to_pass(spec) > data_task.walls_to_pass(spec):
        raise ValueError(
            f"the dataset in {data_dir} holds {data_task.value} episodes, which end before a "
            f"{task.value} episode would; use a dataset of {task.value} or a harder task "
            f"(FULL labels every task)"
        )
    dataset = load_dataset(data_dir)
    sequences = []
    with ProgressBar(f"reading {obs} episodes", dataset.total_episodes, enabled=progress, transient=True) as bar:
        for sequence in iterate_sequences(dataset, obs=obs, gamma=gamma, gate_bearings=gate_bearings):
            sequences.append(relabel(sequence, task, gamma, spec))
            bar.update(advance=1)
    return sequences


def check_dataset_task(manifest: dict[str, Any], task: str | Task, data_dir: str | Path) -> None:
    """Refuse to learn ``task`` from a dataset of the other puzzle, or a labyrinth task from another
    layout's dataset (a layout's episodes are not relabelled), naming both."""
    data_task = str(manifest["task"])
    wanted = puzzle(task)
    labyrinth_data = manifest.get("puzzle") == LABYRINTH
    if labyrinth_data == wanted.is_maze or (labyrinth_data and data_task != wanted.task):
        raise ValueError(
            f"the dataset in {data_dir} holds {data_task} episodes, which cannot teach {wanted.task}: "
            f"use a dataset of {wanted.task}"
            + (" (bimgame generate --task " + wanted.task + ")" if not wanted.is_maze else "")
        )


def dataset_action_type(manifest: dict[str, Any]) -> str:
    """The kind of the actions a dataset holds: the maze expert's and human play are discrete; a
    labyrinth dataset names its own (``action_type``)."""
    return str(manifest.get("action_type", "discrete"))
