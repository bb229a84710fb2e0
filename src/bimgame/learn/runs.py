"""A training run's directory: its layout, its kind and settings, and whether a run may go into it.

Layout of ``RUN_DIR``::

    config.json          the run's settings and its "kind" (written once; a resumed run must match
                         them; a reproduction updates its dataset's path when the reproduction moved)
    checkpoint.pt        latest checkpoint: weights, optimiser statistics, environment steps, seconds
    episodes.csv         one row per finished training episode
    updates.csv          losses, entropy, gradient norm and SPS against environment steps
    eval.csv             periodic evaluation (greedy and sampled episodes)
    summary.json         how the run ended
    tb/                  TensorBoard event files of the same numbers
    .lock                held while a process writes the run (:mod:`bimgame.learn.run_lock`)

A new run goes into a new or empty directory only (:func:`prepare_new_run`), never over someone's
files, and writes its ``config.json`` and a first checkpoint before anything else, so a run
directory always has both; ``--resume`` continues a run of its own kind only
(:func:`check_resumable`). A new run that fails before it has trained anything removes what it wrote
(:func:`discard_new_run`), so the same command can be run again. The learners go through these steps
in one order, holding the lock, with :class:`bimgame.learn.run_dir.RunDirectory`.

JSON files (:func:`write_run_json`) are strict JSON: a NaN or infinite number is written as ``null``;
a file that cannot be written (a full disk) raises :class:`~bimgame.util.files.FileWriteError`, which
names it. The checkpoint is written and read by :mod:`bimgame.learn.checkpoints`, the CSV logs and
``tb/`` by :mod:`bimgame.learn.metric_logs`.
"""

from __future__ import annotations

import contextlib
import json
import math
import numbers
import os
import shutil
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

import torch

from bimgame.learn.run_lock import LOCK
from bimgame.util import files
from bimgame.util.files import FileWriteError

__all__ = [
    "torch_threads",
    "run_kind",
    "KIND_A3C",
    "KIND_POLICY",
    "KIND_VALUE",
    "KIND_DAGGER",
    "KIND_PPO",
    "read_run_config",
    "read_run_settings",
    "CHECKPOINT",
    "CONFIG",
    "SUMMARY",
    "write_run_json",
    "finite_json",
    "prepare_new_run",
    "check_resumable",
    "discard_new_run",
    "directory_entries",
]

CHECKPOINT = "checkpoint.pt"
CONFIG = "config.json"
SUMMARY = "summary.json"
#: What a run directory holds (config.json's "kind"; A3C runs stored before it was recorded have none).
KIND_A3C = "a3c"
KIND_POLICY = "pretrained-policy"
KIND_VALUE = "value-function"
KIND_DAGGER = "dagger-policy"
KIND_PPO = "ppo"
T = TypeVar("T")


def write_run_json(path: str | Path, values: dict[str, Any]) -> Path:
    """``values`` as indented JSON with sorted keys (as :func:`~bimgame.util.files.write_json` writes
    it), written atomically; a NaN or infinite number becomes ``null`` (:func:`finite_json`), so every
    JSON reader opens the file — Python's ``json`` would write ``NaN``, which is not JSON. Raises
    :class:`~bimgame.util.files.FileWriteError` (naming the file) when it fails."""
    text = json.dumps(finite_json(values), indent=2, sort_keys=True, allow_nan=False) + "\n"
    try:
        return files.atomic_write_bytes(path, text.encode())
    except OSError as error:
        raise FileWriteError.from_error(path, error) from error


def finite_json(value: Any) -> Any:
    """``value`` with every non-finite real number (NaN, ±inf; Python's or NumPy's) replaced by None,
    in nested dicts, lists and tuples (tuples become lists, as JSON has them); finite NumPy reals
    become Python floats. Other values are returned as they are."""
    if isinstance(value, dict):
        return {key: finite_json(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(item) for item in value]
    if isinstance(value, numbers.Real) and not isinstance(value, numbers.Integral):
        return float(value) if math.isfinite(value) else None
    return value


@contextlib.contextmanager
def torch_threads(count: int | None = None) -> Iterator[int]:
    """Run a block with ``count`` intra-op threads (default: the cores, at most 2 — what this
    project's reference machine has — and never more than the caller has set, so
    ``torch.set_num_threads(1)`` before a call is respected), restoring the caller's setting
    afterwards: a library call must not change how the rest of the process computes."""
    previous = torch.get_num_threads()
    count = count if count is not None else max(1, min(2, os.cpu_count() or 1, previous))
    torch.set_num_threads(count)
    try:
        yield count
    finally:
        torch.set_num_threads(previous)


def read_run_config(run_dir: str | Path) -> dict[str, Any]:
    """The ``config.json`` of a run directory (or of the run a file in it belongs to): the one
    reader of it, raising ``ValueError`` that names the file when it is missing or not a JSON object."""
    path = Path(run_dir)
    path = path.parent if path.is_file() else path
    if not (path / CONFIG).is_file():
        raise ValueError(f"{path} is not a bimgame run (no {CONFIG})")
    try:
        stored = json.loads((path / CONFIG).read_text())
    except (OSError, ValueError) as error:
        raise ValueError(f"cannot read {path / CONFIG}: {error}") from None
    if not isinstance(stored, dict):
        raise ValueError(f"{path / CONFIG} is not a JSON object")
    _fill_earlier_network_settings(stored)
    return stored


#: Network settings added after runs were first stored, with the value every earlier run had: a
#: stored network without them is the paper's (their defaults now depend on the observation).
EARLIER_NETWORK_SETTINGS = {"aux_heads": False, "asymmetric_critic": False, "precision": "fp32"}


def _fill_earlier_network_settings(block: dict[str, Any]) -> None:
    """Give every stored settings block that describes a network (it has ``obs`` and ``tilt_input``)
    the :data:`EARLIER_NETWORK_SETTINGS` it lacks, at any depth, so that a run stored before they
    existed resumes and loads as the network it is."""
    if "obs" in block and "tilt_input" in block:
        for name, value in EARLIER_NETWORK_SETTINGS.items():
            block.setdefault(name, value)
    for value in block.values():
        if isinstance(value, dict):
            _fill_earlier_network_settings(value)


def read_run_settings(run_dir: str | Path, key: str, parse: Callable[[dict[str, Any]], T]) -> T:
    """``parse(config[key])`` for the run in ``run_dir``: a missing or malformed block, or settings that
    ``parse`` refuses, raise ``ValueError`` naming the ``config.json``."""
    path = Path(run_dir)
    path = (path.parent if path.is_file() else path) / CONFIG
    block = read_run_config(path.parent).get(key)
    if not isinstance(block, dict):
        raise ValueError(f"{path} has no {key!r} settings (a JSON object); it is not a run of this kind, or damaged")
    try:
        return parse(block)
    except (ValueError, TypeError, KeyError) as error:
        raise ValueError(f"{path}: {error}") from None


def run_kind(run_dir: str | Path) -> str:
    """What a run directory (or a checkpoint file in one) holds: :data:`KIND_A3C`, :data:`KIND_POLICY`,
    :data:`KIND_VALUE`, :data:`KIND_DAGGER` or another tool's kind. A ``config.json`` without a kind
    is an A3C run's from before A3C recorded it."""
    return read_run_config(run_dir).get("kind", KIND_A3C)


# ------------------------------------------------------------------------- run directories
def _is_temporary(name: str) -> bool:
    """A temporary of an atomic write (``.NAME.xxxx.tmp``) left by a killed process."""
    return name.startswith(".") and name.endswith(".tmp")


def directory_entries(directory: Path) -> list[str]:
    """The names in ``directory`` (folders with a trailing ``/``), sorted, without the temporaries
    of atomic writes and without the run's lock file (:data:`~bimgame.learn.run_lock.LOCK`: held
    while a process writes the run, left behind by one that was killed; it is nobody's content)."""
    return sorted(
        p.name + ("/" if p.is_dir() else "")
        for p in directory.iterdir()
        if not _is_temporary(p.name) and p.name != LOCK
    )


def _shown(entries: Sequence[str]) -> str:
    """How many ``entries`` a directory holds, naming the first five."""
    return (
        f"found {len(entries)} entr{'y' if len(entries) == 1 else 'ies'}: "
        + ", ".join(repr(name) for name in entries[:5])
        + (", …" if len(entries) > 5 else "")
    )


def prepare_new_run(run_dir: str | Path, *, what: str, flag: str, kind: str | None = None) -> bool:
    """Check that a new run of ``what`` (e.g. "A3C") may go into ``run_dir`` — a new or empty
    directory — before anything is written; returns whether the directory does not exist yet (so
    that :func:`discard_new_run` may remove it). A directory holding anything else is refused,
    naming what is in it: nothing of the user's is ever overwritten. ``kind``: the run kind that
    ``--resume`` continues (None: the tool cannot resume)."""
    run_dir = Path(run_dir)
    if run_dir.exists() and not run_dir.is_dir():
        raise ValueError(f"{flag} {run_dir} exists and is not a directory")
    if not run_dir.exists():
        return True
    found = directory_entries(run_dir)
    if not found:
        return False
    if (run_dir / CONFIG).is_file():
        hint = _existing_run_hint(run_dir, what=what, flag=flag, kind=kind)
        raise ValueError(f"{run_dir} already holds a run; {hint}. Nothing was changed.")
    raise ValueError(
        f"{run_dir} is not empty and is not {_article(what)} {what} run (no {CONFIG}; {_shown(found)}); "
        f"nothing was changed. Use a new or empty {flag}."
    )


def _existing_run_hint(run_dir: Path, *, what: str, flag: str, kind: str | None) -> str:
    """What to do instead of starting a new run of ``what`` in ``run_dir``, which holds a run: resume
    it if it is of ``kind``, else choose another directory (naming the kind it holds, if readable)."""
    try:
        actual: str | None = run_kind(run_dir)
    except ValueError:
        actual = None
    if kind is not None and actual == kind:
        return f"pass --resume to continue it or choose a new {flag}"
    if actual is not None and kind is not None:
        return f"choose a new {flag} (it is a {actual} run, not {_article(what)} {what} run)"
    return f"choose a new {flag}"


def _article(word: str) -> str:
    """The indefinite article before ``word`` ("an A3C run", "a DAgger run")."""
    return "an" if word[:1].upper() in "AEIOU" else "a"


def check_resumable(
    run_dir: str | Path, *, kind: str, what: str, flag: str = "--run-dir", needs: Iterable[str] = ()
) -> dict[str, Any]:
    """Check that ``run_dir`` holds a run of ``kind`` that ``--resume`` can continue — its
    ``config.json`` and the files in ``needs`` (e.g. its checkpoint) — and return its config. Refuses,
    naming what is missing or what the directory holds instead."""
    run_dir = Path(run_dir)
    if not (run_dir / CONFIG).is_file():
        there = _what_is_there(run_dir, what)
        raise ValueError(
            f"--resume: {run_dir} has no {CONFIG}: {there}; start a new run without --resume (in a new or empty {flag})"
        )
    stored = read_run_config(run_dir)
    actual = stored.get("kind", KIND_A3C)  # the kind is missing in A3C runs stored before it was recorded
    if actual != kind:
        raise ValueError(
            f"--resume: {run_dir} holds a {actual} run, not {_article(what)} {what} run ({kind}); nothing was changed"
        )
    missing = [name for name in needs if not (run_dir / name).is_file()]
    if missing:
        raise ValueError(
            f"--resume: {run_dir} has no {' or '.join(missing)}, so the {what} run in it cannot be "
            f"continued (its logs were kept unchanged). Start anew without --resume in a new "
            f"{flag}, or remove {run_dir} first"
        )
    return stored


def _what_is_there(run_dir: Path, what: str) -> str:
    """What ``run_dir``, which holds no run, is instead: missing, empty, or other files (named)."""
    found = directory_entries(run_dir) if run_dir.is_dir() else []
    if found:
        return f"{run_dir} is not {_article(what)} {what} run ({_shown(found)})"
    if not run_dir.exists():
        return f"{run_dir} does not exist"
    return f"{run_dir} is empty"


def discard_new_run(run_dir: str | Path, created: bool, names: Iterable[str]) -> None:
    """Remove what a new run wrote (the files and folders ``names``, and their temporaries) after it
    failed before training anything, so that it blocks no rerun; and the directory itself if the run
    created it and it is empty now. Nothing else is touched."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        return
    names = set(names)
    for path in run_dir.iterdir():
        own_temporary = _is_temporary(path.name) and any(path.name.startswith(f".{name}.") for name in names)
        if path.name in names or own_temporary:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                with contextlib.suppress(OSError):
                    path.unlink()
    if created:
        with contextlib.suppress(OSError):
            run_dir.rmdir()  # only if empty
