"""DAgger with the MPC expert (Ross, Gordon & Bagnell, "A Reduction of Imitation Learning and
Structured Prediction to No-Regret Online Learning", AISTATS 2011) — the paper's baseline.

Each iteration i:

1. **Roll out** ``episodes_per_iteration`` episodes. At every step the expert is asked for its
   action in the true simulator state (:class:`~bimgame.expert.RandomShootingMPC` on
   ``env.sim.get_state()``), and the executed action is the expert's with probability β_i and the
   learner's (sampled from π) otherwise; β_i = ``beta0 · beta_decay^i`` (β_0 = 1: the first
   iteration is plain behaviour cloning data).
2. **Label** every visited state with the expert's action and **aggregate** the episodes into the
   dataset D. The learner's inputs are what it saw while acting: the previous action it *executed*
   and the reward it got, so training and acting see the same input distribution.
3. **Retrain** the same recurrent network on all of D with the pre-training loss
   (:func:`bimgame.learn.supervised.policy_loss_terms`: cross-entropy of the expert's action, value
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
``bimgame train --init`` accept the run.
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

from bimgame.envs.env import BallInMazeEnv
from bimgame.expert.episode import Episode
from bimgame.expert.mpc import MPCConfig, RandomShootingMPC
from bimgame.learn.actor import RecurrentActor, tilt_input
from bimgame.learn.checkpoints import CheckpointError, apply_weights, load_checkpoint, load_weights, save_checkpoint
from bimgame.learn.common import EVAL_COLUMNS, evaluate_greedy_and_sampled, evaluation_seed
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.run_dir import DAGGER_STATE, RunDirectory, stored_run_config
from bimgame.learn.runs import CHECKPOINT, KIND_DAGGER, read_run_settings, torch_threads, write_run_json
from bimgame.learn.supervised import PretrainConfig, train_policy_epochs
from bimgame.sim.maze import MazeSpec
from bimgame.util import files
from bimgame.util.files import FileWriteError
from bimgame.util.progress import ProgressBar
from bimgame.util.seeding import episode_seed
from bimgame.util.settings import from_dict, require_int
from bimgame.util.signals import sigterm_as_interrupt

__all__ = ["resolve_dagger_config", "DAggerConfig", "DAggerResult", "dagger", "collect_episodes", "KIND_DAGGER"]

STATE = DAGGER_STATE
#: The counters of ``dagger_state.json``.
_STATE_KEYS = ("iteration", "env_steps", "expert_sim_steps", "labels")
#: Typo guards on what runs side by side (each rollout has its own simulator and expert).
_LARGEST = {"episodes_per_iteration": (10_000, "rollouts run side by side"),
            "eval_episodes": (10_000, "episodes run side by side"),
            "max_episode_steps": (10**9, "steps")}
_TABLE = ["iteration", "beta", "episodes", "dataset_steps", "expert_sim_steps", "labels", "train_loss",
          "train_accuracy", "rollout_success_rate", *EVAL_COLUMNS, "seconds"]


@dataclasses.dataclass(frozen=True)
class DAggerConfig:
    """Settings of a DAgger run; the network and its loss are ``learner``'s (a
    :class:`~bimgame.learn.supervised.PretrainConfig`: task, observations, sizes, lr, L2, γ). The
    learner has no auxiliary heads nor asymmetric critic: it trains on its own rollouts, which record
    no simulator states."""

    learner: PretrainConfig = dataclasses.field(
        default_factory=lambda: PretrainConfig(task="STG1", aux_heads=False, asymmetric_critic=False))
    iterations: int = 10
    """Iterations to run (roll out, label, aggregate, retrain)."""
    episodes_per_iteration: int = 20
    """Learner rollouts per iteration, run side by side."""
    beta0: float = 1.0
    """Probability of executing the expert's action in iteration 0 (1: behaviour cloning data)."""
    beta_decay: float = 0.5
    """β_i = beta0 · beta_decay^i."""
    epochs_per_iteration: int = 10
    """Passes over the aggregated dataset after each iteration."""
    expert: MPCConfig = dataclasses.field(default_factory=MPCConfig)
    max_episode_steps: int | None = None
    """Time limit of the rollouts; None: the task's."""
    eval_episodes: int = 20
    """Greedy and sampled evaluation episodes after every iteration (0: none)."""

    def __post_init__(self) -> None:
        if self.learner.target != "policy":
            raise ValueError("DAggerConfig.learner must train a policy (target='policy')")
        if self.learner.aux_heads or self.learner.asymmetric_critic:
            raise ValueError("DAggerConfig.learner must have aux_heads=False and asymmetric_critic=False: DAgger "
                             "trains on its own rollouts, which record no simulator states")
        for name in ("iterations", "episodes_per_iteration", "epochs_per_iteration"):
            require_int("DAggerConfig", name, getattr(self, name), 1)
        for name in ("beta0", "beta_decay"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0.0 <= value <= 1.0):
                raise ValueError(f"DAggerConfig.{name} must be in [0, 1], got {value!r}")
        require_int("DAggerConfig", "eval_episodes", self.eval_episodes, 0)
        require_int("DAggerConfig", "max_episode_steps", self.max_episode_steps, 1, optional=True)
        for name, (largest, unit) in _LARGEST.items():
            value = getattr(self, name)
            if value is not None and value > largest:
                raise ValueError(f"DAggerConfig.{name} must be at most {largest:,} ({unit}), got {value!r}")

    #: What a resumed run may change.
    RESUMABLE_CHANGES = ("iterations", "eval_episodes")

    def beta(self, iteration: int) -> float:
        return self.beta0 * self.beta_decay ** iteration

    @property
    def time_limit(self) -> int:
        return self.max_episode_steps or self.learner.time_limit

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> DAggerConfig:
        values = dict(values)
        if "learner" in values:
            values["learner"] = PretrainConfig.from_dict(values["learner"])
        if "expert" in values:
            values["expert"] = from_dict(MPCConfig, values["expert"], "MPC settings")
        return from_dict(cls, values, "DAgger settings")


def resolve_dagger_config(learner: PretrainConfig, given: dict[str, Any], run_dir: str | Path, *,
                          resume: bool) -> DAggerConfig:
    """A run's DAgger settings: ``learner`` and ``given`` (DAggerConfig fields) for a new run; a resumed
    run keeps its stored settings except those it may change (:attr:`DAggerConfig.RESUMABLE_CHANGES`)."""
    if not resume:
        return DAggerConfig(learner=learner, **given)
    stored = _stored_config(run_dir)
    return dataclasses.replace(stored, **{k: v for k, v in given.items() if k in DAggerConfig.RESUMABLE_CHANGES})


def _stored_config(run_dir: str | Path) -> DAggerConfig:
    stored_run_config(run_dir, KIND_DAGGER)
    return read_run_settings(run_dir, "dagger", DAggerConfig.from_dict)


# ------------------------------------------------------------------------------ rollouts
@torch.no_grad()
def collect_episodes(net: RecurrentActorCritic, config: DAggerConfig, beta: float, seed: int,
                     ) -> tuple[list[Episode], dict[str, int]]:
    """``episodes_per_iteration`` episodes, run side by side (one batched forward pass per step),
    executing the expert's action with probability ``beta`` and the learner's sampled action
    otherwise; every visited state is labelled by the expert. Returns the episodes (as
    :class:`~bimgame.expert.episode.Episode` records, ``actions`` being the expert's labels and
    ``executed`` what was done) and the costs: ``env_steps``, ``labels``, ``expert_sim_steps``,
    ``successes``."""
    learner = config.learner
    sequence = np.random.SeedSequence([seed])
    env_seed, torch_seed, mix_seed, *expert_seeds = sequence.generate_state(3 + config.episodes_per_iteration)
    count = config.episodes_per_iteration
    envs = [BallInMazeEnv(learner.task, obs_mode=learner.obs) for _ in range(count)]
    experts = [RandomShootingMPC(envs[0].maze, config.expert, rng=np.random.default_rng(int(s)), task=learner.task)
               for s in expert_seeds]
    mix = np.random.default_rng(int(mix_seed))
    actor = RecurrentActor(net, count, generator=torch.Generator().manual_seed(int(torch_seed)))
    max_tilt = envs[0].maze.max_tilt
    records: list[dict[str, list]] = [{k: [] for k in ("obs", "actions", "executed", "rewards", "tilt")}
                                      for _ in range(count)]
    observations, tilts = [], []
    for i, env in enumerate(envs):
        obs, info = env.reset(seed=int(env_seed) + i)
        observations.append(obs)
        tilts.append(info["tilt"])
    active = np.ones(count, dtype=bool)
    successes = 0
    steps = 0
    try:
        while active.any() and steps < config.time_limit:
            obs_batch = np.stack(observations)
            tilt_batch = tilt_input({"tilt": np.stack(tilts)}, max_tilt)
            policy_actions, _, _ = actor.act(obs_batch, tilt_batch)
            executed = policy_actions.clone()
            rewards = np.zeros(count)
            done = ~active.copy()
            for i in np.flatnonzero(active):
                label = experts[i].act(envs[i].sim.get_state())
                action = label if mix.random() < beta else int(policy_actions[i])
                executed[i] = action
                record = records[i]
                record["obs"].append(observations[i])
                record["tilt"].append(tilts[i])
                record["actions"].append(label)
                record["executed"].append(action)
                obs, reward, terminated, _, info = envs[i].step(action)
                record["rewards"].append(reward)
                observations[i], tilts[i], rewards[i] = obs, info["tilt"], reward
                if terminated:
                    active[i] = False
                    done[i] = True
                    successes += int(info["is_success"])
            steps += 1
            # Finished episodes keep stepping the actor on stale inputs; their records are closed.
            actor.observe(executed, rewards, done)
    finally:
        for env in envs:
            env.close()
        for expert in experts:
            expert.close()
    episodes = [_as_episode(r, learner.gamma) for r in records]
    labels = sum(len(e) for e in episodes)
    costs = {"env_steps": labels, "labels": labels, "successes": successes,
             "expert_sim_steps": labels * config.expert.n_samples * config.expert.horizon}
    return episodes, costs


def _as_episode(record: dict[str, list], gamma: float) -> Episode:
    return Episode.from_steps(obs=np.stack(record["obs"]), actions=record["actions"], rewards=record["rewards"],
                              tilt=record["tilt"], gamma=gamma, executed=record["executed"])


def _save_episodes(path: Path, episodes: list[Episode]) -> None:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **Episode.concatenate(episodes))
    try:
        files.atomic_write_bytes(path, buffer.getvalue())
    except OSError as error:
        raise FileWriteError.from_error(path, error) from error


def _load_episodes(path: Path) -> list[Episode]:
    with np.load(path, allow_pickle=False) as data:
        return Episode.split({key: data[key] for key in data.files})


# ------------------------------------------------------------------------------ the loop
@dataclasses.dataclass
class DAggerResult:
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


def dagger(config: DAggerConfig, run_dir: str | Path, *, resume: bool = False, init: str | Path | None = None,
           progress: bool = True) -> DAggerResult:
    """Run DAgger into ``run_dir`` (see the module notes); ``init`` starts the learner from a
    pre-trained policy's weights; ``resume`` continues after the last finished iteration."""
    with torch_threads():
        return _dagger(config, run_dir, resume=resume, init=init, progress=progress)


def _dagger(config: DAggerConfig, run_dir: Path | str, *, resume: bool, init: str | Path | None,
            progress: bool) -> DAggerResult:
    net = config.learner.build_policy(config.learner.seed)
    with RunDirectory(run_dir, KIND_DAGGER, resume=resume) as run:
        state = _resume_state(run.path, config, net) if resume else _new_state(net, init)
        try:
            if not resume:
                _start(config, run, net, init, state)
            with sigterm_as_interrupt():
                return _iterations(config, run, net, state, resume=resume, progress=progress)
        except FileWriteError as error:
            if run.discards(error):
                raise error.with_advice(f"No iteration had finished, so the new run's files are removed from "
                                        f"{run.path}: free some space and run the same command again") from error
            raise error.with_advice(f"The iterations finished before ({state['iteration']}) are saved in {run.path}: "
                                    f"free some space and continue with --resume") from error


def _new_state(net: RecurrentActorCritic, init: str | Path | None) -> dict[str, Any]:
    """The state of a new run, its learner ``net`` started from ``init``'s weights if given."""
    if init is not None:
        try:
            load_weights(net, init)
        except CheckpointError as error:
            raise CheckpointError(f"--init: {error}") from None
    return {"iteration": 0, "env_steps": 0, "expert_sim_steps": 0, "labels": 0, "seconds": 0.0}


def _start(config: DAggerConfig, run: RunDirectory, net: RecurrentActorCritic, init: str | Path | None,
           state: dict[str, Any]) -> None:
    """Write a new run's settings, starting weights and state, before any work: a run directory always
    holds all three, so --resume never has to guess."""
    run.write_config({"task": config.learner.task, "seed": config.learner.seed,
                      "network": config.learner.network_settings().to_dict(), "net": net.config.to_dict(),
                      "dagger": config.to_dict(), "init": None if init is None else str(init)})
    save_checkpoint(run / CHECKPOINT, model=net.state_dict(), step=0, **state)
    write_run_json(run / STATE, state)


def _resume_state(run_dir: Path, config: DAggerConfig, net: RecurrentActorCritic) -> dict[str, Any]:
    """Check that the run in ``run_dir`` can be continued with ``config``, load its weights into
    ``net`` and return its state; refuses, naming what is missing, rather than starting over.

    The checkpoint is the commit point: it holds the weights and the counts of the last finished
    iteration (``dagger_state.json`` is a copy for readers, rewritten here if a kill left it behind).
    ``run_dir`` is checked to hold a DAgger run with its checkpoint."""
    stored = read_run_settings(run_dir, "dagger", DAggerConfig.from_dict)
    changed = [name for name in ("learner", "episodes_per_iteration", "beta0", "beta_decay",
                                 "epochs_per_iteration", "expert", "max_episode_steps")
               if getattr(stored, name) != getattr(config, name)]
    if changed:
        raise ValueError(f"--resume must keep the run's settings; changed: {', '.join(changed)}. "
                         f"Allowed to change: {', '.join(DAggerConfig.RESUMABLE_CHANGES)}")
    payload = load_checkpoint(run_dir / CHECKPOINT)
    path = run_dir / STATE
    copy = files.read_json(path)
    if all(_count(payload.get(k)) for k in _STATE_KEYS):
        state = {k: payload[k] for k in _STATE_KEYS} | {"seconds": float(payload.get("seconds", 0.0))}
    else:  # a checkpoint of an earlier version: the state file holds the counts
        if not path.is_file():
            raise ValueError(f"--resume: {run_dir} has no {STATE} and its checkpoint holds no counts, so the DAgger "
                             f"run in it cannot be continued. Start anew without --resume in a new --run-dir")
        if copy is None or not all(_count(copy.get(k)) for k in _STATE_KEYS):
            raise ValueError(f"{path} is not a DAgger state (it needs the counts {', '.join(_STATE_KEYS)})")
        state = {k: copy[k] for k in _STATE_KEYS} | {"seconds": float(copy.get("seconds", 0.0))}
        if payload["step"] != state["env_steps"]:
            raise ValueError(f"--resume: {run_dir / CHECKPOINT} holds the weights of step {payload['step']}, but "
                             f"{path} counts {state['env_steps']} steps (stopped between the two writes); the "
                             f"iteration cannot be redone from those weights. Start anew in a new --run-dir")
    missing = [str(_data_path(run_dir, i)) for i in range(state["iteration"]) if not _data_path(run_dir, i).is_file()]
    if missing:
        raise ValueError(f"--resume: the aggregated data of finished iterations is missing ({', '.join(missing)}), "
                         f"so the DAgger run in {run_dir} cannot be continued. Start anew without --resume in a "
                         f"new --run-dir")
    apply_weights(net, payload, run_dir / CHECKPOINT)
    if copy != state:
        write_run_json(path, state)
    return state


def _count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _iterations(config: DAggerConfig, run: RunDirectory, net: RecurrentActorCritic, state: dict[str, Any], *,
                resume: bool, progress: bool) -> DAggerResult:
    """The iterations after the last finished one (``state``, updated in place); each one's checkpoint
    commits it, and the first keeps a new run's files whatever happens later."""
    run_dir = run.path
    first_iteration = state["iteration"]
    dataset: list[Episode] = []
    for i in range(state["iteration"]):
        dataset += _load_episodes(_data_path(run_dir, i))
    # The row at the checkpoint's step is the last finished iteration's (written before it): kept.
    log = run.metric_log({"dagger": _TABLE}, resume_step=state["env_steps"] if resume else None,
                         keep_at_resume_step=("dagger",))
    started = time.monotonic() - state.get("seconds", 0.0)
    final_eval = None
    learner = config.learner
    try:
        with ProgressBar(f"DAgger {learner.task} {learner.obs}", config.iterations, completed=state["iteration"],
                         enabled=progress) as bar:
            for iteration in range(state["iteration"], config.iterations):
                seed = episode_seed(config.learner.seed, iteration)
                beta = config.beta(iteration)
                episodes, costs = collect_episodes(net, config, beta, seed)
                _save_episodes(_data_path(run_dir, iteration), episodes)
                dataset += episodes
                rng = np.random.default_rng(seed)
                summary = train_policy_epochs(net, dataset, config.learner, config.epochs_per_iteration, rng,
                                              MazeSpec.merl().max_tilt)
                final_eval = (evaluate_greedy_and_sampled(net, task=learner.task, obs=learner.obs,
                                                          episodes=config.eval_episodes, seed=evaluation_seed(learner.seed),
                                                          time_limit=learner.time_limit)
                              if config.eval_episodes else None)
                done = dict(state)
                for key in ("env_steps", "expert_sim_steps", "labels"):
                    done[key] += costs[key]
                done["iteration"] = iteration + 1
                done["seconds"] = time.monotonic() - started
                row = {"iteration": iteration, "beta": beta, "episodes": len(dataset),
                       "dataset_steps": sum(len(e) for e in dataset),
                       "expert_sim_steps": done["expert_sim_steps"], "labels": done["labels"],
                       "train_loss": summary["loss"], "train_accuracy": summary["accuracy"],
                       "rollout_success_rate": costs["successes"] / config.episodes_per_iteration,
                       "seconds": done["seconds"], **(final_eval or {})}
                # The log row before the checkpoint, which commits the iteration (weights and counts):
                # a run killed in between redoes the iteration from the weights before it, and the
                # resumed log drops the orphaned row (rows after the checkpoint's step).
                log.write("dagger", done["env_steps"], row,
                          scalars=("train_loss", "train_accuracy", "rollout_success_rate", "greedy_success_rate",
                                   "sampled_success_rate", "dataset_steps", "expert_sim_steps"))
                save_checkpoint(run_dir / CHECKPOINT, model=net.state_dict(), step=done["env_steps"], **done)
                state.update(done)
                run.keep()
                write_run_json(run_dir / STATE, done)  # a copy of the counts for readers
                success = row.get("greedy_success_rate")
                bar.update(completed=iteration + 1,
                           info=f"β {row['beta']:.2f}  dataset {row['dataset_steps']:,} steps"
                                + ("" if success is None else f"  greedy success {success:.0%}"))
                if not math.isfinite(summary["loss"]):
                    raise RuntimeError(f"DAgger's training loss is not finite at iteration {iteration}; "
                                       f"lower the learning rate (now {config.learner.lr})")
    finally:
        log.close()
    return DAggerResult(run_dir, state["iteration"], state["iteration"] - first_iteration, state["env_steps"],
                        state["expert_sim_steps"],
                        sum(len(e) for e in dataset), final_eval, time.monotonic() - started)


def _data_path(run_dir: Path, iteration: int) -> Path:
    return run_dir / "data" / f"iteration_{iteration:03d}.npz"

