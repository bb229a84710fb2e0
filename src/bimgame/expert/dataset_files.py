"""The files of a dataset directory (:mod:`bimgame.expert.datasets` describes the layout) and their
checks: the generation manifest (with the mazes of a dataset on many mazes), the COMPLETE marker's
counts and its verification, leftovers of a killed run."""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.expert.minari_build import EPISODES_DIR, DatasetError, episode_path, hash_arrays
from bimgame.sim.maze_sets import UNLIMITED_MAZE_NUMBERS
from bimgame.util.files import atomic_write_bytes, file_sha256, reporting_full_disk
from bimgame.util.settings import is_integer

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "MANIFEST_NAME",
    "MARKER_NAME",
    "MINARI_DIR",
    "LOCK_NAME",
    "BUILD_PREFIX",
    "is_own_temporary",
    "read_manifest",
    "remove_stale_temporaries",
    "episode_totals",
    "data_path",
    "verify_marker",
    "maze_fields",
    "prepare_out_dir",
    "MANIFEST_KEYS",
]

FORMAT_NAME = "bimgame-expert-dataset"
FORMAT_VERSION = 1

MANIFEST_NAME = "generation.json"
MARKER_NAME = "COMPLETE"
MINARI_DIR = "minari"
LOCK_NAME = ".lock"
BUILD_PREFIX = ".minari-build-"


def is_own_temporary(name: str) -> bool:
    """Whether ``name`` is a temporary file of an interrupted manifest write."""
    return name.startswith(f".{MANIFEST_NAME}.") and name.endswith(".tmp")


#: The fields that decide the episodes' content: a resumed run must match them (the mazes' are absent
#: from a manifest of MERL's maze).
MANIFEST_KEYS = (
    "format_version",
    "task",
    "episodes",
    "seed",
    "max_steps",
    "mpc_config",
    "bimgame_version",
    "num_mazes",
    "start_maze",
)


def prepare_out_dir(out_dir: Path, manifest: dict, keys: tuple[str, ...] = MANIFEST_KEYS) -> None:
    """Create ``out_dir`` with its manifest, or check it is this run's (the same ``keys``: those that
    decide the episodes' content, the maze expert's by default); never touch anything else."""
    if out_dir.exists() and not out_dir.is_dir():
        raise NotADirectoryError(f"out_dir {out_dir} exists and is not a directory")
    manifest_path = out_dir / MANIFEST_NAME
    if manifest_path.exists():
        existing = read_manifest(out_dir, error=FileExistsError)
        differences = [
            f"{key}: {existing.get(key)!r} there, {manifest.get(key)!r} now"
            for key in keys
            if existing.get(key) != manifest.get(key)
        ]
        if differences:
            raise ValueError(
                f"{out_dir} holds a generation run with different arguments ({'; '.join(differences)}); "
                "use another directory, or the same arguments to resume or finish that run"
            )
        return
    if out_dir.exists():
        found = sorted(p.name + ("/" if p.is_dir() else "") for p in out_dir.iterdir() if not is_own_temporary(p.name))
        if found:
            shown = ", ".join(repr(name) for name in found[:5]) + (", …" if len(found) > 5 else "")
            raise FileExistsError(
                f"out_dir {out_dir} is not empty and is not a bimgame generation run (no {MANIFEST_NAME}; "
                f"found {len(found)} entries: {shown}); nothing was changed. Use a new or empty directory."
            )
    with reporting_full_disk(manifest_path):
        atomic_write_bytes(manifest_path, (json.dumps(manifest, indent=2) + "\n").encode())


def read_manifest(out_dir: Path, error: type[Exception] = DatasetError) -> dict:
    """``out_dir``'s generation manifest, checked (else ``error`` naming the problem)."""
    path = out_dir / MANIFEST_NAME
    try:
        manifest = json.loads(path.read_text())
    except FileNotFoundError:
        raise error(f"{out_dir} is not a bimgame dataset directory (no {MANIFEST_NAME})") from None
    except (OSError, ValueError) as exc:
        raise error(f"{path} cannot be read as a generation manifest ({exc})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT_NAME:
        raise error(f"{path} is not a bimgame generation manifest (format is not {FORMAT_NAME!r}); nothing was changed")
    if manifest.get("format_version") != FORMAT_VERSION:
        raise error(
            f"{path} has format version {manifest.get('format_version')!r}; this bimgame reads version {FORMAT_VERSION}"
        )
    return manifest


def maze_fields(num_mazes: Any, start_maze: Any) -> dict[str, int]:
    """The manifest fields of a dataset on many mazes — ``num_mazes`` training mazes from number
    ``start_maze`` on, episode ``j`` on maze ``start_maze + j mod num_mazes`` — or {} for MERL's maze
    alone (``num_mazes`` None: the manifest stays as it always was). Checked: ``ValueError`` naming
    the argument and what is allowed."""
    if num_mazes is None:
        if start_maze != 0:
            raise ValueError(f"start_maze {start_maze!r} needs num_mazes (the number of training mazes)")
        return {}
    if not (is_integer(num_mazes) and num_mazes >= 1):
        raise ValueError(
            f"num_mazes must be an integer >= 1 (or None: MERL's maze), got {num_mazes!r}; a dataset must name "
            "its mazes (episode j is played on maze start_maze + j mod num_mazes), and num_mazes=0, the "
            "learners' unlimited set of a new maze per episode, names none"
        )
    last = UNLIMITED_MAZE_NUMBERS - int(num_mazes)
    if not (is_integer(start_maze) and 0 <= start_maze <= last):
        raise ValueError(
            f"start_maze must be an integer in 0..{last} (maze numbers stay below {UNLIMITED_MAZE_NUMBERS} "
            f"with num_mazes={num_mazes}), got {start_maze!r}"
        )
    return {"num_mazes": int(num_mazes), "start_maze": int(start_maze)}


def remove_stale_temporaries(out_dir: Path, prefixes: tuple[str, ...] = (BUILD_PREFIX,)) -> None:
    """Leftovers of a killed run inside our own directory: partial builds (directories starting
    with one of ``prefixes``) and temporary episode files."""
    for prefix in prefixes:
        for path in out_dir.glob(f"{prefix}*"):
            shutil.rmtree(path, ignore_errors=True)
    for path in (out_dir / EPISODES_DIR).glob(".episode_*.tmp"):
        path.unlink(missing_ok=True)


def episode_totals(
    episodes: int, read: Callable[[int], dict[str, np.ndarray]], keys: tuple[str, ...] | None = None
) -> dict[str, Any]:
    """Steps, successes and the content hash of episode files 0 … ``episodes``−1 (``read(index)``
    gives a file's checked arrays, ``keys`` the hashed ones: None for the maze expert's): what the
    COMPLETE marker records."""
    content = hashlib.sha256()
    totals = {"steps": 0, "successes": 0}
    for index in range(episodes):
        data = read(index)
        hash_arrays(content, data, keys)
        totals["steps"] += len(data["actions"])
        totals["successes"] += bool(data["success"])
    return {**totals, "content_sha256": content.hexdigest()}


def data_path(out_dir: Path, dataset_id: str) -> Path:
    return out_dir / MINARI_DIR / dataset_id / "data"


def verify_marker(out_dir: Path, manifest: dict, *, hashes: bool) -> dict:
    """The COMPLETE marker, after checking it and every file it lists (else DatasetError)."""
    marker_path = out_dir / MARKER_NAME
    episodes = manifest["episodes"]
    if not marker_path.exists():
        present = sum(episode_path(out_dir, i).exists() for i in range(episodes))
        raise DatasetError(
            f"dataset in {out_dir} is incomplete ({present} of {episodes} episode files, no {MARKER_NAME} "
            "marker): its generation was interrupted or is still running; run the generation again with "
            "the same arguments to finish it"
        )
    try:
        marker = json.loads(marker_path.read_text())
        files = marker["files"]
        if not isinstance(files, dict):
            raise TypeError("files is not a mapping")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DatasetError(f"{marker_path} is damaged ({exc})") from None
    if marker.get("episodes") != episodes or marker.get("dataset_id") != manifest["dataset_id"]:
        raise DatasetError(
            f"{marker_path} describes {marker.get('episodes')!r} episodes of "
            f"{marker.get('dataset_id')!r}, the manifest {episodes} of {manifest['dataset_id']!r}"
        )
    expected = {episode_path(out_dir, i).relative_to(out_dir).as_posix() for i in range(episodes)}
    expected |= {
        (Path(MINARI_DIR) / manifest["dataset_id"] / "data" / name).as_posix()
        for name in ("metadata.json", "main_data.hdf5")
    }
    unlisted = sorted(expected - set(files))
    if unlisted:
        raise DatasetError(f"{marker_path} does not cover {', '.join(unlisted[:3])}")
    for name, entry in files.items():
        path = out_dir / name
        if not path.is_file():
            raise DatasetError(f"dataset in {out_dir} is missing {name}")
        size = path.stat().st_size
        if size != entry["size"]:
            raise DatasetError(
                f"{path} has {size} bytes, {entry['size']} when the dataset was completed (truncated or modified)"
            )
        if hashes and file_sha256(path) != entry["sha256"]:
            raise DatasetError(
                f"{path} differs from the file the dataset was completed with (SHA-256 mismatch: corrupted or modified)"
            )
    return marker
