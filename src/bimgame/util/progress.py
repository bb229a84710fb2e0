"""One progress bar for every long job (A3C, pre-training, DAgger, expert episodes, reproduction).

A rich bar on stderr, so that stdout stays for results: a label, the bar, ``done/total`` (with a unit,
or formatted by the caller), a free-text ``info`` field the job fills with its own numbers (success
rate, held-out accuracy, SPS), elapsed time and optionally an ETA. Disabled, every method is a no-op
except :meth:`ProgressBar.print`, which still prints, so callers never branch on ``enabled``.
"""

from __future__ import annotations

from types import TracebackType
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

__all__ = ["ProgressBar", "escape"]


class ProgressBar:
    """A progress bar over ``total`` units (steps, episodes, epochs, estimated seconds).

    ``count``: how ``done/total`` is shown — ``"of"`` (``3/10``), a format string with ``{done}``
    and ``{total}`` fields (e.g. ``"{done:,.0f}/{total:,.0f} steps"``), or None (not shown; the info
    field says it). ``eta``: add an ETA column. ``transient``: remove the bar when done.
    """

    def __init__(
        self,
        label: str,
        total: float,
        *,
        completed: float = 0,
        enabled: bool = True,
        count: str | None = "of",
        eta: bool = False,
        transient: bool = False,
        info: str = "",
        console: Console | None = None,
    ):
        self.enabled = enabled
        self.console = console or Console(stderr=True)
        self._total = total
        self._completed = completed
        self._count = count
        self._info = info
        self._label = label
        self._bar: Progress | None = None
        self._transient = transient
        self._eta = eta

    def __enter__(self) -> ProgressBar:
        if not self.enabled:
            return self
        columns: list[Any] = [TextColumn("{task.description}"), BarColumn()]
        if self._count == "of":
            columns.append(MofNCompleteColumn())
        elif self._count is not None:
            columns.append(TextColumn(self._count.replace("{done", "{task.completed").replace("{total", "{task.total")))
        columns += [TextColumn("{task.fields[info]}"), TimeElapsedColumn()]
        if self._eta:
            columns += [TextColumn("ETA"), TimeRemainingColumn()]
        self._bar = Progress(*columns, console=self.console, transient=self._transient)
        self._bar.__enter__()
        self._task = self._bar.add_task(
            self._label,
            total=self._total,
            completed=self._completed,  # type: ignore[arg-type]  # rich annotates int here, stores a float
            info=self._info,
        )
        return self

    def update(
        self,
        *,
        completed: float | None = None,
        advance: float | None = None,
        info: str | None = None,
        label: str | None = None,
    ) -> None:
        """Move the bar to ``completed`` (or by ``advance``) and replace the info text or label."""
        if self._bar is None:
            return
        fields: dict[str, Any] = {}
        if info is not None:
            fields["info"] = info
        if label is not None:
            fields["description"] = label
        self._bar.update(self._task, completed=completed, advance=advance, **fields)

    def print(self, text: str) -> None:
        """A line above the bar (rich markup; :func:`escape` plain text first), or a plain line when the
        bar is disabled."""
        (self._bar.console if self._bar is not None else self.console).print(text)

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, traceback: TracebackType | None
    ) -> None:
        if self._bar is not None:
            self._bar.__exit__(exc_type, exc, traceback)
            self._bar = None
