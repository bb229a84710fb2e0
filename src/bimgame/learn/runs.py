"""A training run's directory: settings, checkpoints and metric logs.

Layout of ``RUN_DIR``::

    config.json          the run's settings (written once; a resumed run must match them)
    checkpoint.pt        latest checkpoint: weights, optimiser statistics, environment steps
    episodes.csv         one row per finished training episode
    updates.csv          losses, entropy, gradient norm and SPS against environment steps
    eval.csv             periodic evaluation (greedy and sampled episodes)
    tb/                  TensorBoard event files of the same numbers

Checkpoints are written atomically and read with ``torch.load(weights_only=True)``: a checkpoint is a
dict of tensors, numbers and strings only, so a file someone sent cannot run code when loaded.
CSV logs are appended line by line and flushed; a resumed run first drops the rows logged after its
checkpoint, so no step is counted twice.
"""

from __future__ import annotations

import contextlib
import csv
import io
import os
import json
import math
import pickle
from pathlib import Path
from typing import Any, Iterable, Iterator

import torch

from bimgame.util.files import atomic_write_bytes

__all__ = ["torch_threads", "run_kind", "KIND_A3C", "KIND_POLICY", "KIND_VALUE", "CheckpointError", "save_checkpoint", "load_checkpoint", "load_weights", "CsvLog",
           "MetricLog", "read_run_config", "CHECKPOINT", "CONFIG"]

CHECKPOINT = "checkpoint.pt"
CONFIG = "config.json"
#: What a run directory holds (config.json's "kind"; A3C runs have none).
KIND_A3C = "a3c"
KIND_POLICY = "pretrained-policy"
KIND_VALUE = "value-function"
_REQUIRED = {"model": dict, "step": int}


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
    return stored


def run_kind(run_dir: str | Path) -> str:
    """What a run directory (or a checkpoint file in one) holds: :data:`KIND_A3C`,
    :data:`KIND_POLICY`, :data:`KIND_VALUE` or another tool's kind (e.g. DAgger's)."""
    return read_run_config(run_dir).get("kind", KIND_A3C)


class CheckpointError(ValueError):
    """A checkpoint that cannot be used: missing, unreadable, unsafe, or not from a bimgame run."""


def save_checkpoint(path: str | Path, *, model: dict[str, torch.Tensor], step: int,
                    optimizer: dict | None = None, **extra: Any) -> Path:
    """Write a checkpoint atomically. ``extra`` values must be tensors, numbers, strings or
    containers of them (what ``weights_only`` loading accepts)."""
    payload = {"format": "bimgame-checkpoint-1", "model": {k: v.detach().clone() for k, v in model.items()},
               "step": int(step), **extra}
    if optimizer is not None:
        payload["optimizer"] = optimizer
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    return atomic_write_bytes(path, buffer.getvalue())


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Read a checkpoint safely; raises :class:`CheckpointError` naming what is wrong."""
    path = Path(path)
    if path.is_dir():
        path = path / CHECKPOINT
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:
        raise CheckpointError(f"refused to load {path}: it holds objects other than tensors and plain "
                              f"data (loading it could run code): {str(error).splitlines()[0]}") from None
    except (RuntimeError, EOFError, OSError, ValueError) as error:
        raise CheckpointError(f"cannot read checkpoint {path}: {error}") from None
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
    payload = load_checkpoint(source)
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


class CsvLog:
    """An append-only CSV file with a fixed header, flushed after every row."""

    def __init__(self, path: str | Path, fields: Iterable[str], *, step_field: str = "step",
                 keep_until: int | None = None):
        """``keep_until``: when resuming, drop existing rows whose ``step_field`` exceeds it
        (rewritten atomically); None starts a fresh file."""
        self.path = Path(path)
        self.fields = list(fields)
        rows: list[dict[str, str]] = []
        if keep_until is not None and self.path.is_file():
            with self.path.open(newline="") as handle:
                reader = csv.DictReader(handle)
                if reader.fieldnames == self.fields:
                    rows = [r for r in reader if _as_number(r.get(step_field)) <= keep_until]
        text = io.StringIO()
        writer = csv.DictWriter(text, self.fields)
        writer.writeheader()
        writer.writerows(rows)
        atomic_write_bytes(self.path, text.getvalue().encode())
        self._handle = self.path.open("a", newline="")
        self._writer = csv.DictWriter(self._handle, self.fields)

    def write(self, row: dict[str, Any]) -> None:
        self._writer.writerow({k: _format(row.get(k)) for k in self.fields})
        self._handle.flush()

    def close(self) -> None:
        self._handle.close()


def _as_number(text: str | None) -> float:
    try:
        return float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return math.inf


def _format(value: Any) -> Any:
    if isinstance(value, float):
        return f"{value:.6g}"
    return "" if value is None else value


class MetricLog:
    """CSV files plus TensorBoard scalars, keyed by environment steps."""

    def __init__(self, run_dir: str | Path, tables: dict[str, list[str]], *, resume_step: int | None = None,
                 tensorboard: bool = True):
        self.run_dir = Path(run_dir)
        self.tables = {name: CsvLog(self.run_dir / f"{name}.csv", ["step", *fields], keep_until=resume_step)
                       for name, fields in tables.items()}
        self.writer = None
        if tensorboard:
            # Lazy: importing TensorBoard's writer costs about a second, paid only by runs that log.
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(self.run_dir / "tb"), purge_step=resume_step)

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
        if self.writer is not None:
            self.writer.close()

