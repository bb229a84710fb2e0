"""The files of a dataset directory (:mod:`bimgame.expert.datasets` describes the layout) and their
checks: the generation manifest, the COMPLETE marker's counts and its verification, leftovers of a
killed run."""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.expert.minari_build import EPISODES_DIR, DatasetError, episode_path, hash_arrays
from bimgame.util.files import file_sha256

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


def remove_stale_temporaries(out_dir: Path, prefixes: tuple[str, ...] = (BUILD_PREFIX,)) -> None:
    """Leftovers of a killed run inside our own directory: partial builds (directories starting
    with one of ``prefixes``) and temporary episode files."""
    for prefix in prefixes:
        for path in out_dir.glob(f"{prefix}*"):
            shutil.rmtree(path, ignore_errors=True)
    for path in (out_dir / EPISODES_DIR).glob(".episode_*.tmp"):
        path.unlink(missing_ok=True)


def episode_totals(episodes: int, read: Callable[[int], dict[str, np.ndarray]]) -> dict[str, Any]:
    """Steps, successes and the content hash of episode files 0 … ``episodes``−1 (``read(index)``
    gives a file's checked arrays): what the COMPLETE marker records."""
    content = hashlib.sha256()
    totals = {"steps": 0, "successes": 0}
    for index in range(episodes):
        data = read(index)
        hash_arrays(content, data)
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
