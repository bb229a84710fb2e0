"""What the parent process of an A3C run does while its workers train: start the worker and evaluator
processes (:mod:`bimgame.learn.a3c.workers`), log what they report, show progress, write the
checkpoints, and stop them — at the end of the steps, on Ctrl-C or SIGTERM, or at the first failure,
which it turns into a :class:`TrainingError` that says what is kept and how to continue.
:func:`bimgame.learn.a3c.train` runs one such session per call."""

from __future__ import annotations

import dataclasses
import json
import math
import queue as queue_module
import time
from pathlib import Path
from typing import Any

import torch
import torch.multiprocessing as mp

from bimgame.learn.a3c.settings import A3CConfig
from bimgame.learn.a3c.update import make_optimizer, shared_optimizer_state
from bimgame.learn.a3c.workers import RunShared, _evaluator, _worker
from bimgame.learn.checkpoints import save_checkpoint
from bimgame.learn.curricula import CURRICULUM_COLUMNS, CURRICULUM_SCALARS
from bimgame.learn.episode_monitor import Monitor
from bimgame.learn.evaluations import EVAL_COLUMNS
from bimgame.learn.metric_logs import MetricLog
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.rewards import EnvWrapper
from bimgame.learn.run_dir import TrainingError
from bimgame.learn.runs import CHECKPOINT
from bimgame.util.files import FileWriteError
from bimgame.util.progress import ProgressBar
from bimgame.util.signals import sigterm_as_interrupt

__all__ = ["SessionStart", "Session", "TABLES"]


#: The run's CSV logs and their columns.
TABLES = {
    "episodes": ["start_step", "worker", "return", "length", "success", "true_start"],
    "updates": [
        "seconds",
        "sps",
        "policy_loss",
        "value_loss",
        "entropy",
        "grad_norm",
        "recent_success",
        "recent_return",
        "recent_length",
        "kl",
        "bc",
        "aux_frame",
        "aux_memory",
        "actor_weight",
        "kl_weight",
        "bc_weight",
        "entropy_coef",
        *CURRICULUM_COLUMNS,
    ],
    "eval": list(EVAL_COLUMNS),
}
#: The update columns that also go to TensorBoard.
_UPDATE_SCALARS = (
    "sps",
    "policy_loss",
    "value_loss",
    "entropy",
    "grad_norm",
    "recent_success",
    "kl",
    "aux_frame",
    "aux_memory",
    "actor_weight",
    "kl_weight",
    "bc_weight",
    "entropy_coef",
    *CURRICULUM_SCALARS,
)


@dataclasses.dataclass
class SessionStart:
    """Where a session starts: the checkpoint's step, the seconds the run had trained before, the
    optimiser statistics; ``fresh`` for a new run."""

    step: int = 0
    seconds: float = 0.0
    optimizer: dict | None = None
    fresh: bool = True
    teacher: dict[str, torch.Tensor] | None = None
    """π^s for the KL term (kickstarting), or None."""
    checkpoint_step: int = 0
    """Step of the newest checkpoint written (0 until the first one after the start)."""


class Session:
    """One session's processes, as the parent sees them: what they report, the checkpoints, and how
    the session ended (``stopped``, ``failure``: a worker's error, ``write_failure``: a full disk).
    :meth:`run` runs the session."""

    def __init__(
        self,
        config: A3CConfig,
        run_dir: Path,
        shared: RecurrentActorCritic,
        start: SessionStart,
        log: MetricLog,
        monitor: Monitor,
        started: float,
        env_wrapper: EnvWrapper | None,
    ):
        self.config, self.run_dir, self.shared, self.start = config, run_dir, shared, start
        self.log, self.monitor, self.started = log, monitor, started
        shared.share_memory()
        self.optimizer = make_optimizer(config, shared)
        if start.optimizer is not None:
            self.optimizer.load_state_dict(start.optimizer)
        optimizer_state = shared_optimizer_state(self.optimizer)
        initial_weights = {k: v.detach().clone() for k, v in shared.state_dict().items()}
        context = mp.get_context("spawn")
        self.counter = context.Value("q", start.step)
        self.stop = context.Event()
        self.messages = context.Queue()
        run = RunShared(
            config, shared, optimizer_state, self.counter, self.stop, self.messages, env_wrapper, start.step,
            start.teacher,
        )  # fmt: skip
        self.processes = [
            context.Process(target=_worker, name=f"a3c-worker-{rank}", args=(rank, run), daemon=True)
            for rank in range(config.schedule.workers)
        ]
        if config.schedule.eval_every > 0:
            evaluator_args = (config, shared, self.counter, self.stop, self.messages, start.step, initial_weights)
            self.processes.append(
                context.Process(target=_evaluator, name="a3c-evaluator", args=evaluator_args, daemon=True)
            )
        self.stopped = "finished"
        self.failure: str | None = None
        self.write_failure: FileWriteError | None = None

    def run(self, progress: bool) -> tuple[int, str]:
        """The workers and the evaluator, until the steps are done, Ctrl-C, or a failure; writes the
        checkpoints. Returns (step, "finished" or "interrupted"); raises :class:`TrainingError`."""
        self.watch(progress)
        step = int(self.counter.value)
        self.note_unreported_exit(step)
        saved = self.final_checkpoint(step)
        self.raise_failure(step, saved)
        return step, self.stopped

    def checkpoint(self) -> None:
        step = int(self.counter.value)
        save_checkpoint(
            self.run_dir / CHECKPOINT,
            model=self.shared.state_dict(),
            optimizer=self.optimizer.state_dict(),
            step=step,
            seconds=time.monotonic() - self.started,
            config=json.dumps(self.config.to_dict()),
        )
        self.start.checkpoint_step = step

    def watch(self, progress: bool) -> None:
        """Start the processes and handle their reports until they have all exited; then stop them."""
        title = f"A3C {self.config.task} {self.config.network.obs}"
        try:
            with (
                sigterm_as_interrupt(),
                ProgressBar(
                    title, self.config.schedule.steps, completed=self.start.step, enabled=progress, eta=True,
                    count="{done:,.0f}/{total:,.0f} steps",
                ) as bar,
            ):  # fmt: skip
                for process in self.processes:
                    process.start()
                self._read_reports(bar, progress)
        except KeyboardInterrupt:
            self.stopped = "interrupted"
        except FileWriteError as error:
            self.write_failure = error
        finally:
            self.stop.set()
            _stop_processes(self.processes, self.messages)

    def _read_reports(self, bar: Any, progress: bool) -> None:
        running, shown_at = len(self.processes), 0.0
        while running:
            try:
                kind, rank, payload = self.messages.get(timeout=0.25)
            except queue_module.Empty:
                kind, rank, payload = None, -1, None
                if not any(p.is_alive() for p in self.processes):
                    break
            if kind == "exit":
                running -= 1
            elif kind is not None:
                self._handle(kind, rank, payload)
            step = int(self.counter.value)
            if progress and time.monotonic() - shown_at >= 0.5:
                shown_at = time.monotonic()
                success = self.monitor.recent()["recent_success"]
                shown = "-" if math.isnan(success) else f"{success:.0%}"
                bar.update(completed=step, info=f"{self.monitor.sps(step):,.0f} SPS  success {shown}")
            if self.failure is None and step - self.start.checkpoint_step >= self.config.schedule.checkpoint_every:
                self.checkpoint()

    def _handle(self, kind: str, rank: int, payload: Any) -> None:
        """Log one report of a process; a failure sets the stop event."""
        if kind == "episode":
            self.monitor.episode(payload)
            row = {**payload, "worker": rank}
            self.log.write("episodes", payload["end_step"], row, scalars=("return", "length", "success"))
        elif kind == "update":
            timing = {"sps": self.monitor.sps(self.counter.value), "seconds": time.monotonic() - self.started}
            row = {**payload, **self.monitor.recent(), **timing}
            self.log.write("updates", payload["step"], row, scalars=_UPDATE_SCALARS)
        elif kind == "eval":
            self.log.write("eval", payload["step"], payload, scalars=tuple(TABLES["eval"]))
        elif kind == "nan":
            self.failure = (
                f"worker {rank} got a non-finite {payload['what']} at step {payload['step']} "
                f"({payload}); the update was not applied. Lower --lr or --max-grad-norm, or "
                f"check the env wrapper's rewards."
            )
            self.stop.set()
        elif kind == "error":
            self.failure = f"process {rank} failed:\n{payload}"
            self.stop.set()

    def note_unreported_exit(self, step: int) -> None:
        """Every process exited without reporting an error (e.g. killed, or failed while starting,
        before its own error handling ran) before the steps were done: not a finished run."""
        steps = self.config.schedule.steps
        if self.stopped != "finished" or self.failure is not None or self.write_failure is not None or step >= steps:
            return
        codes = ", ".join(f"{p.name} {p.exitcode}" for p in self.processes)
        self.failure = (
            f"the worker processes exited at step {step:,} of {steps:,} without reporting an error "
            f"(exit codes: {codes}). If training was started from a script, the script needs an "
            f"`if __name__ == '__main__':` guard: workers are spawned and import it again."
        )

    def final_checkpoint(self, step: int) -> bool:
        """The session's last checkpoint: always after a clean end; after a failure, the weights before
        the failing update when they are finite (for inspection or a resume). Whether a failure's
        weights were saved."""
        try:
            if self.failure is None and self.write_failure is None:
                self.checkpoint()
            elif (
                self.write_failure is None
                and not (self.start.fresh and step == 0)
                and all(torch.isfinite(p).all() for p in self.shared.parameters())
            ):
                self.checkpoint()
                return True
        except FileWriteError as error:
            self.write_failure = error
        return False

    def raise_failure(self, step: int, saved: bool) -> None:
        """A :class:`TrainingError` for a failed session, saying what is kept and how to continue."""
        run_dir, start, failure = self.run_dir, self.start, self.failure
        discarded = start.fresh and start.checkpoint_step == 0  # train() removes a new run that kept nothing
        if self.write_failure is not None:
            # No new checkpoint: the logs may lack rows before it. The last one and the rows before it are whole.
            then = f" ({failure.splitlines()[0]})" if failure else ""
            if discarded:
                raise TrainingError(
                    f"{self.write_failure}. Training stopped at step {step:,}{then} before its first "
                    f"checkpoint, so the new run's files are removed from {run_dir}: free some space "
                    f"and run the same command again"
                ) from self.write_failure
            raise TrainingError(
                f"{self.write_failure}. Training stopped at step {step:,}{then}; the checkpoint "
                f"{run_dir / CHECKPOINT} (step {start.checkpoint_step:,}) and the logs before it are "
                f"intact: free some space and continue with --resume"
            ) from self.write_failure
        if failure is None:
            return
        if discarded:
            raise TrainingError(
                f"{failure} No checkpoint was written after step 0, so the new run's files are "
                f"removed from {run_dir}: fix the cause and run the same command again."
            )
        where = (
            f"The weights from before that update are saved in {run_dir / CHECKPOINT}."
            if saved
            else f"The last checkpoint ({run_dir / CHECKPOINT}, step {start.checkpoint_step:,}) is kept."
        )
        raise TrainingError(f"{failure} {where}")


def _stop_processes(processes: list, messages: Any, timeout: float = 30.0) -> None:
    """Wait for the (already told to stop) processes to exit, reading what they still send meanwhile:
    a process that has put messages on the queue cannot exit until they are read (its queue's feeder
    thread flushes them into the pipe first), so joining without reading can wait for nothing but
    the timeout. Processes still alive after ``timeout`` seconds are terminated."""
    started = [p for p in processes if p.pid is not None]  # not started: e.g. its arguments could not be sent
    deadline = time.monotonic() + timeout
    while any(p.is_alive() for p in started) and time.monotonic() < deadline:
        try:
            while True:
                messages.get_nowait()  # what arrives after the stop is not logged
        except (queue_module.Empty, OSError, ValueError, EOFError):
            pass
        for process in started:
            process.join(timeout=0.05)
    for process in started:
        if process.is_alive():
            process.terminate()
            process.join()
