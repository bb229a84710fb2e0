"""Where the pieces of a reproduction are computed: the :class:`Backend` interface that
:func:`bimgame.experiments.reproduce.reproduce` drives, :class:`PieceOutcome` (what came of one
piece) and :class:`LocalBackend`, which computes
one piece at a time in this process, in the reproduction directory itself.

The Ray backend, which runs the pieces side by side on the nodes of a cluster, is
:class:`bimgame.experiments.cluster.RayBackend`. The driver does the bookkeeping for both: it
decides which pieces may start (all they need is finished), records every outcome in
``status.json`` and shows progress; a backend only computes.
"""

from __future__ import annotations

import dataclasses
import time
import traceback
from collections import deque
from pathlib import Path
from typing import Protocol

from bimgame.experiments.budgets import Budget
from bimgame.experiments.grid import Piece
from bimgame.experiments.kinds import kind_of
from bimgame.learn.runs import torch_threads

__all__ = ["Backend", "PieceOutcome", "LocalBackend", "run_piece", "error_text"]


@dataclasses.dataclass
class PieceOutcome:
    """What came of computing one piece."""

    piece: Piece
    seconds: float
    """Wall time of this attempt (on a cluster: on the node that computed it, without the wait in
    the queue)."""
    note: str = ""
    """The runner's note for ``status.json`` ("resumed from its checkpoint", …)."""
    error: str | None = None
    """``"Type: message"`` when the piece failed."""
    traceback: str | None = None
    node: str | None = None
    """The cluster node that computed it (None locally)."""

    @property
    def failed(self) -> bool:
        return self.error is not None


class Backend(Protocol):
    """What the driver needs from a place that computes pieces."""

    @property
    def capacity(self) -> int | None:
        """Pieces in flight at once (None: as many as are ready; the cluster queues them by CPUs)."""

    @property
    def queues(self) -> bool:
        """Whether a submitted piece may wait in a queue before it runs (then "submitted", not "running")."""

    def submit(self, piece: Piece) -> None:
        """Start computing ``piece``; every piece it needs is finished in the reproduction directory."""

    def next_outcome(self) -> PieceOutcome:
        """Block until a submitted piece is done (or failed) and its outputs are in the reproduction
        directory. ``KeyboardInterrupt`` passes through; the pieces in flight are then unfinished."""

    def close(self) -> None:
        """Stop whatever is still in flight and release the backend's resources."""


def run_piece(piece: Piece, budget: Budget, root: Path) -> str:
    """Compute (or continue) ``piece`` in ``root`` with the budget's torch threads; returns the
    runner's note. A piece that stopped before it finished raises ``KeyboardInterrupt``."""
    with torch_threads(budget.torch_threads):
        return kind_of(piece).run(piece, budget, root)


def error_text(error: BaseException) -> str:
    """How ``status.json`` names an error: ``"Type: message"``."""
    return f"{type(error).__name__}: {error}"


class LocalBackend:
    """One piece at a time, in this process (A3C runs start their own worker processes), directly in
    the reproduction directory: an unfinished piece continues from what it left there."""

    capacity = 1
    queues = False

    def __init__(self, out_dir: Path, budget: Budget):
        self.out_dir, self.budget = out_dir, budget
        self._queue: deque[Piece] = deque()

    def submit(self, piece: Piece) -> None:
        self._queue.append(piece)

    def next_outcome(self) -> PieceOutcome:
        piece = self._queue.popleft()
        started = time.monotonic()
        try:
            note = run_piece(piece, self.budget, self.out_dir)
        except KeyboardInterrupt:
            raise
        except Exception as error:  # noqa: BLE001 - recorded with its traceback; independent pieces still run
            return PieceOutcome(
                piece, time.monotonic() - started, error=error_text(error), traceback=traceback.format_exc()
            )
        return PieceOutcome(piece, time.monotonic() - started, note=note)

    def close(self) -> None:
        self._queue.clear()
