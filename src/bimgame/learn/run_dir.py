"""One run directory's lifecycle, the same for every learner: A3C, DAgger and pre-training.

:class:`RunDirectory` is a context manager that, on entering,

1. refuses a directory that another process holds (its lock); checks that it may take a new run
   (:func:`~bimgame.learn.runs.prepare_new_run`: new or empty) or holds a run of its kind to continue
   (:func:`~bimgame.learn.runs.check_resumable`, with its checkpoint), before anything is created or
   changed;
2. creates the directory and takes its lock (:class:`~bimgame.learn.run_lock.RunLock`), so that a
   second process writing the same run is refused, naming the holder; then checks again, as the
   directory may have changed between the first look and the lock;

while the learner works in it, writes ``config.json`` with the run's ``kind``
(:meth:`RunDirectory.write_config`), opens the logs (:meth:`RunDirectory.metric_log`) and writes the
summary (:meth:`RunDirectory.write_summary`); and on leaving releases the lock, after removing what a
new run wrote if it failed before it kept anything (:meth:`RunDirectory.keep`), so the same command
can be run again.

What each kind of run writes is declared once, in :data:`LAYOUTS`: the discard removes those names
only, never anything else in the directory.
"""

from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path
from types import TracebackType
from typing import Any

from bimgame.learn.metric_logs import MetricLog
from bimgame.learn.run_lock import RunLock
from bimgame.learn.runs import (
    CHECKPOINT,
    CONFIG,
    KIND_A3C,
    KIND_DAGGER,
    KIND_POLICY,
    KIND_PPO,
    KIND_VALUE,
    SUMMARY,
    check_resumable,
    discard_new_run,
    prepare_new_run,
    write_run_json,
)
from bimgame.util.files import FileWriteError

__all__ = [
    "TrainingError",
    "TrainResult",
    "RunLayout",
    "LAYOUTS",
    "TEACHER",
    "DAGGER_STATE",
    "BEST",
    "RunDirectory",
    "stored_run_config",
]

#: A3C's frozen π^s of a run with the KL term (kickstarting): the weights it started from.
TEACHER = "teacher.pt"
#: DAgger's counters after the last finished iteration (a readable copy of its checkpoint's).
DAGGER_STATE = "dagger_state.json"
#: The best iterate of a DAgger or PPO run by its in-run evaluation (:mod:`bimgame.learn.best_iterate`).
BEST = "best.pt"


class TrainingError(RuntimeError):
    """A learner's run stopped because something went wrong (a non-finite reward, loss or gradient,
    a crashed worker, a full disk); the message says what is kept and how to continue."""


@dataclasses.dataclass
class TrainResult:
    """How a learner's run (A3C, PPO) ended."""

    run_dir: Path
    steps: int
    """Environment steps trained, all sessions together."""
    stopped: str
    """``finished`` (budget spent) or ``interrupted`` (Ctrl-C, SIGTERM)."""
    final_eval: dict[str, Any] | None
    """The final greedy and sampled evaluation; None when interrupted before it."""
    seconds: float


@dataclasses.dataclass(frozen=True)
class RunLayout:
    """What one kind of run writes in its directory, and how messages name it."""

    kind: str
    """config.json's ``kind``."""
    what: str
    """The run's name in messages ("A3C", "DAgger", "pre-training")."""
    flag: str
    """The command-line option that names the directory."""
    files: tuple[str, ...]
    """Files and folders other than the logs."""
    tables: tuple[str, ...]
    """The CSV logs (``NAME.csv``), with TensorBoard scalars in ``tb/``."""
    resumable: bool
    """Whether ``--resume`` continues a run of this kind. One that cannot is removed whenever it stops
    early; one that can, only when it fails (not on Ctrl-C) before it kept anything."""

    @property
    def names(self) -> tuple[str, ...]:
        """Every file and folder a run of this kind may write in its directory."""
        return (*self.files, *(f"{table}.csv" for table in self.tables), *(("tb",) if self.tables else ()))


_A3C_FILES = (CONFIG, CHECKPOINT, SUMMARY, TEACHER, "curves.png")
_DAGGER_FILES = (CONFIG, CHECKPOINT, DAGGER_STATE, BEST, "data")
_PRETRAINING_FILES = (CONFIG, CHECKPOINT, SUMMARY)
_PPO_FILES = (CONFIG, CHECKPOINT, SUMMARY, "curves.png", TEACHER, BEST)

#: The layout of every kind of run, by kind.
LAYOUTS: dict[str, RunLayout] = {
    layout.kind: layout
    for layout in (
        RunLayout(KIND_A3C, "A3C", "--run-dir", _A3C_FILES, ("episodes", "updates", "eval"), resumable=True),
        RunLayout(KIND_DAGGER, "DAgger", "--run-dir", _DAGGER_FILES, ("dagger",), resumable=True),
        RunLayout(KIND_PPO, "PPO", "--run-dir", _PPO_FILES, ("episodes", "updates", "eval"), resumable=True),
        RunLayout(KIND_POLICY, "pre-training", "--out", _PRETRAINING_FILES, ("pretrain",), resumable=False),
        RunLayout(KIND_VALUE, "pre-training", "--out", _PRETRAINING_FILES, ("pretrain",), resumable=False),
    )
}


def _layout(kind: str) -> RunLayout:
    """The layout of ``kind``; an unknown kind is refused, naming the known ones."""
    if kind not in LAYOUTS:
        raise ValueError(f"unknown run kind {kind!r}; allowed: {', '.join(LAYOUTS)}")
    return LAYOUTS[kind]


def stored_run_config(run_dir: str | Path, kind: str) -> dict[str, Any]:
    """The ``config.json`` of the run of ``kind`` in ``run_dir`` that ``--resume`` would continue, read
    without taking the lock (to resolve a resumed run's settings before it starts); refuses a
    directory that holds no such run, naming what it holds."""
    layout = _layout(kind)
    return check_resumable(run_dir, kind=layout.kind, what=layout.what, flag=layout.flag)


class RunDirectory:
    """The directory of one run of ``kind`` while a learner writes it (see the module notes).

    Args:
        path: the run directory.
        kind: a key of :data:`LAYOUTS`.
        resume: continue the run in ``path`` (it must hold a run of ``kind`` with its checkpoint)
            instead of starting a new one (``path`` must be new or empty).
    Raises (on entering):
        ValueError: the directory cannot take a new run, or holds no run of ``kind`` to continue;
            nothing was changed.
        RunDirectoryInUse: another process holds the directory's lock; nothing was changed.
    """

    def __init__(self, path: str | Path, kind: str, *, resume: bool = False) -> None:
        self.path = Path(path)
        self.layout = _layout(kind)
        self.resume = resume
        self.created = False
        """Whether the directory did not exist before this run (it is removed again with the run)."""
        self.kept = resume
        """Whether a failure keeps the run's files (a resumed run's always; a new one's after :meth:`keep`)."""
        self.config: dict[str, Any] | None = None
        """A resumed run's stored ``config.json``."""
        self._lock: RunLock | None = None

    # ------------------------------------------------------------------------- entering, leaving
    def __enter__(self) -> RunDirectory:
        """Check the directory, create it for a new run and take its lock; check again under the lock."""
        RunLock.refuse_if_held(self.path)  # a busy directory is refused as such, whatever it holds
        self._check(first=True)
        if not self.resume:
            try:
                self.path.mkdir(parents=True, exist_ok=True)
            except OSError as error:
                raise FileWriteError.from_error(self.path, error) from error
        try:
            self._lock = RunLock.acquire(self.path)
            self._check(first=False)  # what it holds now that nobody else can write it
        except BaseException:
            self._leave()
            raise
        return self

    def _check(self, *, first: bool) -> None:
        """Refuse a directory that holds no run of this kind to continue, or cannot take a new one;
        the ``first`` look records whether the directory is new."""
        layout = self.layout
        if self.resume:
            self.config = check_resumable(
                self.path, kind=layout.kind, what=layout.what, flag=layout.flag, needs=(CHECKPOINT,)
            )
            return
        created = prepare_new_run(
            self.path, what=layout.what, flag=layout.flag, kind=layout.kind if layout.resumable else None
        )
        if first:
            self.created = created

    def __exit__(
        self, exc_type: type[BaseException] | None, error: BaseException | None, traceback: TracebackType | None
    ) -> None:
        """Remove what a new run wrote if ``error`` discards it (:meth:`discards`), then release the lock."""
        try:
            if error is not None and self.discards(error):
                discard_new_run(self.path, False, self.layout.names)  # nothing kept: a rerun starts afresh
        finally:
            self._leave()

    def _leave(self) -> None:
        """Release the lock, and remove the directory if this run created it and left it empty."""
        if self._lock is not None:
            self._lock.release()
            self._lock = None
        if self.created:
            with contextlib.suppress(OSError):
                self.path.rmdir()  # only if empty

    def keep(self) -> None:
        """Mark the new run as worth keeping (it trained something and saved it): from now on a
        failure leaves its files for ``--resume``."""
        self.kept = True

    def discards(self, error: BaseException) -> bool:
        """Whether leaving the run with ``error`` removes what it wrote (see :attr:`RunLayout.resumable`)."""
        return not self.kept and (isinstance(error, Exception) or not self.layout.resumable)

    # ---------------------------------------------------------------------------------- files
    def __truediv__(self, name: str) -> Path:
        """The path of ``name`` (a file or folder of the layout, or a path under a folder of it) in
        the run directory: what a learner writes must be declared, so that a failed new run's
        discard removes it."""
        if Path(name).parts[0] not in self.layout.names:
            raise ValueError(
                f"{name!r} is not a file of {_article(self.layout.what)} {self.layout.what} run; "
                f"declared: {', '.join(self.layout.names)}"
            )
        return self.path / name

    def write_config(self, values: dict[str, Any]) -> Path:
        """Write ``config.json``: ``values`` and the run's ``kind`` (which ``values`` must not hold)."""
        if "kind" in values:
            raise ValueError(
                f"the settings to store hold a 'kind' ({values['kind']!r}); the run's kind is "
                f"{self.layout.kind!r} and is recorded by the run directory"
            )
        return write_run_json(self / CONFIG, {"kind": self.layout.kind, **values})

    def write_summary(self, values: dict[str, Any]) -> Path:
        """Write ``summary.json`` (strict JSON: NaN and infinities as ``null``)."""
        return write_run_json(self / SUMMARY, values)

    def metric_log(self, tables: dict[str, list[str]], **options: Any) -> MetricLog:
        """The run's :class:`~bimgame.learn.metric_logs.MetricLog` of ``tables`` (declared in the layout)."""
        undeclared = sorted(set(tables) - set(self.layout.tables))
        if undeclared:
            raise ValueError(
                f"logs {undeclared} are not declared for {self.layout.kind} runs; declared: "
                f"{', '.join(self.layout.tables)}"
            )
        return MetricLog(self.path, tables, **options)


def _article(word: str) -> str:
    """The indefinite article before ``word`` ("an A3C run", "a DAgger run")."""
    return "an" if word[:1].upper() in "AEIOU" else "a"
