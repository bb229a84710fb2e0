"""A training run's metric logs: CSV tables (``NAME.csv``) with TensorBoard scalars of the same numbers.

CSV logs are appended line by line and flushed (:class:`CsvLog`), so a killed run loses at most the
row it was writing. A resumed run first keeps the rows logged before its checkpoint
(:func:`resumed_rows`), so no step is counted twice, and refuses a log it did not write;
:class:`MetricLog` does this for every table of a run and hides TensorBoard's events of the dropped
steps. A file that cannot be written (a full disk) raises :class:`~bimgame.util.files.FileWriteError`,
which names it.
"""

from __future__ import annotations

import contextlib
import csv
import io
import math
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bimgame.util import files
from bimgame.util.files import FileWriteError

if TYPE_CHECKING:
    from torch.utils.tensorboard import SummaryWriter

__all__ = ["CsvLog", "MetricLog", "resumed_rows"]


def resumed_rows(
    path: str | Path, fields: Sequence[str], before: int, *, keep_equal: bool = False, step_field: str = "step"
) -> list[dict[str, str]]:
    """The rows of the CSV log ``path`` that a run resumed from a checkpoint at step ``before`` keeps:
    those logged strictly before it (also those at exactly ``before`` with ``keep_equal``, for a table
    whose rows at a checkpoint's step were logged before the checkpoint was written). A last line cut
    off by a kill or a full disk is dropped. A log this run did not write — another header, a row
    that does not parse — is refused (``ValueError`` naming the file), before anything is changed:
    its rows are never dropped silently. A missing file has no rows."""
    path = Path(path)
    if not path.is_file():
        return []
    reader = csv.reader(_complete_lines(path))
    header = next(reader, None)
    if header != list(fields):
        shown = ",".join(header) if header else "(none: empty)"
        raise ValueError(
            f"cannot resume: {path} has the header {shown} "
            f"but this run writes {','.join(fields)}; it was not written by this run (or by another "
            f"version of bimgame). Nothing was changed: move the file away to resume without its "
            f"rows, or start a new run"
        )
    return [
        row
        for row, step in _rows_with_steps(path, header, reader, step_field)
        if step < before or (keep_equal and step == before)
    ]


def _complete_lines(path: Path) -> list[str]:
    """The lines of the log ``path``, without a last line cut off mid-write (it was never complete)."""
    try:
        return files.complete_lines(path)
    except (OSError, UnicodeDecodeError) as error:
        raise ValueError(f"cannot read the log {path} to resume: {error}") from None


def _rows_with_steps(
    path: Path, header: list[str], reader: Iterator[list[str]], step_field: str
) -> Iterator[tuple[dict[str, str], float]]:
    """Each row after the ``header`` of the log ``path`` with its step; a row with the wrong number
    of fields or a step that is not a number is refused, naming its line."""
    for number, values in enumerate(reader, start=2):
        if len(values) != len(header):
            raise ValueError(
                f"cannot resume: {path} line {number} has {len(values)} fields, its header "
                f"{len(header)}; nothing was changed"
            )
        row = dict(zip(header, values, strict=True))
        try:
            step = float(row[step_field])
        except ValueError:
            raise ValueError(
                f"cannot resume: {path} line {number}: {step_field} {row[step_field]!r} is not a "
                f"number; nothing was changed"
            ) from None
        yield row, step


class CsvLog:
    """An append-only CSV file with a fixed header, flushed after every row; write failures raise
    :class:`~bimgame.util.files.FileWriteError` naming the file."""

    def __init__(self, path: str | Path, fields: Iterable[str], *, rows: Iterable[dict[str, Any]] = ()) -> None:
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
        """Append ``row`` (its missing fields empty, floats to 6 significant digits) and flush it."""
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
    """A cell as the CSV file shows it: floats to 6 significant digits, None as an empty cell."""
    if isinstance(value, float):
        return f"{value:.6g}"
    return "" if value is None else value


class MetricLog:
    """CSV files plus TensorBoard scalars, keyed by environment steps.

    ``resume_step``: the step of the checkpoint a resumed run continues from; each table keeps its
    rows logged before it (:func:`resumed_rows`; ``keep_at_resume_step`` names the tables whose rows at
    exactly that step are kept too). Every table is read and checked before any is rewritten, so a
    refusal changes nothing. ``kept`` holds the kept rows by table."""

    def __init__(
        self,
        run_dir: str | Path,
        tables: dict[str, list[str]],
        *,
        resume_step: int | None = None,
        keep_at_resume_step: Iterable[str] = (),
        tensorboard: bool = True,
    ) -> None:
        self.run_dir = Path(run_dir)
        keep_equal = set(keep_at_resume_step)
        fields = {name: ["step", *columns] for name, columns in tables.items()}
        self.kept: dict[str, list[dict[str, str]]] = {name: [] for name in tables}
        if resume_step is not None:
            self.kept = {
                name: resumed_rows(self._path(name), fields[name], resume_step, keep_equal=name in keep_equal)
                for name in tables
            }
        self.tables: dict[str, CsvLog] = {}
        self.writer: SummaryWriter | None = None
        try:
            for name in tables:
                self.tables[name] = CsvLog(self._path(name), fields[name], rows=self.kept[name])
        except BaseException:
            self.close()
            raise
        if tensorboard:
            # Events at or after purge_step are hidden: those of the steps the CSV files dropped.
            purge = None if resume_step is None else resume_step + (1 if keep_equal >= set(tables) else 0)
            self.writer = _tensorboard_writer(self.run_dir / "tb", purge)

    def _path(self, table: str) -> Path:
        """The CSV file of ``table``."""
        return self.run_dir / f"{table}.csv"

    def write(self, table: str, step: int, values: dict[str, Any], *, scalars: Iterable[str] = ()) -> None:
        """Append ``values`` at ``step`` to ``table``; those named in ``scalars`` that are finite
        numbers also go to TensorBoard (as ``TABLE/NAME``)."""
        self.tables[table].write({"step": step, **values})
        if self.writer is not None:
            for key in scalars:
                value = values.get(key)
                if value is not None and math.isfinite(float(value)):
                    self.writer.add_scalar(f"{table}/{key}", float(value), step)

    def close(self) -> None:
        """Close every table and the TensorBoard writer."""
        for table in self.tables.values():
            table.close()
        if self.writer is not None:
            with contextlib.suppress(OSError):
                self.writer.close()


def _tensorboard_writer(directory: Path, purge_step: int | None) -> SummaryWriter:
    """A TensorBoard writer into ``directory`` hiding the events at or after ``purge_step``."""
    # Lazy: importing TensorBoard's writer costs about a second, paid only by runs that log.
    from torch.utils.tensorboard import SummaryWriter

    return SummaryWriter(str(directory), purge_step=purge_step)
