"""The directory protocol of an expert-data generation run, one for both puzzles' datasets
(:mod:`bimgame.expert.datasets`, the circular maze's; :mod:`bimgame.expert.labyrinth_datasets`, the
labyrinth's): what makes a run resumable, repairable and safe to interrupt, whatever its episodes are.

:func:`run_generation` takes the run's manifest, how to read a saved episode file back (checked)
and how to play the episodes still missing; it

1. creates the directory with its manifest, or checks that it is this run's (:func:`prepare_out_dir`);
2. holds a lock against a second writer;
3. returns at once for a finished run whose ``COMPLETE`` marker verifies, or repairs one that does not;
4. plays only the episodes without an intact file, writing each atomically as it finishes (a progress
   bar shows episodes done and success so far);
5. builds the Minari dataset in a child process and a temporary root, moves it into place, and writes
   the ``COMPLETE`` marker last (:func:`write_marker`).

A full disk stops the run with :class:`~bimgame.util.files.DiskFullError` naming the file and how many
episodes are saved; nothing finished is lost. What differs between the puzzles is an
:class:`EpisodeFormat`: which manifest keys decide the episodes' content, the arrays of an episode file
and the Minari writer.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.expert.dataset_files import (
    BUILD_PREFIX,
    FORMAT_NAME,
    FORMAT_VERSION,
    LOCK_NAME,
    MANIFEST_KEYS,
    MARKER_NAME,
    MINARI_DIR,
    data_path,
    episode_totals,
    prepare_out_dir,
    remove_stale_temporaries,
    verify_marker,
)
from bimgame.expert.minari_build import (
    EPISODES_DIR,
    EXPERT_WRITER,
    DatasetError,
    episode_bytes,
    episode_path,
    run_build_process,
)
from bimgame.expert.pool import EpisodeOutcome, episode_progress
from bimgame.util.files import atomic_write_bytes, exclusive_lock, file_sha256, reporting_full_disk

__all__ = ["EpisodeFormat", "EpisodeReader", "EpisodePlayer", "run_generation", "write_marker", "BUILD_CHUNK"]

#: Episodes handed to Minari per write (bounds memory for large datasets).
BUILD_CHUNK = 64
#: Reads saved episode ``index`` back, checked against the run (DatasetError if it is damaged).
EpisodeReader = Callable[[int], dict[str, np.ndarray]]
#: Plays the episodes of the given indices, yielding each as it finishes: (index, arrays, seconds).
EpisodePlayer = Callable[[list[int]], Iterable[EpisodeOutcome]]


@dataclasses.dataclass(frozen=True)
class EpisodeFormat:
    """What a puzzle's generation run stores: the defaults are the circular maze expert's."""

    manifest_keys: tuple[str, ...] = MANIFEST_KEYS
    """The manifest fields that decide the episodes' content: a resumed run must match them."""
    episode_keys: tuple[str, ...] | None = None
    """The arrays of an episode file (None: the maze expert's, with the maze number where there is one)."""
    writer: str = EXPERT_WRITER
    """The Minari build process's writer (``module:function``, :func:`run_build_process`)."""


def run_generation(
    out_dir: Path,
    manifest: dict[str, Any],
    episode_format: EpisodeFormat,
    *,
    read: EpisodeReader,
    play: EpisodePlayer,
    progress: bool,
) -> None:
    """Generate (or resume, repair or verify) the run of ``manifest`` in ``out_dir`` (absolute): see
    the module notes. ``read`` and ``play`` are the puzzle's; the progress bar is labelled with the
    manifest's task."""
    episodes = manifest["episodes"]
    with reporting_full_disk(None, lambda: _resume_advice(out_dir, episodes), default_path=out_dir):
        prepare_out_dir(out_dir, manifest, episode_format.manifest_keys)
        with exclusive_lock(
            out_dir / LOCK_NAME, f"another process is generating into {out_dir}; wait for it to finish"
        ):
            marker_path = out_dir / MARKER_NAME
            if marker_path.exists():
                try:
                    verify_marker(out_dir, manifest, hashes=True)
                    return
                except DatasetError as error:  # repair: regenerate what is damaged, rebuild
                    warnings.warn(f"{out_dir}: {error}; repairing", stacklevel=3)
                    marker_path.unlink()
            remove_stale_temporaries(out_dir)
            (out_dir / EPISODES_DIR).mkdir(exist_ok=True)
            done_success, todo = _saved_episodes(episodes, read, out_dir)
            if todo:
                with episode_progress(
                    progress, f"expert on {manifest['task']}", episodes, len(done_success), sum(done_success)
                ) as update:
                    for index, episode, _ in play(todo):
                        path = episode_path(out_dir, index)
                        with reporting_full_disk(path, lambda: _resume_advice(out_dir, episodes)):
                            atomic_write_bytes(path, episode_bytes(index, episode, episode_format.episode_keys))
                        update(bool(episode["success"]))
            _build_minari(out_dir, manifest, read, episode_format)


def _saved_episodes(episodes: int, read: EpisodeReader, out_dir: Path) -> tuple[list[bool], list[int]]:
    """The success of each episode already saved intact, and the indices still to play (a damaged
    file is played again, with a warning)."""
    done_success: list[bool] = []
    todo: list[int] = []
    for index in range(episodes):
        if episode_path(out_dir, index).exists():
            try:
                done_success.append(bool(read(index)["success"]))
                continue
            except DatasetError as error:
                warnings.warn(f"{error}; generating episode {index} again", stacklevel=4)
        todo.append(index)
    return done_success, todo


def _resume_advice(out_dir: Path, episodes: int) -> str:
    saved = sum(episode_path(out_dir, i).exists() for i in range(episodes))
    return f"rerun the same command to resume ({saved} of {episodes} episodes are saved)"


def _build_minari(out_dir: Path, manifest: dict[str, Any], read: EpisodeReader, episode_format: EpisodeFormat) -> None:
    """Build the Minari dataset from the episode files in a temporary datasets root (in a child
    process), move it into place, then write the COMPLETE marker (the last step)."""
    episodes = manifest["episodes"]
    totals = episode_totals(episodes, read, episode_format.episode_keys)
    build_root = Path(tempfile.mkdtemp(prefix=BUILD_PREFIX, dir=out_dir))
    try:
        with reporting_full_disk(data_path(out_dir, manifest["dataset_id"]) / "main_data.hdf5"):
            run_build_process(out_dir, manifest, build_root, BUILD_CHUNK, writer=episode_format.writer)
        final = out_dir / MINARI_DIR
        if final.exists():  # an earlier build of this run that never got its marker
            shutil.rmtree(final)
        os.replace(build_root, final)
    finally:
        shutil.rmtree(build_root, ignore_errors=True)
    with reporting_full_disk(out_dir / MARKER_NAME):
        write_marker(out_dir, manifest["dataset_id"], episodes, totals)


def write_marker(out_dir: Path, dataset_id: str, episodes: int, totals: dict[str, Any]) -> None:
    """Write the COMPLETE marker — the last step of a build: the counts and content hash of
    :func:`episode_totals`, and every episode and Minari file's size and SHA-256."""
    files = {}
    for path in [episode_path(out_dir, i) for i in range(episodes)] + sorted(
        p for p in (out_dir / MINARI_DIR).rglob("*") if p.is_file()
    ):
        files[path.relative_to(out_dir).as_posix()] = {"size": path.stat().st_size, "sha256": file_sha256(path)}
    marker = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "dataset_id": dataset_id,
        "episodes": episodes,
        "steps": totals["steps"],
        "successes": totals["successes"],
        "content_sha256": totals["content_sha256"],
        "files": files,
    }
    atomic_write_bytes(out_dir / MARKER_NAME, (json.dumps(marker, indent=1) + "\n").encode())
