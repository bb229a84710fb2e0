"""The paper's experiments as one resumable grid of pieces: :func:`reproduce` runs (or continues)
every unfinished piece of a budget in a reproduction directory ``DIR``::

    plan.json        the budget and every piece: id, kind, directory, dependencies, cost estimate
    status.json      each piece's state (done, failed, …), wall time and how often it was computed;
                     rewritten (atomically) after every piece
    data/, pretrain/, runs/   one directory per piece (see :mod:`bimgame.experiments.grid`)

The driver only orders and records: what the grid is lives in :mod:`~bimgame.experiments.budgets`
and :mod:`~bimgame.experiments.grid`, how long a piece takes in :mod:`~bimgame.experiments.costs`,
the plan and status files and whether a piece is finished in :mod:`~bimgame.experiments.plan`,
how each piece is computed in :mod:`~bimgame.experiments.runners`, where in
:mod:`~bimgame.experiments.backends` (this process, one piece at a time, in plan order) or
:mod:`~bimgame.experiments.cluster` (Ray tasks side by side on a cluster, each started as soon as
the pieces it needs are finished, results shipped back); the report is built afterwards
from the saved results by :mod:`bimgame.experiments.report`. One process works in a directory at a
time (a lock file); SIGTERM stops it like Ctrl-C.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

from rich.console import Console

from bimgame.experiments.backends import Backend, LocalBackend, PieceOutcome
from bimgame.experiments.budgets import Budget
from bimgame.experiments.cluster import RayBackend
from bimgame.experiments.costs import COSTS, CostModel, cluster_seconds, estimate_seconds, format_duration
from bimgame.experiments.grid import Piece
from bimgame.experiments.plan import STATUS, check_compatible, load_status, piece_done, timestamp, write_plan
from bimgame.expert.pool import BACKENDS
from bimgame.util.files import exclusive_lock, write_json
from bimgame.util.progress import ProgressBar, escape
from bimgame.util.signals import sigterm_as_interrupt

__all__ = ["ReproductionResult", "reproduce"]

_LOCK = ".reproduce.lock"


def _exclusive(out_dir: Path):
    """One reproduction process per directory at a time."""
    return exclusive_lock(out_dir / _LOCK, f"another bimgame reproduce is running in {out_dir}; wait for it or stop it")


@dataclasses.dataclass
class ReproductionResult:
    """What one call of :func:`reproduce` did, as piece ids by outcome."""

    out_dir: Path
    computed: list[str]
    """Pieces computed (or finished) by this call."""
    reused: list[str]
    """Pieces found finished and skipped."""
    failed: dict[str, str]
    """Pieces that raised, with the error."""
    skipped: list[str]
    """Pieces not run because a piece they need failed."""
    remaining: list[str]
    """Pieces not run because ``stop_after`` was reached."""
    seconds: float

    @property
    def complete(self) -> bool:
        return not (self.failed or self.skipped or self.remaining)


def reproduce(
    out_dir: str | Path,
    budget: Budget,
    *,
    progress: bool = True,
    stop_after: int | None = None,
    console: Any = None,
    costs: CostModel = COSTS,
    backend: str = "local",
    ray_address: str | None = None,
    max_retries: int = 3,
) -> ReproductionResult:
    """Run (or continue) the reproduction of ``budget`` in ``out_dir``.

    Writes ``plan.json``, then computes every unfinished piece once all it needs is finished,
    rewriting ``status.json`` after each. A failing piece is recorded and the pieces that do not
    need it still run. Ctrl-C stops cleanly (the pieces running are marked interrupted and resume
    next time) and re-raises ``KeyboardInterrupt``.

    Args:
        stop_after: compute at most this many pieces in this call, then return (finished pieces do
            not count); run again to continue.
        progress: one overall rich progress bar over the pieces (each piece's own bars stay off).
        console: a ``rich.console.Console`` for the messages (default: stderr).
        backend: ``local`` (one piece at a time in this process, in plan order) or ``ray`` (pieces
            side by side as Ray tasks; :mod:`bimgame.experiments.cluster`).
        ray_address: with ``backend="ray"``, the cluster to join (None: the Ray initialised in this
            process, else a new local one).
        max_retries: with ``backend="ray"``, how often a piece whose node died is started again.
    Returns:
        What was computed, reused, failed or left; the report is built by :mod:`bimgame.experiments.report`.
    """
    _check_arguments(budget, stop_after, backend, ray_address)
    # Absolute, so the paths the runs record in their config.json (init, value reward) hold from anywhere.
    out_dir = Path(out_dir).resolve()
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"--out {out_dir} exists and is not a directory")
    out_dir.mkdir(parents=True, exist_ok=True)
    with _exclusive(out_dir), sigterm_as_interrupt():
        check_compatible(out_dir, budget)
        pieces = write_plan(out_dir, budget, costs)
        book = _Bookkeeping(out_dir, load_status(out_dir), ReproductionResult(out_dir, [], [], {}, [], [], 0.0))
        invocation: dict[str, Any] = {"started": timestamp(), "budget": budget.name, "backend": backend}
        book.status.setdefault("invocations", []).append(invocation)
        started = time.monotonic()
        done = {p.id for p in pieces if piece_done(p, out_dir, budget)}
        book.mark_planned(pieces, done)
        todo = [p for p in pieces if p.id not in done]
        runner = _backend(
            backend,
            out_dir,
            budget,
            pieces,
            todo,
            invocation,
            console,
            costs,
            ray_address=ray_address,
            max_retries=max_retries,
        )
        shown = todo if stop_after is None else todo[:stop_after]
        driver = _Driver(book, runner, set(done), list(todo), stop_after)
        try:
            with _Display(progress, console, shown, budget, costs, driver.started_state) as display:
                driver.run(display)
        except KeyboardInterrupt:
            driver.interrupted()
            raise
        finally:
            runner.close()
        result = book.result
        result.remaining = [p.id for p in driver.pending]
        result.seconds = time.monotonic() - started
        invocation.update(
            finished=timestamp(),
            seconds=round(result.seconds, 1),
            computed=len(result.computed),
            reused=len(result.reused),
            failed=len(result.failed),
        )
        book.save()
    return result


def _check_arguments(budget: Budget, stop_after: int | None, backend: str, ray_address: str | None) -> None:
    """Refuse bad arguments of :func:`reproduce` before anything is written."""
    if stop_after is not None and not (isinstance(stop_after, int) and stop_after >= 1):
        raise ValueError(f"stop_after must be None or an integer >= 1, got {stop_after!r}")
    if not isinstance(budget, Budget):
        raise TypeError(f"budget must be a Budget, got {type(budget).__name__}")
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; allowed: {', '.join(BACKENDS)}")
    if ray_address is not None and backend != "ray":
        raise ValueError("ray_address is only used with backend='ray'")


def _backend(
    backend: str,
    out_dir: Path,
    budget: Budget,
    pieces: list[Piece],
    todo: list[Piece],
    invocation: dict[str, Any],
    console: Any,
    costs: CostModel,
    *,
    ray_address: str | None,
    max_retries: int,
) -> Backend:
    """The backend that computes the pieces; a Ray cluster is checked to fit them and announced with
    its expected wall time."""
    if backend != "ray":
        return LocalBackend(out_dir, budget)
    cluster = RayBackend(out_dir, budget, pieces, address=ray_address, max_retries=max_retries)
    cluster.check_fits(todo)
    invocation["cluster_cpus"] = cluster.cpus
    _print(
        console,
        f"Ray cluster: {cluster.cpus:g} CPUs on {cluster.nodes} nodes; expected ≈ "
        f"{format_duration(cluster_seconds(todo, budget, cluster.cpus, costs))} for the "
        f"{len(todo)} pieces not finished yet (their estimates spread over the CPUs, at "
        f"least the longest chain of pieces that wait for one another)",
    )
    return cluster


@dataclasses.dataclass
class _Bookkeeping:
    """``status.json`` (rewritten after every change) and what this call did."""

    out_dir: Path
    status: dict[str, Any]
    result: ReproductionResult

    @property
    def entries(self) -> dict[str, dict[str, Any]]:
        return self.status.setdefault("pieces", {})

    def save(self) -> None:
        self.status["updated"] = timestamp()
        write_json(self.out_dir / STATUS, self.status)

    def mark_planned(self, pieces: list[Piece], done: set[str]) -> None:
        """Every piece's entry: done (reused) or pending (a piece whose outputs are gone starts over)."""
        for piece in pieces:
            entry = self.entries.setdefault(piece.id, {"computed": 0})
            entry.update(kind=piece.kind, path=piece.path)
            if piece.id in done:
                entry["state"] = "done"
                self.result.reused.append(piece.id)
            else:
                if entry.get("state") == "done":  # its outputs are gone: it starts over
                    entry["seconds"] = 0.0
                entry["state"] = "pending"
        self.save()


class _Driver:
    """Submits each pending piece once all it needs is finished (skipping those whose needs failed),
    records each outcome, until nothing is in flight."""

    def __init__(
        self, book: _Bookkeeping, runner: Backend, finished: set[str], pending: list[Piece], stop_after: int | None
    ):
        self.book, self.runner, self.stop_after = book, runner, stop_after
        self.finished, self.pending = finished, pending
        self.in_flight: dict[str, float] = {}
        self.submitted = 0
        self.started_state = "submitted" if runner.queues else "running"

    def run(self, display: _Display) -> None:
        while True:
            self._submit_ready(display)
            if not self.in_flight:
                return
            self._record(self.runner.next_outcome(), display)

    def _may_start(self, piece: Piece) -> bool:
        return (
            all(n in self.finished for n in piece.needs)
            and (self.runner.capacity is None or len(self.in_flight) < self.runner.capacity)
            and (self.stop_after is None or self.submitted < self.stop_after)
        )

    def _submit_ready(self, display: _Display) -> None:
        result = self.book.result
        for piece in list(self.pending):
            entry = self.book.entries[piece.id]
            blocked = [n for n in piece.needs if n in result.failed or n in result.skipped]
            if blocked:
                entry.update(state="skipped", error=f"needs {', '.join(blocked)}, which did not finish")
                result.skipped.append(piece.id)
                self.pending.remove(piece)
                self.book.save()
                continue
            if not self._may_start(piece):
                continue
            entry.update(state=self.started_state, started=timestamp())
            for stale in ("error", "traceback", "node"):
                entry.pop(stale, None)
            self.book.save()
            self.runner.submit(piece)
            self.pending.remove(piece)
            self.in_flight[piece.id] = time.monotonic()
            self.submitted += 1
            display.start(piece)

    def _record(self, outcome: PieceOutcome, display: _Display) -> None:
        """A piece's attempt ended: its wall time, node and outcome go to ``status.json`` and the display."""
        piece = outcome.piece
        del self.in_flight[piece.id]
        entry = self.book.entries[piece.id]
        # Wall time includes earlier interrupted or failed attempts of the same piece.
        entry["seconds"] = entry.get("seconds", 0.0) + outcome.seconds
        entry["finished"] = timestamp()
        if outcome.node is not None:
            entry["node"] = outcome.node
        if outcome.error is not None:
            self._record_failure(outcome, outcome.error, entry, display)
        else:
            self._record_success(outcome, entry, display)

    def _record_failure(self, outcome: PieceOutcome, error: str, entry: dict[str, Any], display: _Display) -> None:
        """The piece failed with ``error``: the pieces that need it will be skipped."""
        piece = outcome.piece
        entry.update(state="failed", error=error, traceback=outcome.traceback)
        self.book.result.failed[piece.id] = error
        self.book.save()
        display.finish(piece, f"[red]failed[/red]: {escape(error)}")

    def _record_success(self, outcome: PieceOutcome, entry: dict[str, Any], display: _Display) -> None:
        """The piece finished: the pieces that need it may start."""
        piece = outcome.piece
        entry.update(state="done", computed=entry.get("computed", 0) + 1)
        entry.pop("traceback", None)
        entry.pop("note", None)
        if outcome.note:
            entry["note"] = outcome.note
        self.finished.add(piece.id)
        self.book.result.computed.append(piece.id)
        self.book.save()
        where = f" on {outcome.node}" if outcome.node else ""
        display.finish(
            piece,
            f"done in {format_duration(outcome.seconds)}{escape(where)}"
            + (f" ({escape(outcome.note)})" if outcome.note else ""),
        )

    def interrupted(self) -> None:
        """Mark the pieces in flight interrupted (they resume next time), with the time they ran."""
        now = time.monotonic()
        for piece_id, submitted_at in self.in_flight.items():
            entry = self.book.entries[piece_id]
            # Locally the piece ran since it was submitted; in a queue it may not have started.
            spent = 0.0 if self.runner.queues else now - submitted_at
            entry.update(state="interrupted", seconds=entry.get("seconds", 0.0) + spent)
        self.book.save()


def _print(console: Any, text: str) -> None:
    """A line on ``console`` (default: stderr)."""
    (console if console is not None else Console(stderr=True)).print(escape(text))


class _Display:
    """One progress bar over the pieces, weighted by their estimated cost, showing pieces done/total,
    elapsed and remaining time and the piece running, with a line per finished piece; plain lines
    when the bar is off."""

    def __init__(self, enabled: bool, console: Any, todo: list[Piece], budget: Budget, costs: CostModel, verb: str):
        self.budget, self.costs, self.verb = budget, costs, verb
        self.estimates = {p.id: estimate_seconds(p, budget, costs) for p in todo}
        self.count = len(todo)
        self.finished = 0
        self.bar = ProgressBar(
            "reproduce",
            max(sum(self.estimates.values()), 1.0),
            enabled=enabled,
            count=None,
            eta=True,
            info=self._pieces(),
            console=console,
        )

    def _pieces(self) -> str:
        return f"{self.finished}/{self.count} pieces"

    def __enter__(self) -> _Display:
        self.bar.__enter__()
        return self

    def start(self, piece: Piece) -> None:
        estimate = self.estimates.get(piece.id) or estimate_seconds(piece, self.budget, self.costs)
        text = escape(f"{piece.id} (≈ {format_duration(estimate)})")
        if self.bar.enabled:
            self.bar.update(info=f"{self._pieces()}  {text}")
        else:
            self.bar.print(f"{self.verb} {text}")

    def finish(self, piece: Piece, message: str) -> None:
        """``message`` is rich markup (escape any text in it)."""
        self.finished += 1
        self.bar.print(f"{escape(f'[{self.finished}/{self.count}] {piece.id}')}: {message}")
        self.bar.update(advance=self.estimates.get(piece.id, 0.0), info=self._pieces())

    def __exit__(self, *exc: Any) -> None:
        self.bar.update(info=self._pieces())
        self.bar.__exit__(*exc)
