"""A3C: asynchronous advantage actor-critic (Mnih et al., "Asynchronous Methods for Deep
Reinforcement Learning", ICML 2016) with a recurrent network, as the BiMGame paper trained it.

``workers`` processes each own a copy of the environment (``envs_per_worker`` of them, stepped as
one batch) and a local copy of the network. Each repeatedly

1. copies the shared weights into its local network,
2. acts for ``n_steps`` steps (one batched no-grad forward per step),
3. computes n-step returns (or GAE), the policy-gradient, value and entropy losses over the segment
   — unrolling the LSTM from the state it had at the segment's start, so the gradient is exactly
   that of the policy that acted,
4. clips the gradient norm and applies it to the *shared* weights with the *shared* optimiser
   statistics, without locks (Hogwild).

With ``envs_per_worker=1`` this is exactly the paper's A3C. A separate evaluator process
periodically runs greedy and sampled episodes with the shared weights. The parent process only
orchestrates: it logs what workers report, shows progress, writes checkpoints, and stops everything
on Ctrl-C, on a non-finite loss, or when the step budget is spent.

Why our own implementation: no maintained library ships recurrent A3C for PyTorch (RLlib removed
A3C; Stable-Baselines3 has no recurrent A2C).

This module owns :func:`train` and the parent process (the run directory, checkpoints, logs,
progress); it re-exports the rest of the public API. The settings, loss and update that the worker
processes share with it live in :mod:`bimgame.learn.a3c_core`, the worker and evaluator processes
in :mod:`bimgame.learn.a3c_workers`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import queue as queue_module
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.multiprocessing as mp

from bimgame.learn.a3c_core import (
    MAX_STEPS,
    OPTIMIZERS,
    START_CURRICULA,
    A3CConfig,
    EnvWrapper,
    a3c_segment_loss,
    apply_update,
    evaluate,
    make_optimizer,
    network_for,
    shared_optimizer_state,
)
from bimgame.learn.a3c_workers import RunShared, _evaluator, _worker
from bimgame.learn.common import EVAL_COLUMNS, init_network_settings
from bimgame.learn.curves import plot_run
from bimgame.learn.learner_settings import DEFAULT_FINETUNE, FINETUNE_PRESETS
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.run_dir import TEACHER, RunDirectory, stored_run_config
from bimgame.learn.checkpoints import CheckpointError, apply_weights, load_checkpoint, load_weights, save_checkpoint
from bimgame.learn.metric_logs import MetricLog
from bimgame.learn.runs import CHECKPOINT, KIND_A3C, SUMMARY, read_run_settings, torch_threads
from bimgame.util.files import FileWriteError, read_json
from bimgame.util.progress import ProgressBar
from bimgame.util.signals import sigterm_as_interrupt

__all__ = ["A3CConfig", "TrainingError", "TrainResult", "train", "network_for", "make_optimizer", "evaluate",
           "OPTIMIZERS", "START_CURRICULA", "MAX_STEPS", "EnvWrapper", "resolve_config", "a3c_segment_loss", "apply_update",
           "shared_optimizer_state"]


class TrainingError(RuntimeError):
    """Training stopped because something went wrong (a non-finite loss, a crashed worker)."""


@dataclasses.dataclass
class TrainResult:
    run_dir: Path
    steps: int
    stopped: str
    """``finished`` (budget spent) or ``interrupted`` (Ctrl-C)."""
    final_eval: dict[str, Any] | None
    seconds: float


# ---------------------------------------------------------------------- the parent process
_TABLES = {
    "episodes": ["start_step", "worker", "return", "length", "success", "true_start"],
    "updates": ["seconds", "sps", "policy_loss", "value_loss", "entropy", "grad_norm", "recent_success", "recent_return",
                "recent_length", "kl", "bc", "aux_frame", "aux_memory", "actor_weight", "kl_weight", "bc_weight", "entropy_coef", "curriculum_stage",
                "curriculum_steps_back", "curriculum_pool", "curriculum_good", "curriculum_mastered",
                "curriculum_start_distance", "curriculum_window_success", "true_start_share"],
    "eval": list(EVAL_COLUMNS),
}



def resolve_config(given: dict[str, Any], run_dir: str | Path, *, resume: bool = False,
                   init: str | Path | None = None) -> A3CConfig:
    """A run's settings from the ones a user gave (``given``: field → value, only those given): the
    defaults, or with ``resume`` the run's stored settings, overridden by ``given``; with ``init``, the
    network settings of the run it points at unless given (a pre-trained π^s fixes the network's
    shape) and the fine-tuning preset's settings (``finetune``, default ``keep``) unless given. The
    command line and the reproduction both build their A3C settings here."""
    if resume:
        stored_run_config(run_dir, KIND_A3C)
        return read_run_settings(run_dir, "a3c", lambda stored: A3CConfig.from_dict({**stored, **given}))
    if init is not None:
        given = {**init_network_settings(init), **finetune_settings(given.get("finetune")), **given}
    return A3CConfig.from_dict(given)


def finetune_settings(preset: str | None) -> dict[str, Any]:
    """The settings a run started from a pre-trained policy takes unless given: those of the fine-tuning
    ``preset`` (None: :data:`~bimgame.learn.finetune.DEFAULT_FINETUNE`), with its name recorded."""
    preset = DEFAULT_FINETUNE if preset is None else preset
    if preset not in FINETUNE_PRESETS:
        raise ValueError(f"A3CConfig.finetune must be one of {', '.join(FINETUNE_PRESETS)}, got {preset!r}")
    return {**FINETUNE_PRESETS[preset], "finetune": preset}


def _check_resume(run_dir: Path, config: A3CConfig) -> None:
    """Refuse to resume the run in ``run_dir`` (checked to be an A3C run with its checkpoint) with
    settings other than its own, except :attr:`A3CConfig.RESUMABLE_CHANGES`."""
    previous = read_run_settings(run_dir, "a3c", A3CConfig.from_dict).to_dict()
    current = config.to_dict()
    changed = [name for name in current if previous[name] != current[name] and name not in A3CConfig.RESUMABLE_CHANGES]
    if changed:
        raise ValueError("--resume must keep the run's settings; changed: "
                         + ", ".join(f"{k} ({previous[k]!r} -> {current[k]!r})" for k in changed)
                         + f". Allowed to change: {', '.join(A3CConfig.RESUMABLE_CHANGES)}")


def _summarised(run_dir: Path, step: int) -> bool:
    """Whether the run's summary reports it finished at ``step``, with its final evaluation."""
    summary = read_json(run_dir / SUMMARY)
    return (summary is not None and summary.get("stopped") == "finished" and summary.get("steps") == step
            and summary.get("final_eval") is not None)


def train(config: A3CConfig, run_dir: str | Path, *, resume: bool = False, init: str | Path | None = None,
          env_wrapper: EnvWrapper | None = None, progress: bool = True, extra_config: dict | None = None,
          ) -> TrainResult:
    """Train with A3C; everything is saved in ``run_dir`` (see :mod:`bimgame.learn.runs`).

    A new run needs a new or empty ``run_dir``; it writes its ``config.json`` and a step-0 checkpoint
    first, and if it fails before its first later checkpoint it removes its files again, so the same
    call can be repeated. A resumed run continues from its checkpoint (its logs keep the rows from
    before it); one whose steps are all done but whose final evaluation is missing (stopped during
    it) only does that evaluation and writes the summary. The run holds its directory's lock while it
    runs (:class:`~bimgame.learn.run_dir.RunDirectory`): another process writing the same directory is
    refused, naming this one; the worker processes write nothing there.

    Args:
        resume: continue the run in ``run_dir`` from its checkpoint.
        init: a checkpoint file or run directory whose weights the network starts from (e.g. a
            pre-trained π^s); optimiser statistics start fresh. A resumed run starts from its checkpoint.
        env_wrapper: wraps each worker's vector env (e.g. value-function reward shaping); must be
            picklable. Evaluation always uses the true task reward.
        extra_config: more settings to record in config.json (e.g. how the wrapper was built).
    Raises:
        TrainingError: a worker produced a non-finite loss or crashed, or a file could not be written
            (weights stay as they were before the failing update; the last good checkpoint is kept).
    """
    with torch_threads(1):  # the parent only orchestrates; workers set their own
        return _train(config, Path(run_dir), resume=resume, init=init, env_wrapper=env_wrapper, progress=progress,
                      extra_config=extra_config)


@dataclasses.dataclass
class _Start:
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


def _train(config: A3CConfig, run_dir: Path, *, resume: bool, init: str | Path | None,
           env_wrapper: EnvWrapper | None, progress: bool, extra_config: dict | None) -> TrainResult:
    shared = network_for(config)
    if not resume and config.has_teacher and init is None:
        raise ValueError("A3CConfig.kl_coef > 0 (kickstarting) needs a pre-trained policy to stay close to: "
                         "pass --init (or set kl_coef to 0)")
    with RunDirectory(run_dir, KIND_A3C, resume=resume) as run:
        start = _resumed(config, run, shared) if resume else _started(config, run, shared, init, extra_config)
        try:
            return _session(config, run, shared, start, env_wrapper=env_wrapper, progress=progress)
        finally:
            if start.checkpoint_step > 0:
                run.keep()  # trained and saved: a failure from now on leaves the run for --resume


def _resumed(config: A3CConfig, run: RunDirectory, shared: RecurrentActorCritic) -> _Start:
    """The start of a resumed run: its checkpoint's weights (put into ``shared``), step, seconds and
    optimiser statistics, and its teacher; refuses other settings and a run that is done."""
    _check_resume(run.path, config)
    payload = load_checkpoint(run / CHECKPOINT)
    apply_weights(shared, payload, run / CHECKPOINT)
    start = _Start(step=payload["step"], seconds=float(payload.get("seconds", 0.0)),
                   optimizer=payload.get("optimizer"), fresh=False, checkpoint_step=payload["step"])
    if config.has_teacher:
        start.teacher = load_checkpoint(run / TEACHER)["model"]
    if start.step >= config.schedule.steps and _summarised(run.path, start.step):
        raise ValueError(f"the run in {run.path} already has {start.step} steps >= steps={config.schedule.steps}; "
                         f"pass a larger --steps to continue")
    return start


def _started(config: A3CConfig, run: RunDirectory, shared: RecurrentActorCritic, init: str | Path | None,
             extra_config: dict | None) -> _Start:
    """The start of a new run: ``shared`` from ``init`` (if given), its teacher, and its settings, teacher
    and step-0 checkpoint written before anything else, so the directory always holds both."""
    start = _Start()
    if init is not None:
        try:
            load_weights(shared, init)
        except CheckpointError as error:
            raise CheckpointError(f"--init: {error}") from None
    if config.has_teacher:
        start.teacher = {k: v.detach().clone() for k, v in shared.state_dict().items()}
    run.write_config({"a3c": config.to_dict(), "net": shared.config.to_dict(),
                      "init": str(init) if init is not None else None, **(extra_config or {})})
    if start.teacher is not None:
        save_checkpoint(run / TEACHER, model=start.teacher, step=0, source=str(init))
    save_checkpoint(run / CHECKPOINT, model=shared.state_dict(), step=0, seconds=0.0,
                    config=json.dumps(config.to_dict()))
    return start


def _session(config: A3CConfig, run: RunDirectory, shared: RecurrentActorCritic, start: _Start, *,
             env_wrapper: EnvWrapper | None, progress: bool) -> TrainResult:
    """Train from ``start`` to ``config.schedule.steps`` (nothing if the steps are all done), then evaluate
    and write the summary."""
    run_dir = run.path
    log = run.metric_log(_TABLES, resume_step=None if start.fresh else start.step,
                         keep_at_resume_step=("updates",))  # an update's row is logged before its step's checkpoint
    monitor = _Monitor(start.step)
    monitor.restore(log.kept["episodes"])
    started = time.monotonic() - start.seconds  # seconds count the whole run, across resumes
    step, stopped = start.step, "finished"
    if step < config.schedule.steps:
        try:
            step, stopped = _run_processes(config, run_dir, shared, start, log, monitor, started,
                                           env_wrapper=env_wrapper, progress=progress)
        except BaseException:
            log.close()
            raise
    final_eval = None
    if stopped == "finished":
        try:
            with sigterm_as_interrupt():  # Ctrl-C or SIGTERM here: --resume does just this evaluation
                final_eval = {"step": step, **evaluate(shared, config)}
        except KeyboardInterrupt:
            stopped = "interrupted"
    try:
        if final_eval is not None:
            log.write("eval", step, final_eval, scalars=tuple(_TABLES["eval"]))
        log.close()
        seconds = time.monotonic() - started
        run.write_summary({"steps": step, "stopped": stopped, "seconds": seconds, "final_eval": final_eval,
                           **monitor.recent()})
    except FileWriteError as error:
        log.close()
        raise TrainingError(f"{error}. The checkpoint {run_dir / CHECKPOINT} (step {step:,}) is saved: free some "
                            f"space and continue with --resume (a run whose steps are all done then only evaluates "
                            f"and writes its summary)") from error
    try:
        plot_run(run_dir, title=f"A3C on {config.task} ({config.network.obs})")
    except (ValueError, OSError):
        pass  # no finished episode yet (nothing to plot), or no room for the figure: the logs hold it all
    return TrainResult(run_dir, step, stopped, final_eval, seconds)


def _run_processes(config: A3CConfig, run_dir: Path, shared: RecurrentActorCritic, start: _Start, log: MetricLog,
                   monitor: _Monitor, started: float, *, env_wrapper: EnvWrapper | None, progress: bool,
                   ) -> tuple[int, str]:
    """The workers and the evaluator, until the steps are done, Ctrl-C, or a failure; writes the
    checkpoints. Returns (step, "finished" or "interrupted"); raises :class:`TrainingError`."""
    shared.share_memory()
    optimizer = make_optimizer(config, shared)
    if start.optimizer is not None:
        optimizer.load_state_dict(start.optimizer)
    optimizer_state = shared_optimizer_state(optimizer)

    initial_weights = {k: v.detach().clone() for k, v in shared.state_dict().items()}
    context = mp.get_context("spawn")
    counter = context.Value("q", start.step)
    stop = context.Event()
    messages = context.Queue()
    run = RunShared(config, shared, optimizer_state, counter, stop, messages, env_wrapper, start.step, start.teacher)
    processes = [context.Process(target=_worker, name=f"a3c-worker-{rank}", args=(rank, run), daemon=True)
                 for rank in range(config.schedule.workers)]
    if config.schedule.eval_every > 0:
        processes.append(context.Process(target=_evaluator, name="a3c-evaluator",
                                         args=(config, shared, counter, stop, messages, start.step,
                                               initial_weights), daemon=True))
    stopped = "finished"
    failure: str | None = None
    write_failure: FileWriteError | None = None

    def checkpoint() -> None:
        step = int(counter.value)
        save_checkpoint(run_dir / CHECKPOINT, model=shared.state_dict(), optimizer=optimizer.state_dict(),
                        step=step, seconds=time.monotonic() - started, config=json.dumps(config.to_dict()))
        start.checkpoint_step = step

    shown_at = 0.0
    try:
        with sigterm_as_interrupt(), ProgressBar(f"A3C {config.task} {config.network.obs}", config.schedule.steps,
                                                 completed=start.step, enabled=progress, eta=True,
                                                 count="{done:,.0f}/{total:,.0f} steps") as bar:
            for process in processes:
                process.start()
            running = len(processes)
            while running:
                try:
                    kind, rank, payload = messages.get(timeout=0.25)
                except queue_module.Empty:
                    kind = None
                    if not any(p.is_alive() for p in processes):
                        break
                if kind == "exit":
                    running -= 1
                elif kind == "episode":
                    monitor.episode(payload)
                    log.write("episodes", payload["end_step"], {**payload, "worker": rank},
                              scalars=("return", "length", "success"))
                elif kind == "update":
                    row = {**payload, **monitor.recent(), "sps": monitor.sps(counter.value),
                           "seconds": time.monotonic() - started}
                    log.write("updates", payload["step"], row,
                              scalars=("sps", "policy_loss", "value_loss", "entropy", "grad_norm", "recent_success",
                                       "kl", "aux_frame", "aux_memory", "actor_weight", "kl_weight", "bc_weight",
                                       "entropy_coef",
                                       "curriculum_stage", "curriculum_steps_back", "curriculum_start_distance"))
                elif kind == "eval":
                    log.write("eval", payload["step"], payload, scalars=tuple(_TABLES["eval"]))
                elif kind == "nan":
                    failure = (f"worker {rank} got a non-finite {payload['what']} at step {payload['step']} "
                               f"({payload}); the update was not applied. Lower --lr or --max-grad-norm, or "
                               f"check the env wrapper's rewards.")
                    stop.set()
                elif kind == "error":
                    failure = f"process {rank} failed:\n{payload}"
                    stop.set()
                step = int(counter.value)
                if progress and time.monotonic() - shown_at >= 0.5:
                    shown_at = time.monotonic()
                    success = monitor.recent()["recent_success"]
                    bar.update(completed=step, info=f"{monitor.sps(step):,.0f} SPS  success "
                                                    + ("-" if math.isnan(success) else f"{success:.0%}"))
                if failure is None and step - start.checkpoint_step >= config.schedule.checkpoint_every:
                    checkpoint()
    except KeyboardInterrupt:
        stopped = "interrupted"
    except FileWriteError as error:
        write_failure = error
    finally:
        stop.set()
        _stop_processes(processes, messages)
    step = int(counter.value)
    if stopped == "finished" and failure is None and write_failure is None and step < config.schedule.steps:
        # Every process exited without reporting an error (e.g. killed, or failed while starting,
        # before its own error handling ran): not a finished run.
        codes = ", ".join(f"{p.name} {p.exitcode}" for p in processes)
        failure = (f"the worker processes exited at step {step:,} of {config.schedule.steps:,} without reporting an error "
                   f"(exit codes: {codes}). If training was started from a script, the script needs an "
                   f"`if __name__ == '__main__':` guard: workers are spawned and import it again.")
    saved = False
    try:
        if failure is None and write_failure is None:
            checkpoint()
        elif write_failure is None and not (start.fresh and step == 0) and \
                all(torch.isfinite(p).all() for p in shared.parameters()):
            checkpoint()  # the weights before the failing update, for inspection or a resume
            saved = True
    except FileWriteError as error:
        write_failure = error
    discarded = start.fresh and start.checkpoint_step == 0  # _train removes a new run that kept nothing
    if write_failure is not None:
        # No new checkpoint: the logs may lack rows before it. The last one and the rows before it are whole.
        then = f" ({failure.splitlines()[0]})" if failure else ""
        if discarded:
            raise TrainingError(f"{write_failure}. Training stopped at step {step:,}{then} before its first "
                                f"checkpoint, so the new run's files are removed from {run_dir}: free some space "
                                f"and run the same command again") from write_failure
        raise TrainingError(f"{write_failure}. Training stopped at step {step:,}{then}; the checkpoint "
                            f"{run_dir / CHECKPOINT} (step {start.checkpoint_step:,}) and the logs before it are "
                            f"intact: free some space and continue with --resume") from write_failure
    if failure is not None:
        if discarded:
            raise TrainingError(f"{failure} No checkpoint was written after step 0, so the new run's files are "
                                f"removed from {run_dir}: fix the cause and run the same command again.")
        where = (f"The weights from before that update are saved in {run_dir / CHECKPOINT}." if saved else
                 f"The last checkpoint ({run_dir / CHECKPOINT}, step {start.checkpoint_step:,}) is kept.")
        raise TrainingError(f"{failure} {where}")
    return step, stopped


def _stop_processes(processes: list, messages, timeout: float = 30.0) -> None:
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


class _Monitor:
    """Recent training episodes (by the step they started at) and throughput, for the progress bar
    and the logs."""

    def __init__(self, start_step: int, window: int = 100):
        self.window = window
        self.episodes: list[dict] = []
        self.start_time = time.monotonic()
        self._marks: list[tuple[float, int]] = [(self.start_time, start_step)]

    def restore(self, rows: list[dict[str, str]]) -> None:
        """The episodes a resumed run logged before its checkpoint (rows of episodes.csv), so that the
        recent success continues where it was."""
        for row in rows[-4 * self.window:]:
            try:
                self.episode({"start_step": int(float(row["start_step"])), "return": float(row["return"]),
                              "length": int(float(row["length"])), "success": row["success"] == "True",
                              "true_start": row.get("true_start", "True") != "False"})
            except (KeyError, ValueError):
                continue  # a row another version wrote differently: not worth refusing the resume for

    def episode(self, payload: dict) -> None:
        if not payload.get("true_start", True):
            return  # a start curriculum's episode: training success counts the task's own starts only
        self.episodes.append(payload)
        if len(self.episodes) > 4 * self.window:
            self.episodes = self.episodes[-2 * self.window:]

    def recent(self) -> dict[str, float]:
        # The most recently *started* finished episodes: counting by end step favours the short,
        # successful episodes that finish first.
        recent = sorted(self.episodes, key=lambda e: e["start_step"])[-self.window:]
        if not recent:
            return {"recent_success": float("nan"), "recent_return": float("nan"), "recent_length": float("nan")}
        return {"recent_success": float(np.mean([e["success"] for e in recent])),
                "recent_return": float(np.mean([e["return"] for e in recent])),
                "recent_length": float(np.mean([e["length"] for e in recent]))}

    def sps(self, step: int) -> float:
        now = time.monotonic()
        self._marks.append((now, step))
        while len(self._marks) > 2 and now - self._marks[0][0] > 30.0:
            self._marks.pop(0)
        (t0, s0) = self._marks[0]
        return (step - s0) / (now - t0) if now > t0 else 0.0
