"""Training an A3C run in its directory: the settings a run resolves to (:func:`resolve_config`), a new
or resumed run's start (config.json, teacher, step-0 checkpoint), one session of the worker processes
(:mod:`bimgame.learn.a3c.parent`), the final evaluation and the summary."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from bimgame.learn.a3c.parent import TABLES, Session, SessionStart
from bimgame.learn.a3c.settings import A3CConfig
from bimgame.learn.a3c.update import network_for
from bimgame.learn.checkpoints import apply_weights, load_checkpoint, load_init_weights, save_checkpoint
from bimgame.learn.common import run_evaluation
from bimgame.learn.curves import plot_run
from bimgame.learn.episode_monitor import Monitor
from bimgame.learn.init_network import check_init_network, init_settings_for
from bimgame.learn.learner_settings import DEFAULT_FINETUNE, FINETUNE_PRESETS, check_init_puzzle
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.rewards import EnvWrapper
from bimgame.learn.run_dir import TEACHER, RunDirectory, TrainingError, TrainResult, stored_run_config
from bimgame.learn.runs import CHECKPOINT, KIND_A3C, SUMMARY, read_run_settings, torch_threads
from bimgame.util.files import FileWriteError, read_json
from bimgame.util.signals import sigterm_as_interrupt

__all__ = ["train", "resolve_config", "finetune_settings"]


def resolve_config(
    given: dict[str, Any], run_dir: str | Path, *, resume: bool = False, init: str | Path | None = None
) -> A3CConfig:
    """A run's settings from the ones a user gave (``given``: field → value, only those given): the
    defaults, or with ``resume`` the run's stored settings, overridden by ``given``; with ``init``, the
    network settings of the run it points at unless given (a pre-trained π^s fixes the network's
    shape) and the fine-tuning preset's settings (``finetune``, default ``keep``) unless given. The
    command line and the reproduction both build their A3C settings here."""
    if resume:
        stored_run_config(run_dir, KIND_A3C)
        return read_run_settings(run_dir, "a3c", lambda stored: A3CConfig.from_dict({**stored, **given}))
    if init is not None:
        check_init_puzzle(init, given.get("task", A3CConfig.task))  # before its network settings are taken
        given = {**init_settings_for(init, given.get("num_mazes")), **finetune_settings(given.get("finetune")), **given}
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
    config.check_resumable_from(read_run_settings(run_dir, "a3c", A3CConfig.from_dict))


def _summarised(run_dir: Path, step: int) -> bool:
    """Whether the run's summary reports it finished at ``step``, with its final evaluation."""
    summary = read_json(run_dir / SUMMARY)
    return (
        summary is not None
        and summary.get("stopped") == "finished"
        and summary.get("steps") == step
        and summary.get("final_eval") is not None
    )


def train(
    config: A3CConfig,
    run_dir: str | Path,
    *,
    resume: bool = False,
    init: str | Path | None = None,
    env_wrapper: EnvWrapper | None = None,
    progress: bool = True,
    extra_config: dict | None = None,
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
        return _train(
            config,
            Path(run_dir),
            resume=resume,
            init=init,
            env_wrapper=env_wrapper,
            progress=progress,
            extra_config=extra_config,
        )


def _train(
    config: A3CConfig,
    run_dir: Path,
    *,
    resume: bool,
    init: str | Path | None,
    env_wrapper: EnvWrapper | None,
    progress: bool,
    extra_config: dict | None,
) -> TrainResult:
    shared = network_for(config)
    if not resume and config.has_teacher and init is None:
        raise ValueError(
            "A3CConfig.kl_coef > 0 (kickstarting) needs a pre-trained policy to stay close to: "
            "pass --init (or set kl_coef to 0)"
        )
    if not resume:
        check_init_puzzle(init, config.task)
        check_init_network(init, config.network)  # before the run directory: a refused start writes nothing
    with RunDirectory(run_dir, KIND_A3C, resume=resume) as run:
        start = _resumed(config, run, shared) if resume else _started(config, run, shared, init, extra_config)
        try:
            return _session(config, run, shared, start, env_wrapper=env_wrapper, progress=progress)
        finally:
            if start.checkpoint_step > 0:
                run.keep()  # trained and saved: a failure from now on leaves the run for --resume


def _resumed(config: A3CConfig, run: RunDirectory, shared: RecurrentActorCritic) -> SessionStart:
    """The start of a resumed run: its checkpoint's weights (put into ``shared``), step, seconds and
    optimiser statistics, and its teacher; refuses other settings and a run that is done."""
    _check_resume(run.path, config)
    payload = load_checkpoint(run / CHECKPOINT)
    apply_weights(shared, payload, run / CHECKPOINT)
    start = SessionStart(
        step=payload["step"],
        seconds=float(payload.get("seconds", 0.0)),
        optimizer=payload.get("optimizer"),
        fresh=False,
        checkpoint_step=payload["step"],
    )
    if config.has_teacher:
        start.teacher = load_checkpoint(run / TEACHER)["model"]
    if start.step >= config.schedule.steps and _summarised(run.path, start.step):
        raise ValueError(
            f"the run in {run.path} already has {start.step} steps >= steps={config.schedule.steps}; "
            f"pass a larger --steps to continue"
        )
    return start


def _started(
    config: A3CConfig,
    run: RunDirectory,
    shared: RecurrentActorCritic,
    init: str | Path | None,
    extra_config: dict | None,
) -> SessionStart:
    """The start of a new run: ``shared`` from ``init`` (if given), its teacher, and its settings, teacher
    and step-0 checkpoint written before anything else, so the directory always holds both."""
    start = SessionStart()
    load_init_weights(shared, init)
    if config.has_teacher:
        start.teacher = {k: v.detach().clone() for k, v in shared.state_dict().items()}
    run.write_config(
        {
            "a3c": config.to_dict(),
            "net": shared.config.to_dict(),
            "init": str(init) if init is not None else None,
            **(extra_config or {}),
        }
    )
    if start.teacher is not None:
        save_checkpoint(run / TEACHER, model=start.teacher, step=0, source=str(init))
    save_checkpoint(
        run / CHECKPOINT, model=shared.state_dict(), step=0, seconds=0.0, config=json.dumps(config.to_dict())
    )
    return start


def _session(
    config: A3CConfig,
    run: RunDirectory,
    shared: RecurrentActorCritic,
    start: SessionStart,
    *,
    env_wrapper: EnvWrapper | None,
    progress: bool,
) -> TrainResult:
    """Train from ``start`` to ``config.schedule.steps`` (nothing if the steps are all done), then evaluate
    and write the summary."""
    run_dir = run.path
    log = run.metric_log(
        TABLES, resume_step=None if start.fresh else start.step, keep_at_resume_step=("updates",)
    )  # an update's row is logged before its step's checkpoint
    monitor = Monitor(start.step)
    monitor.restore(log.kept["episodes"])
    started = time.monotonic() - start.seconds  # seconds count the whole run, across resumes
    step, stopped = start.step, "finished"
    if step < config.schedule.steps:
        try:
            session = Session(config, run_dir, shared, start, log, monitor, started, env_wrapper)
            step, stopped = session.run(progress)
        except BaseException:
            log.close()
            raise
    final_eval = None
    if stopped == "finished":
        try:
            with sigterm_as_interrupt():  # Ctrl-C or SIGTERM here: --resume does just this evaluation
                final_eval = {"step": step, **run_evaluation(shared, config)}
        except KeyboardInterrupt:
            stopped = "interrupted"
    try:
        if final_eval is not None:
            log.write("eval", step, final_eval, scalars=tuple(TABLES["eval"]))
        log.close()
        seconds = time.monotonic() - started
        run.write_summary(
            {"steps": step, "stopped": stopped, "seconds": seconds, "final_eval": final_eval, **monitor.recent()}
        )
    except FileWriteError as error:
        log.close()
        raise TrainingError(
            f"{error}. The checkpoint {run_dir / CHECKPOINT} (step {step:,}) is saved: free some "
            f"space and continue with --resume (a run whose steps are all done then only evaluates "
            f"and writes its summary)"
        ) from error
    try:
        plot_run(run_dir, title=f"A3C on {config.task} ({config.network.obs})")
    except (ValueError, OSError):
        pass  # no finished episode yet (nothing to plot), or no room for the figure: the logs hold it all
    return TrainResult(run_dir, step, stopped, final_eval, seconds)
