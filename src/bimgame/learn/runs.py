"""A training run's directory: settings, checkpoints and metric logs.

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

JSON files (:func:`write_run_json`) are strict JSON: a NaN or infinite number is written as ``null``.

Checkpoints are written atomically and read with ``torch.load(weights_only=True)``: a checkpoint is a
dict of tensors, numbers and strings only, so a file someone sent cannot run code when loaded.
CSV logs are appended line by line and flushed; a resumed run first keeps the rows logged before its
checkpoint (:func:`resumed_rows`), so no step is counted twice, and refuses a log it did not write.
A file that cannot be written (a full disk) raises :class:`~bimgame.util.files.FileWriteError`, which names it.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import numbers
import os
import re
import shutil
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

import torch

from bimgame.learn.run_lock import LOCK
from bimgame.util import files
from bimgame.util.files import FileWriteError

__all__ = ["torch_threads", "run_kind", "KIND_A3C", "KIND_POLICY", "KIND_VALUE", "KIND_DAGGER", "CheckpointError",
           "save_checkpoint", "load_checkpoint", "load_weights", "apply_weights", "CsvLog", "MetricLog",
           "read_run_config", "read_run_settings", "CHECKPOINT", "CONFIG", "SUMMARY", "write_run_json", "finite_json",
           "prepare_new_run", "check_resumable", "discard_new_run", "directory_entries", "resumed_rows"]

CHECKPOINT = "checkpoint.pt"
CONFIG = "config.json"
SUMMARY = "summary.json"
#: What a run directory holds (config.json's "kind"; A3C runs stored before it was recorded have none).
KIND_A3C = "a3c"
KIND_POLICY = "pretrained-policy"
KIND_VALUE = "value-function"
KIND_DAGGER = "dagger-policy"
_REQUIRED = {"model": dict, "step": int}
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
    return sorted(p.name + ("/" if p.is_dir() else "") for p in directory.iterdir()
                  if not _is_temporary(p.name) and p.name != LOCK)


def _shown(entries: Sequence[str]) -> str:
    return (f"found {len(entries)} entr{'y' if len(entries) == 1 else 'ies'}: "
            + ", ".join(repr(name) for name in entries[:5]) + (", …" if len(entries) > 5 else ""))


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
        try:
            actual = run_kind(run_dir)
        except ValueError:
            actual = None
        if kind is not None and actual == kind:
            hint = f"pass --resume to continue it or choose a new {flag}"
        else:
            hint = f"choose a new {flag}" + (f" (it is a {actual} run, not {_article(what)} {what} run)"
                                             if actual is not None and kind is not None and actual != kind else "")
        raise ValueError(f"{run_dir} already holds a run; {hint}. Nothing was changed.")
    raise ValueError(f"{run_dir} is not empty and is not {_article(what)} {what} run (no {CONFIG}; {_shown(found)}); "
                     f"nothing was changed. Use a new or empty {flag}.")


def _article(word: str) -> str:
    return "an" if word[:1].upper() in "AEIOU" else "a"


def check_resumable(run_dir: str | Path, *, kind: str, what: str, flag: str = "--run-dir",
                    needs: Iterable[str] = ()) -> dict[str, Any]:
    """Check that ``run_dir`` holds a run of ``kind`` that ``--resume`` can continue — its
    ``config.json`` and the files in ``needs`` (e.g. its checkpoint) — and return its config. Refuses,
    naming what is missing or what the directory holds instead."""
    run_dir = Path(run_dir)
    if not (run_dir / CONFIG).is_file():
        found = directory_entries(run_dir) if run_dir.is_dir() else []
        there = f"{run_dir} is not {_article(what)} {what} run ({_shown(found)})" if found else \
            f"{run_dir} does not exist" if not run_dir.exists() else f"{run_dir} is empty"
        raise ValueError(f"--resume: {run_dir} has no {CONFIG}: {there}; start a new run without --resume "
                         f"(in a new or empty {flag})")
    stored = read_run_config(run_dir)
    actual = stored.get("kind", KIND_A3C)  # the kind is missing in A3C runs stored before it was recorded
    if actual != kind:
        raise ValueError(f"--resume: {run_dir} holds a {actual} run, not {_article(what)} {what} run ({kind}); "
                         f"nothing was changed")
    missing = [name for name in needs if not (run_dir / name).is_file()]
    if missing:
        raise ValueError(f"--resume: {run_dir} has no {' or '.join(missing)}, so the {what} run in it cannot be "
                         f"continued (its logs were kept unchanged). Start anew without --resume in a new "
                         f"{flag}, or remove {run_dir} first")
    return stored


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


# ------------------------------------------------------------------------------ checkpoints
class CheckpointError(ValueError):
    """A checkpoint that cannot be used: missing, unreadable, unsafe, or not from a bimgame run."""


def save_checkpoint(path: str | Path, *, model: dict[str, torch.Tensor], step: int,
                    optimizer: dict | None = None, **extra: Any) -> Path:
    """Write a checkpoint atomically (:class:`~bimgame.util.files.FileWriteError` naming it if that fails). ``extra``
    values must be tensors, numbers, strings or containers of them (what ``weights_only`` loading
    accepts)."""
    payload = {"format": "bimgame-checkpoint-1", "model": {k: v.detach().clone() for k, v in model.items()},
               "step": int(step), **extra}
    if optimizer is not None:
        payload["optimizer"] = optimizer
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    try:
        return files.atomic_write_bytes(path, buffer.getvalue())
    except OSError as error:
        raise FileWriteError.from_error(path, error) from error


def _load_failure(path: Path, error: BaseException) -> CheckpointError:
    """Why ``torch.load(weights_only=True)`` refused ``path``, in our words: torch's own message
    advises loading with ``weights_only=False``, which would run whatever code the file holds, so none
    of its advice is passed on."""
    text = str(error)
    # torch words it two ways: "Unsupported global: GLOBAL x.y" and "unsupported GLOBAL x.y whose module ...".
    unsafe = re.search(r"[Uu]nsupported (?:global: )?GLOBAL ([\w.]+)", text)
    if unsafe:
        return CheckpointError(f"refused to load {path}: it holds objects other than tensors and plain data "
                               f"({unsafe.group(1)}); loading such a file could run code, so bimgame never does")
    if isinstance(error, EOFError) or "failed finding central directory" in text:
        return CheckpointError(f"cannot read checkpoint {path}: it is truncated (an unfinished copy or download?)")
    reason = re.search(r"WeightsUnpickler error:\s*(.+?)\s*(?:\n\n|$)", text, re.S)
    detail = reason.group(1) if reason else text.split(". ")[0]
    detail = " ".join(detail.split())
    if "weights_only" in detail or not detail:
        detail = type(error).__name__
    return CheckpointError(f"cannot read checkpoint {path}: it is not a PyTorch checkpoint, or it is damaged "
                           f"({detail})")


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Read a checkpoint safely; raises :class:`CheckpointError` naming what is wrong."""
    path = Path(path)
    if path.is_dir():
        path = path / CHECKPOINT
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path}")
    try:
        size = path.stat().st_size
    except OSError as error:
        raise CheckpointError(f"cannot read checkpoint {path}: {error.strerror or error}") from None
    if size == 0:
        raise CheckpointError(f"cannot read checkpoint {path}: the file is empty (0 bytes; truncated, or never "
                              f"written to the end)")
    try:
        with warnings.catch_warnings():
            # A damaged file can claim any pickle protocol; torch's warning about it says nothing useful here.
            warnings.filterwarnings("ignore", message="Detected pickle protocol", category=UserWarning)
            payload = torch.load(path, map_location="cpu", weights_only=True)
    except OSError as error:
        raise CheckpointError(f"cannot read checkpoint {path}: {error.strerror or error}") from None
    except Exception as error:  # noqa: BLE001 - damaged bytes make the unpickler raise IndexError, KeyError, struct.error…
        raise _load_failure(path, error) from None
    if not isinstance(payload, dict) or payload.get("format") != "bimgame-checkpoint-1":
        raise CheckpointError(f"{path} is not a bimgame checkpoint (no 'format': 'bimgame-checkpoint-1')")
    for key, kind in _REQUIRED.items():
        if not isinstance(payload.get(key), kind):
            raise CheckpointError(f"checkpoint {path} lacks {key!r} ({kind.__name__})")
    bad = [k for k, v in payload["model"].items() if not torch.is_tensor(v)]
    if bad:
        raise CheckpointError(f"checkpoint {path}: model entries {bad} are not tensors")
    nonfinite = [k for k, v in payload["model"].items() if v.is_floating_point() and not torch.isfinite(v).all()]
    if nonfinite:
        raise CheckpointError(f"checkpoint {path}: weights {nonfinite} are not finite")
    return payload


def load_weights(module: torch.nn.Module, source: str | Path) -> int:
    """Load a checkpoint's (or run directory's) weights into ``module``; returns the checkpoint's
    step. Shapes must match exactly."""
    return apply_weights(module, load_checkpoint(source), source)


def apply_weights(module: torch.nn.Module, payload: dict[str, Any], source: str | Path) -> int:
    """Put the weights of a checkpoint already read (:func:`load_checkpoint`) from ``source`` into
    ``module``; returns its step. Shapes must match exactly."""
    expected = module.state_dict()
    missing = sorted(set(expected) - set(payload["model"]))
    unexpected = sorted(set(payload["model"]) - set(expected))
    mismatched = [k for k in expected if k in payload["model"] and payload["model"][k].shape != expected[k].shape]
    if missing or unexpected or mismatched:
        raise CheckpointError(
            f"weights in {source} do not fit this network: missing {missing}, unexpected {unexpected}, "
            f"shape mismatch {[(k, tuple(payload['model'][k].shape), tuple(expected[k].shape)) for k in mismatched]}")
    module.load_state_dict(payload["model"])
    return payload["step"]


# ------------------------------------------------------------------------------------- logs
def resumed_rows(path: str | Path, fields: Sequence[str], before: int, *, keep_equal: bool = False,
                 step_field: str = "step") -> list[dict[str, str]]:
    """The rows of the CSV log ``path`` that a run resumed from a checkpoint at step ``before`` keeps:
    those logged strictly before it (also those at exactly ``before`` with ``keep_equal``, for a table
    whose rows at a checkpoint's step were logged before the checkpoint was written). A last line cut
    off by a kill or a full disk is dropped. A log this run did not write — another header, a row
    that does not parse — is refused (``ValueError`` naming the file), before anything is changed:
    its rows are never dropped silently. A missing file has no rows."""
    path = Path(path)
    if not path.is_file():
        return []
    try:
        with path.open(encoding="utf-8", newline="") as handle:
            text = handle.read()
    except (OSError, UnicodeDecodeError) as error:
        raise ValueError(f"cannot read the log {path} to resume: {error}") from None
    lines = text.splitlines(keepends=True)
    if lines and not lines[-1].endswith("\n"):
        lines.pop()  # a row cut off mid-write: it was never complete
    reader = csv.reader(lines)
    header = next(reader, None)
    if header != list(fields):
        raise ValueError(f"cannot resume: {path} has the header {','.join(header) if header else '(none: empty)'} "
                         f"but this run writes {','.join(fields)}; it was not written by this run (or by another "
                         f"version of bimgame). Nothing was changed: move the file away to resume without its "
                         f"rows, or start a new run")
    kept = []
    for number, values in enumerate(reader, start=2):
        if len(values) != len(header):
            raise ValueError(f"cannot resume: {path} line {number} has {len(values)} fields, its header "
                             f"{len(header)}; nothing was changed")
        row = dict(zip(header, values, strict=True))
        try:
            step = float(row[step_field])
        except ValueError:
            raise ValueError(f"cannot resume: {path} line {number}: {step_field} {row[step_field]!r} is not a "
                             f"number; nothing was changed") from None
        if step < before or (keep_equal and step == before):
            kept.append(row)
    return kept


class CsvLog:
    """An append-only CSV file with a fixed header, flushed after every row; write failures raise
    :class:`~bimgame.util.files.FileWriteError` naming the file."""

    def __init__(self, path: str | Path, fields: Iterable[str], *, rows: Iterable[dict[str, Any]] = ()):
        """Start the file (atomically) with its header and ``rows`` (e.g. a resumed run's
        :func:`resumed_rows`)."""
        self.path = Path(path)
        self.fields = list(fields)
        text = io.StringIO()
        writer = csv.DictWriter(text, self.fields)
        writer.writeheader()
        writer.writerows(rows)
        try:
            files.atomic_write_bytes(self.path, text.getvalue().encode())
            self._handle = self.path.open("a", newline="", encoding="utf-8")
        except OSError as error:
            raise FileWriteError.from_error(self.path, error) from error
        self._writer = csv.DictWriter(self._handle, self.fields)

    def write(self, row: dict[str, Any]) -> None:
        try:
            self._writer.writerow({k: _format(row.get(k)) for k in self.fields})
            self._handle.flush()
        except OSError as error:
            raise FileWriteError.from_error(self.path, error) from error

    def close(self) -> None:
        """Close the file. Every row was flushed when written, so after a failed write (which was
        reported) closing cannot lose more: a second failure is not raised."""
        with contextlib.suppress(OSError):
            self._handle.close()


def _format(value: Any) -> Any:
    if isinstance(value, float):
        return f"{value:.6g}"
    return "" if value is None else value


class MetricLog:
    """CSV files plus TensorBoard scalars, keyed by environment steps.

    ``resume_step``: the step of the checkpoint a resumed run continues from; each table keeps its
    rows logged before it (:func:`resumed_rows`; ``keep_at_resume_step`` names the tables whose rows at
    exactly that step are kept too). Every table is read and checked before any is rewritten, so a
    refusal changes nothing. ``kept`` holds the kept rows by table."""

    def __init__(self, run_dir: str | Path, tables: dict[str, list[str]], *, resume_step: int | None = None,
                 keep_at_resume_step: Iterable[str] = (), tensorboard: bool = True):
        self.run_dir = Path(run_dir)
        keep_equal = set(keep_at_resume_step)
        fields = {name: ["step", *columns] for name, columns in tables.items()}
        self.kept: dict[str, list[dict[str, str]]] = {name: [] for name in tables}
        if resume_step is not None:
            self.kept = {name: resumed_rows(self._path(name), fields[name], resume_step, keep_equal=name in keep_equal)
                         for name in tables}
        self.tables: dict[str, CsvLog] = {}
        try:
            for name in tables:
                self.tables[name] = CsvLog(self._path(name), fields[name], rows=self.kept[name])
        except BaseException:
            self.close()
            raise
        self.writer = None
        if tensorboard:
            # Lazy: importing TensorBoard's writer costs about a second, paid only by runs that log.
            from torch.utils.tensorboard import SummaryWriter

            # Events at or after purge_step are hidden: those of the steps the CSV files dropped.
            purge = None if resume_step is None else resume_step + (1 if keep_equal >= set(tables) else 0)
            self.writer = SummaryWriter(str(self.run_dir / "tb"), purge_step=purge)

    def _path(self, table: str) -> Path:
        return self.run_dir / f"{table}.csv"

    def write(self, table: str, step: int, values: dict[str, Any], *, scalars: Iterable[str] = ()) -> None:
        self.tables[table].write({"step": step, **values})
        if self.writer is not None:
            for key in scalars:
                value = values.get(key)
                if value is not None and math.isfinite(float(value)):
                    self.writer.add_scalar(f"{table}/{key}", float(value), step)

    def close(self) -> None:
        for table in self.tables.values():
            table.close()
        if getattr(self, "writer", None) is not None:
            with contextlib.suppress(OSError):
                self.writer.close()
