"""DAgger with the MPC expert (Ross, Gordon & Bagnell, "A Reduction of Imitation Learning and
Structured Prediction to No-Regret Online Learning", AISTATS 2011) — the paper's baseline.

Each iteration i:

1. **Roll out** ``episodes_per_iteration`` episodes. At every step the expert is asked for its
   action in the true simulator state (:class:`~bimgame.expert.RandomShootingMPC` on
   ``env.sim.get_state()``; on the labyrinth :class:`~bimgame.expert.labyrinth_mpc.LabyrinthMPC`, in
   the learner's kind of action), and the executed action is the expert's with probability β_i and
   the learner's (sampled from π) otherwise; β_i = ``beta0 · beta_decay^i`` (β_0 = 1: the first
   iteration is plain behaviour cloning data).
2. **Label** every visited state with the expert's action and **aggregate** the episodes into the
   dataset D; with ``expert_data``, D starts from that expert dataset's episodes (the
   demonstrations π^s was cloned from). The learner's inputs are what it saw while acting: the
   previous action it *executed* and the reward it got, so training and acting see the same input
   distribution.
3. **Retrain** the same recurrent network on all of D with the pre-training loss
   (:func:`bimgame.learn.supervised.policy_loss_terms`: −log π of the expert's action, value
   regression on the executed returns, L2).

Costs are counted separately so that curves against A3C are honest: ``env_steps`` are the steps
taken in the environment (what A3C's x-axis counts), ``expert_sim_steps`` the simulator steps the
expert spent planning its labels (K·H per label).

The run directory is resumable: the aggregated episodes of every finished iteration are saved
(``data/iteration_NNN.npz``, atomically), then the checkpoint commits the iteration — the weights
after it with the counts (``dagger_state.json`` is a readable copy of them); a restarted run
continues after the last committed iteration, and refuses to start over when the checkpoint or a
finished iteration's data is missing. A new run goes into a new or empty directory only, and one
that fails before its first iteration finished removes its files again; a run holds its directory's
lock while it works (:class:`~bimgame.learn.run_dir.RunDirectory`). ``bimgame evaluate`` and
``bimgame train --init`` accept the run. With in-run evaluation the run also keeps the iteration
that evaluated best in ``best.pt`` (:mod:`bimgame.learn.dagger.best`).

The settings (:class:`~bimgame.learn.dagger.settings.DAggerConfig`) are in
:mod:`bimgame.learn.dagger.settings` and the rollouts in :mod:`bimgame.learn.dagger.rollouts`; this
module runs the iterations in a run directory.
"""

from __future__ import annotations

import dataclasses
import io
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bimgame.envs.puzzles import puzzle
from bimgame.expert.datasets import dataset_manifest, dataset_mazes
from bimgame.expert.episode import Episode
from bimgame.learn.best_iterate import evaluation_rank, is_better, save_best
from bimgame.learn.checkpoints import apply_weights, load_checkpoint, load_init_weights, save_checkpoint
from bimgame.learn.dagger.best import repair_best
from bimgame.learn.dagger.rollouts import collect_episodes
from bimgame.learn.dagger.settings import DAggerConfig
from bimgame.learn.dagger.starts import demo_start_states
from bimgame.learn.evaluations import EVAL_COLUMNS, evaluate_greedy_and_sampled, evaluation_seed
from bimgame.learn.expert_data import check_dataset_task, dataset_action_type, load_sequences
from bimgame.learn.learner_settings import check_init_puzzle
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.run_dir import BEST, DAGGER_STATE, RunDirectory
from bimgame.learn.runs import CHECKPOINT, KIND_DAGGER, read_run_settings, torch_threads, write_run_json
from bimgame.learn.supervised import train_policy_epochs
from bimgame.util import files
from bimgame.util.files import FileWriteError
from bimgame.util.progress import ProgressBar
from bimgame.util.seeding import episode_seed
from bimgame.util.signals import sigterm_as_interrupt

__all__ = ["DAggerResult", "dagger"]

STATE = DAGGER_STATE
#: The counters of ``dagger_state.json``.
_STATE_KEYS = ("iteration", "env_steps", "expert_sim_steps", "labels")
#: The columns of ``dagger.csv`` (one row per iteration) after its ``step``.
_TABLE = [
    "iteration",
    "beta",
    "episodes",
    "dataset_steps",
    "expert_sim_steps",
    "labels",
    "train_loss",
    "train_accuracy",
    "rollout_success_rate",
    *EVAL_COLUMNS,
    "seconds",
]
#: The columns of a run with ``stall_steps``: also how many rollouts it ended.
_AFTER = _TABLE.index("rollout_success_rate") + 1
_STALL_TABLE = [*_TABLE[:_AFTER], "rollouts_stalled", *_TABLE[_AFTER:]]


def _save_episodes(path: Path, episodes: list[Episode]) -> None:
    """Write an iteration's ``episodes`` to ``path`` as one compressed ``.npz``, atomically."""
    buffer = io.BytesIO()
    # NumPy's stub types **kwds as if a name could be its `allow_pickle` keyword (a bool); every value is an array.
    np.savez_compressed(buffer, **Episode.concatenate(episodes))  # type: ignore[arg-type]
    try:
        files.atomic_write_bytes(path, buffer.getvalue())
    except OSError as error:
        raise FileWriteError.from_error(path, error) from error


def _load_episodes(path: Path) -> list[Episode]:
    """The episodes :func:`_save_episodes` wrote to ``path`` (read without unpickling anything)."""
    with np.load(path, allow_pickle=False) as data:
        return Episode.split({key: data[key] for key in data.files})


# ------------------------------------------------------------------------------ the loop
@dataclasses.dataclass
class DAggerResult:
    """What a call of :func:`dagger` did, and where the run stands."""

    run_dir: Path
    iterations: int
    """Iterations finished in the run, in all."""
    iterations_run: int
    """Iterations this call ran (0: the run had already finished them all)."""
    env_steps: int
    expert_sim_steps: int
    dataset_steps: int
    final_eval: dict[str, float] | None
    seconds: float
    best: dict[str, Any] | None = None
    """The best iterate by the in-run evaluation (iteration, step, rank; its weights in ``best.pt``),
    None without in-run evaluation (:mod:`bimgame.learn.dagger.best`)."""


def dagger(
    config: DAggerConfig,
    run_dir: str | Path,
    *,
    resume: bool = False,
    init: str | Path | None = None,
    progress: bool = True,
) -> DAggerResult:
    """Run DAgger into ``run_dir`` (see the module notes); ``init`` starts the learner from a
    pre-trained policy's weights; ``resume`` continues after the last finished iteration."""
    with torch_threads():
        return _dagger(config, run_dir, resume=resume, init=init, progress=progress)


def _dagger(
    config: DAggerConfig, run_dir: Path | str, *, resume: bool, init: str | Path | None, progress: bool
) -> DAggerResult:
    """:func:`dagger` within the caller's torch threads: the run directory held, new or resumed."""
    check_init_puzzle(init, config.learner.task)
    net = config.learner.build_policy(config.learner.seed, puzzle(config.learner.task).spec)
    with RunDirectory(run_dir, KIND_DAGGER, resume=resume) as run:
        state = _resume_state(run.path, config, net) if resume else _new_state(net, init)
        try:
            if not resume:
                _start(config, run, net, init, state)
            with sigterm_as_interrupt():
                return _iterations(config, run, net, state, resume=resume, progress=progress)
        except FileWriteError as error:
            if run.discards(error):
                raise error.with_advice(
                    f"No iteration had finished, so the new run's files are removed from "
                    f"{run.path}: free some space and run the same command again"
                ) from error
            raise error.with_advice(
                f"The iterations finished before ({state['iteration']}) are saved in {run.path}: "
                f"free some space and continue with --resume"
            ) from error


def _new_state(net: RecurrentActorCritic, init: str | Path | None) -> dict[str, Any]:
    """The state of a new run, its learner ``net`` started from ``init``'s weights if given."""
    load_init_weights(net, init)
    return {"iteration": 0, "env_steps": 0, "expert_sim_steps": 0, "labels": 0, "seconds": 0.0, "best": None}


def _start(
    config: DAggerConfig, run: RunDirectory, net: RecurrentActorCritic, init: str | Path | None, state: dict[str, Any]
) -> None:
    """Write a new run's settings, starting weights and state, before any work: a run directory always
    holds all three, so --resume never has to guess."""
    run.write_config(
        {
            "task": config.learner.task,
            "seed": config.learner.seed,
            "network": config.learner.network_settings().to_dict(),
            "net": net.config.to_dict(),
            "dagger": config.to_dict(),
            "init": None if init is None else str(init),
            "torch_threads": torch.get_num_threads(),
            **config.maze_options,
        }
    )
    save_checkpoint(run / CHECKPOINT, model=net.state_dict(), step=0, **state)
    write_run_json(run / STATE, state)


def _resume_state(run_dir: Path, config: DAggerConfig, net: RecurrentActorCritic) -> dict[str, Any]:
    """Check that the run in ``run_dir`` can be continued with ``config``, load its weights into
    ``net`` and return its state; refuses, naming what is missing, rather than starting over.

    The checkpoint is the commit point: it holds the weights and the counts of the last finished
    iteration (``dagger_state.json`` is a copy for readers, rewritten here if a kill left it behind).
    ``run_dir`` is checked to hold a DAgger run with its checkpoint."""
    config.require_resumable_from(read_run_settings(run_dir, "dagger", DAggerConfig.from_dict))
    payload = load_checkpoint(run_dir / CHECKPOINT)
    path = run_dir / STATE
    copy = files.read_json(path)
    if all(_count(payload.get(k)) for k in _STATE_KEYS):
        state = _counts(payload)
    else:  # a checkpoint of an earlier version: the state file holds the counts
        state = _counts_of_state_file(run_dir, copy, payload["step"])
    _require_iteration_data(run_dir, state["iteration"])
    apply_weights(net, payload, run_dir / CHECKPOINT)
    repair_best(run_dir / BEST, payload["model"], state["best"], state["iteration"])
    if copy != state:
        write_run_json(path, state)
    return state


def _counts(source: dict[str, Any]) -> dict[str, Any]:
    """The run's state in ``source`` (a checkpoint or a state file): its counts, seconds and best
    iterate (:mod:`bimgame.learn.dagger.best`; None in runs of earlier versions)."""
    return {k: source[k] for k in _STATE_KEYS} | {
        "seconds": float(source.get("seconds", 0.0)),
        "best": source.get("best"),
    }


def _counts_of_state_file(run_dir: Path, copy: dict[str, Any] | None, checkpoint_step: int) -> dict[str, Any]:
    """The state in ``run_dir``'s state file (read as ``copy``), for a checkpoint of an earlier version
    that holds no counts; refused unless it counts the checkpoint's ``checkpoint_step``."""
    path = run_dir / STATE
    if not path.is_file():
        raise ValueError(
            f"--resume: {run_dir} has no {STATE} and its checkpoint holds no counts, so the DAgger "
            f"run in it cannot be continued. Start anew without --resume in a new --run-dir"
        )
    if copy is None or not all(_count(copy.get(k)) for k in _STATE_KEYS):
        raise ValueError(f"{path} is not a DAgger state (it needs the counts {', '.join(_STATE_KEYS)})")
    state = _counts(copy)
    if checkpoint_step != state["env_steps"]:
        raise ValueError(
            f"--resume: {run_dir / CHECKPOINT} holds the weights of step {checkpoint_step}, but "
            f"{path} counts {state['env_steps']} steps (stopped between the two writes); the "
            f"iteration cannot be redone from those weights. Start anew in a new --run-dir"
        )
    return state


def _require_iteration_data(run_dir: Path, iterations: int) -> None:
    """Refuse to resume unless the aggregated data of the first ``iterations`` iterations is saved."""
    missing = [str(_data_path(run_dir, i)) for i in range(iterations) if not _data_path(run_dir, i).is_file()]
    if missing:
        raise ValueError(
            f"--resume: the aggregated data of finished iterations is missing ({', '.join(missing)}), "
            f"so the DAgger run in {run_dir} cannot be continued. Start anew without --resume in a "
            f"new --run-dir"
        )


def _count(value: Any) -> bool:
    """Whether ``value`` is a count: a non-negative int (not a bool)."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


#: The columns of ``dagger.csv`` that also go to TensorBoard.
_SCALARS = (
    "train_loss",
    "train_accuracy",
    "rollout_success_rate",
    "greedy_success_rate",
    "sampled_success_rate",
    "dataset_steps",
    "expert_sim_steps",
)


def _iterations(
    config: DAggerConfig,
    run: RunDirectory,
    net: RecurrentActorCritic,
    state: dict[str, Any],
    *,
    resume: bool,
    progress: bool,
) -> DAggerResult:
    """The iterations after the last finished one (``state``, updated in place); each one's checkpoint
    commits it, and the first keeps a new run's files whatever happens later."""
    run_dir = run.path
    first_iteration = state["iteration"]
    dataset = _demonstrations(config, progress=progress)
    demo_states = demo_start_states(config)
    for i in range(state["iteration"]):
        dataset += _load_episodes(_data_path(run_dir, i))
    # The row at the checkpoint's step is the last finished iteration's (written before it): kept.
    log = run.metric_log(
        {"dagger": _TABLE if config.stall_steps is None else _STALL_TABLE},
        resume_step=state["env_steps"] if resume else None,
        keep_at_resume_step=("dagger",),
    )
    started = time.monotonic() - state.get("seconds", 0.0)
    final_eval = None
    learner = config.learner
    try:
        with ProgressBar(
            f"DAgger {learner.task} {learner.obs}", config.iterations, completed=state["iteration"], enabled=progress
        ) as bar:
            for iteration in range(state["iteration"], config.iterations):
                outcome = _run_iteration(config, run_dir, net, dataset, iteration, demo_states)
                final_eval = outcome.evaluation
                done = _counts_after(state, outcome.costs, iteration, time.monotonic() - started, outcome.evaluation)
                row = _log_row(config, iteration, outcome, dataset, done)
                # The log row before the checkpoint, which commits the iteration (weights and counts):
                # a run killed in between redoes the iteration from the weights before it, and the
                # resumed log drops the orphaned row (rows after the checkpoint's step).
                log.write("dagger", done["env_steps"], row, scalars=_SCALARS)
                save_checkpoint(run_dir / CHECKPOINT, model=net.state_dict(), step=done["env_steps"], **done)
                if done["best"] is not state["best"]:  # written after the commit (see dagger.best)
                    save_best(run_dir / BEST, net.state_dict(), done["best"])
                state.update(done)
                run.keep()
                write_run_json(run_dir / STATE, done)  # a copy of the counts for readers
                _show_progress(bar, iteration, row)
                if not math.isfinite(outcome.summary["loss"]):
                    raise RuntimeError(
                        f"DAgger's training loss is not finite at iteration {iteration}; "
                        f"lower the learning rate (now {config.learner.lr})"
                    )
    finally:
        log.close()
    return DAggerResult(
        run_dir,
        state["iteration"],
        state["iteration"] - first_iteration,
        state["env_steps"],
        state["expert_sim_steps"],
        sum(len(e) for e in dataset),
        final_eval,
        time.monotonic() - started,
        state["best"],
    )


@dataclasses.dataclass(frozen=True)
class _Outcome:
    """What one iteration did: its β, what its rollouts cost (:func:`collect_episodes`), the last
    training epoch's summary, and the evaluation after it (None without evaluation episodes)."""

    beta: float
    costs: dict[str, int]
    summary: dict[str, float]
    evaluation: dict[str, float] | None


def _run_iteration(
    config: DAggerConfig,
    run_dir: Path,
    net: RecurrentActorCritic,
    dataset: list[Episode],
    iteration: int,
    demo_states: np.ndarray | None,
) -> _Outcome:
    """Iteration ``iteration``'s work: roll out (a share starting in ``demo_states``), save and
    aggregate the labelled episodes into ``dataset`` (in place), retrain ``net`` on all of it, evaluate it."""
    learner = config.learner
    seed = episode_seed(learner.seed, iteration)
    beta = config.beta(iteration)
    episodes, costs = collect_episodes(net, config, beta, seed, demo_states)
    _save_episodes(_data_path(run_dir, iteration), episodes)
    dataset += episodes
    rng = np.random.default_rng(seed)
    max_tilt = puzzle(learner.task).spec.max_tilt
    summary = train_policy_epochs(net, dataset, learner, config.epochs_per_iteration, rng, max_tilt)
    evaluation = (
        evaluate_greedy_and_sampled(
            net,
            task=learner.task,
            obs=learner.obs,
            episodes=config.eval_episodes,
            seed=evaluation_seed(learner.seed),
            time_limit=learner.time_limit,
            mazes=config.maze_options or None,
        )
        if config.eval_episodes
        else None
    )
    return _Outcome(beta, costs, summary, evaluation)


def _demonstrations(config: DAggerConfig, *, progress: bool) -> list[Episode]:
    """The episodes of ``config.expert_data`` that start the aggregated dataset (none without it); a
    dataset of another task, puzzle or kind of action is refused by name."""
    if config.expert_data is None:
        return []
    learner = config.learner
    manifest = dataset_manifest(config.expert_data)
    check_dataset_task(manifest, learner.task, config.expert_data)
    if dataset_action_type(manifest) != learner.action_type:
        raise ValueError(
            f"DAggerConfig.expert_data {config.expert_data} holds {dataset_action_type(manifest)} actions, the "
            f"learner has {learner.action_type} ones: use a dataset generated with --action-type {learner.action_type}"
        )
    on_mazes = bool(dataset_mazes(config.expert_data))
    if on_mazes != (config.num_mazes is not None):
        merl, random = "MERL's maze alone", "random mazes"
        advice = "set num_mazes (--num-mazes)" if on_mazes else "use a dataset generated with --num-mazes"
        raise ValueError(
            f"DAggerConfig.expert_data {config.expert_data} was generated on {random if on_mazes else merl}, "
            f"the run rolls out on {merl if config.num_mazes is None else random}: {advice}"
        )
    return load_sequences(
        config.expert_data,
        learner.task,
        learner.obs,
        learner.gamma,
        progress=progress,
        gate_bearings=bool(getattr(learner, "gate_bearings", False)),
        surroundings=bool(getattr(learner, "surroundings", False)),
        motion=bool(getattr(learner, "motion", False)),
    )


def _counts_after(
    state: dict[str, Any],
    costs: dict[str, int],
    iteration: int,
    seconds: float,
    evaluation: dict[str, float] | None,
) -> dict[str, Any]:
    """The run's state once ``iteration`` (which cost ``costs`` and evaluated as ``evaluation``) has
    finished, ``seconds`` into the run; its best iterate is this one if it ranks higher."""
    done = dict(state)
    for key in ("env_steps", "expert_sim_steps", "labels"):
        done[key] += costs[key]
    done["iteration"] = iteration + 1
    done["seconds"] = seconds
    if evaluation is not None and is_better(evaluation, state["best"]):
        done["best"] = {"iteration": iteration, "step": done["env_steps"], "rank": evaluation_rank(evaluation)}
    return done


def _log_row(
    config: DAggerConfig, iteration: int, outcome: _Outcome, dataset: list[Episode], done: dict[str, Any]
) -> dict[str, Any]:
    """The ``dagger.csv`` row of ``iteration``: what it did, the aggregated ``dataset`` and the counts
    ``done`` after it."""
    return {
        "iteration": iteration,
        "beta": outcome.beta,
        "episodes": len(dataset),
        "dataset_steps": sum(len(e) for e in dataset),
        "expert_sim_steps": done["expert_sim_steps"],
        "labels": done["labels"],
        "train_loss": outcome.summary["loss"],
        "train_accuracy": outcome.summary["accuracy"],
        "rollout_success_rate": outcome.costs["successes"] / config.episodes_per_iteration,
        **({} if config.stall_steps is None else {"rollouts_stalled": outcome.costs["stalled"]}),
        "seconds": done["seconds"],
        **(outcome.evaluation or {}),
    }


def _show_progress(bar: ProgressBar, iteration: int, row: dict[str, Any]) -> None:
    """Show on ``bar`` that ``iteration`` finished, with its β, the dataset's size and greedy success."""
    success = row.get("greedy_success_rate")
    bar.update(
        completed=iteration + 1,
        info=f"β {row['beta']:.2f}  dataset {row['dataset_steps']:,} steps"
        + ("" if success is None else f"  greedy success {success:.0%}"),
    )


def _data_path(run_dir: Path, iteration: int) -> Path:
    """Where the aggregated episodes of ``iteration`` are saved."""
    return run_dir / "data" / f"iteration_{iteration:03d}.npz"
