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
"""

from __future__ import annotations

import dataclasses
import json
import math
import multiprocessing as std_mp
import os
import queue as queue_module
import signal
import time
import traceback
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
import torch.multiprocessing as mp

from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.learn.actor import RecurrentActor, tilt_input
from bimgame.learn.common import (NetworkSettings, check_seed, evaluate_greedy_and_sampled, evaluation_seed,
                                  init_network_settings)
from bimgame.learn.curves import plot_run
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.runs import (CHECKPOINT, CONFIG, KIND_A3C, SUMMARY, CheckpointError, MetricLog, RunWriteError,
                                check_resumable, discard_new_run, load_checkpoint, load_weights, prepare_new_run,
                                read_run_settings, save_checkpoint, torch_threads, write_run_json)
from bimgame.sim.maze import MazeSpec
from bimgame.sim.tasks import MAX_EPISODE_STEPS, Task, parse_task
from bimgame.util.files import read_json
from bimgame.util.progress import ProgressBar
from bimgame.util.settings import from_dict, require_int
from bimgame.util.signals import sigterm_as_interrupt

__all__ = ["A3CConfig", "TrainingError", "TrainResult", "train", "network_for", "make_optimizer", "evaluate",
           "OPTIMIZERS", "MAX_STEPS", "EnvWrapper", "resolve_config", "a3c_segment_loss", "apply_update",
           "shared_optimizer_state"]

OPTIMIZERS = ("rmsprop", "adam")
#: The most environment steps a run (or a checkpoint or evaluation interval) may count: 10¹², about
#: 30 years at this machine's 1,000 steps/s. More is a typo (``--steps 1e30``), found before any work.
MAX_STEPS = 10**12
#: The largest value of the settings that size what is allocated at once (processes, environments,
#: segment memory, evaluation episodes run side by side), far above any sensible value: larger is a
#: typo that would otherwise fail only when memory runs out.
_LARGEST = {**{name: (MAX_STEPS, "1e12 environment steps") for name in
               ("steps", "checkpoint_every", "eval_every", "log_every", "max_episode_steps")},
            "workers": (256, "processes"), "envs_per_worker": (4096, "environments in one process"),
            "n_steps": (10_000, "steps kept in memory per update"),
            "eval_episodes": (10_000, "episodes run side by side")}
#: A callable that wraps a worker's vector env (e.g. reward shaping). It is sent to spawned worker
#: processes, so it must be picklable (a module-level function or an instance of a module-level class).
EnvWrapper = Callable[[BallInMazeVectorEnv], Any]


class TrainingError(RuntimeError):
    """Training stopped because something went wrong (a non-finite loss, a crashed worker)."""


@dataclasses.dataclass(frozen=True)
class A3CConfig(NetworkSettings):
    """Settings of an A3C run. Learning defaults follow the A3C paper and its widely used reference
    implementations (OpenAI Baselines' A2C settings for the loss, RMSProp with shared statistics).
    The network settings (``obs``, ``hidden``, ``features``, …) are inherited from
    :class:`~bimgame.learn.common.NetworkSettings`."""

    task: str = "STG1"
    """FULL, STG1 … STG4."""
    steps: int = 5_000_000
    """Environment steps to train for (all workers together)."""
    workers: int = 2
    """Worker processes (one thread each)."""
    envs_per_worker: int = 16
    """Environments per worker, stepped as one batch (one forward pass acts for all); 1 is exactly
    the paper's A3C. Batching is what makes the network affordable on a CPU: one LSTM step costs
    about the same for 1 environment as for 16."""
    n_steps: int = 20
    """t_max: steps per update (n-step returns)."""
    gamma: float = 0.99
    """Discount."""
    gae_lambda: float = 1.0
    """1.0 gives A3C's n-step returns; below 1, generalised advantage estimation."""
    lr: float = 7e-4
    """Learning rate of the shared optimiser."""
    optimizer: str = "rmsprop"
    """``rmsprop`` (A3C's, statistics shared by all workers) or ``adam`` (also shared)."""
    rmsprop_alpha: float = 0.99
    """RMSProp's smoothing constant."""
    optimizer_eps: float = 1e-5
    """The optimiser's epsilon (numerical stability)."""
    entropy_coef: float = 0.01
    """Weight of the entropy bonus in the loss."""
    value_coef: float = 0.5
    """Weight of the value loss against the policy loss."""
    max_grad_norm: float = 0.5
    """Clip each update's gradient to this global norm (losses are means over the segment)."""
    seed: int = 0
    """Seeds the network's initial weights, the workers' environments and sampling, and the evaluations."""
    max_episode_steps: int | None = None
    """Time limit; None uses the task's (STG1 300, STG2 500, STG3 750, STG4/FULL 1000)."""
    checkpoint_every: int = 100_000
    """Environment steps between checkpoints (``--resume`` loses at most this many)."""
    eval_every: int = 100_000
    """Environment steps between evaluations; 0 disables the evaluator process."""
    eval_episodes: int = 10
    """Episodes per evaluation, each greedy and sampled."""
    log_every: int = 2_000
    """Environment steps (per worker) between loss reports."""

    def __post_init__(self) -> None:
        super().__post_init__()
        try:
            object.__setattr__(self, "task", parse_task(self.task).value)
        except ValueError as error:
            raise ValueError(f"A3CConfig.task: {error}") from None
        if self.optimizer not in OPTIMIZERS:
            raise ValueError(f"A3CConfig.optimizer must be one of {OPTIMIZERS}, got {self.optimizer!r}")
        positive_ints = ("steps", "workers", "envs_per_worker", "n_steps", "checkpoint_every", "eval_episodes",
                         "log_every")
        for name in positive_ints:
            require_int("A3CConfig", name, getattr(self, name), 1)
        check_seed("A3CConfig", self.seed)  # numpy's seed sequences take no negative seeds, torch none of 2**64
        if not (isinstance(self.eval_every, int) and self.eval_every >= 0):
            raise ValueError(f"A3CConfig.eval_every must be an integer >= 0 (0: no evaluator), got {self.eval_every!r}")
        require_int("A3CConfig", "max_episode_steps", self.max_episode_steps, 1, optional=True)
        for name, (largest, unit) in _LARGEST.items():
            value = getattr(self, name)
            if value is not None and value > largest:
                raise ValueError(f"A3CConfig.{name} must be at most {largest:,} ({unit}), got {value!r}")
        ranges = {"gamma": (0.0, 1.0), "gae_lambda": (0.0, 1.0), "rmsprop_alpha": (0.0, 1.0)}
        for name, (low, high) in ranges.items():
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and low <= value <= high):
                raise ValueError(f"A3CConfig.{name} must be in [{low}, {high}], got {value!r}")
        for name in ("lr", "optimizer_eps", "max_grad_norm"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"A3CConfig.{name} must be a finite number > 0, got {value!r}")
        for name in ("entropy_coef", "value_coef"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"A3CConfig.{name} must be a finite number >= 0, got {value!r}")

    @property
    def time_limit(self) -> int:
        return self.max_episode_steps or MAX_EPISODE_STEPS[Task(self.task)]

    @property
    def steps_per_update(self) -> int:
        return self.n_steps * self.envs_per_worker

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> A3CConfig:
        return from_dict(cls, values, "A3C settings")

    # What a resumed run may change without changing what is being learned.
    RESUMABLE_CHANGES = ("steps", "workers", "checkpoint_every", "eval_every", "eval_episodes", "log_every")


def network_for(config: A3CConfig, maze: MazeSpec | None = None) -> RecurrentActorCritic:
    """A fresh network for ``config``'s run, initialised from its seed."""
    return config.build_policy(config.seed, maze)


def make_optimizer(config: A3CConfig, params) -> torch.optim.Optimizer:
    if config.optimizer == "rmsprop":
        return torch.optim.RMSprop(params, lr=config.lr, alpha=config.rmsprop_alpha, eps=config.optimizer_eps)
    return torch.optim.Adam(params, lr=config.lr, eps=config.optimizer_eps)


def shared_optimizer_state(optimizer: torch.optim.Optimizer) -> list[dict[str, torch.Tensor]]:
    """Create every parameter's optimiser statistics (if not loaded) and move them to shared memory,
    so all workers update the same statistics (A3C's 'shared RMSProp')."""
    params = [p for group in optimizer.param_groups for p in group["params"]]
    if not optimizer.state:
        # One step with zero gradients creates the statistics without changing any weight (RMSProp
        # and Adam both move by 0 for a zero gradient); then the step counts are reset to 0.
        for p in params:
            p.grad = torch.zeros_like(p)
        optimizer.step()
        for p in params:
            p.grad = None
            optimizer.state[p]["step"].zero_()
    states = []
    for p in params:
        state = optimizer.state[p]
        for value in state.values():
            if torch.is_tensor(value):
                value.share_memory_()
        states.append(state)
    return states


def a3c_segment_loss(net: RecurrentActorCritic, segment: dict[str, torch.Tensor], config: A3CConfig,
                     ) -> tuple[torch.Tensor, dict[str, float]]:
    """The actor-critic loss of one segment (T steps × B envs), recomputed with gradients.

    ``segment`` holds ``obs``, ``prev_action``, ``prev_reward``, ``tilt`` and ``starts`` for T+1
    steps (the last is the bootstrap state), ``actions``, ``rewards`` (with γ·V(final observation)
    already added at time-limit truncations) and ``ends`` (the episode ended after this step) for T
    steps, and the LSTM state ``h0``/``c0`` at the segment start."""
    logits, values, _ = net.unroll(segment["obs"], segment["prev_action"], segment["prev_reward"],
                                   segment.get("tilt"), (segment["h0"], segment["c0"]), segment["starts"])
    logits, bootstrap, values = logits[:-1], values[-1].detach(), values[:-1]
    rewards, ends = segment["rewards"], segment["ends"].float()
    advantages = torch.zeros_like(rewards)
    next_value, running = bootstrap, torch.zeros_like(bootstrap)
    detached = values.detach()
    for t in reversed(range(rewards.shape[0])):
        not_end = 1.0 - ends[t]
        delta = rewards[t] + config.gamma * next_value * not_end - detached[t]
        running = delta + config.gamma * config.gae_lambda * not_end * running
        advantages[t] = running
        next_value = detached[t]
    targets = advantages + detached
    log_probs = torch.log_softmax(logits, dim=-1)
    chosen = log_probs.gather(-1, segment["actions"].unsqueeze(-1)).squeeze(-1)
    entropy = -(log_probs.exp() * log_probs).sum(-1).mean()
    policy_loss = -(chosen * advantages).mean()
    value_loss = 0.5 * (targets - values).pow(2).mean()
    loss = policy_loss + config.value_coef * value_loss - config.entropy_coef * entropy
    return loss, {"policy_loss": policy_loss.item(), "value_loss": value_loss.item(), "entropy": entropy.item()}


def apply_update(local: RecurrentActorCritic, shared_params: list[torch.Tensor], optimizer: torch.optim.Optimizer,
                 segment: dict[str, torch.Tensor], config: A3CConfig) -> dict[str, float]:
    """One A3C update: the segment's loss, its gradient (norm clipped) on the local network, applied
    to the shared weights by the shared optimiser. A non-finite loss or gradient is not applied
    (``applied`` is False in the returned losses)."""
    loss, parts = a3c_segment_loss(local, segment, config)
    local.zero_grad(set_to_none=True)
    loss.backward()
    grad_norm = float(torch.nn.utils.clip_grad_norm_(local.parameters(), config.max_grad_norm))
    applied = math.isfinite(loss.item()) and math.isfinite(grad_norm)
    if applied:
        for shared_param, param in zip(shared_params, local.parameters()):
            shared_param.grad = param.grad
        optimizer.step()
    return {**parts, "loss": loss.item(), "grad_norm": grad_norm, "applied": applied}


@dataclasses.dataclass
class TrainResult:
    run_dir: Path
    steps: int
    stopped: str
    """``finished`` (budget spent) or ``interrupted`` (Ctrl-C)."""
    final_eval: dict[str, Any] | None
    seconds: float


# ---------------------------------------------------------------------- processes
def _worker_seeds(config: A3CConfig, rank: int, start_step: int) -> tuple[int, int]:
    """(env seed, torch seed) of a worker; a resumed run (start_step > 0) draws fresh episodes."""
    sequence = np.random.SeedSequence([config.seed, rank, start_step])
    env_seed, torch_seed = sequence.generate_state(2)
    return int(env_seed), int(torch_seed)


def _make_env(config: A3CConfig, num_envs: int, **kwargs: Any) -> BallInMazeVectorEnv:
    return BallInMazeVectorEnv(num_envs, task=config.task, obs_mode=config.obs, nthread=1,
                               max_episode_steps=config.time_limit, autoreset_mode="same_step", **kwargs)


def _parent_alive() -> bool:
    parent = std_mp.parent_process()
    return parent is None or parent.is_alive()


def _worker(rank: int, config: A3CConfig, shared: RecurrentActorCritic, optimizer_state: list[dict],
            counter, stop, messages, env_wrapper: EnvWrapper | None, start_step: int) -> None:
    """One A3C worker process: act, compute the segment's gradient, apply it to the shared weights."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops us
    torch.set_num_threads(1)
    try:
        _worker_loop(rank, config, shared, optimizer_state, counter, stop, messages, env_wrapper, start_step)
    except Exception:
        messages.put(("error", rank, traceback.format_exc()))
    finally:
        messages.put(("exit", rank, None))


def _worker_loop(rank, config, shared, optimizer_state, counter, stop, messages, env_wrapper, start_step):
    env_seed, torch_seed = _worker_seeds(config, rank, start_step)
    base_env = _make_env(config, config.envs_per_worker)
    env = env_wrapper(base_env) if env_wrapper is not None else base_env
    max_tilt = base_env.maze.max_tilt
    local = network_for(config, base_env.maze)
    optimizer = make_optimizer(config, shared.parameters())
    shared_params = list(shared.parameters())
    for param, state in zip(shared_params, optimizer_state):
        optimizer.state[param] = state
    generator = torch.Generator().manual_seed(torch_seed)
    actor = RecurrentActor(local, config.envs_per_worker, generator=generator)
    obs, info = env.reset(seed=env_seed)
    tilt = tilt_input(info, max_tilt)
    n, batch = config.n_steps, config.envs_per_worker
    episode_return = np.zeros(batch)
    episode_length = np.zeros(batch, dtype=np.int64)
    episode_start = np.full(batch, counter.value, dtype=np.int64)
    stats = {"policy_loss": 0.0, "value_loss": 0.0, "entropy": 0.0, "grad_norm": 0.0, "updates": 0}
    since_report = 0
    while not stop.is_set() and counter.value < config.steps and _parent_alive():
        local.load_state_dict(shared.state_dict())
        h0, c0 = actor.state
        seg: dict[str, list] = {k: [] for k in ("obs", "prev_action", "prev_reward", "tilt", "starts",
                                                "actions", "rewards", "ends")}
        step_at_start = counter.value
        for _ in range(n):
            seg["obs"].append(torch.as_tensor(obs))
            seg["prev_action"].append(actor.prev_action)
            seg["prev_reward"].append(actor.prev_reward)
            seg["tilt"].append(tilt)
            seg["starts"].append(actor.starts)
            actions, _, _ = actor.act(obs, tilt)
            obs, reward, terminated, truncated, info = env.step(actions.numpy())
            reward = np.asarray(reward, dtype=np.float64)
            if not np.all(np.isfinite(reward)):
                messages.put(("nan", rank, {"step": int(counter.value), "what": "reward from the env",
                                            "rewards": reward.tolist()}))
                return
            done = terminated | truncated
            rewards_t = torch.as_tensor(reward, dtype=torch.float32)
            cut = truncated & ~terminated
            if cut.any():
                # A time limit is not a terminal state: bootstrap from the value of the last
                # observation, which SAME_STEP autoreset keeps in info["final_obs"].
                rewards_t = rewards_t + config.gamma * _final_values(actor, actions, reward, info, cut, max_tilt)
            seg["actions"].append(actions)
            seg["rewards"].append(rewards_t)
            seg["ends"].append(torch.as_tensor(done))
            # Learning curves show the task's own reward, also when a wrapper shapes it.
            episode_return += np.asarray(info.get("task_reward", reward), dtype=np.float64)
            episode_length += 1
            for i in np.flatnonzero(done):
                messages.put(("episode", rank, {
                    "start_step": int(episode_start[i]), "end_step": int(counter.value),
                    "return": float(episode_return[i]), "length": int(episode_length[i]),
                    "success": bool(terminated[i])}))
            episode_return[done] = 0.0
            episode_length[done] = 0
            episode_start[done] = step_at_start
            actor.observe(actions, reward, done)
            tilt = tilt_input(info, max_tilt)
        seg["obs"].append(torch.as_tensor(obs))
        seg["prev_action"].append(actor.prev_action)
        seg["prev_reward"].append(actor.prev_reward)
        seg["tilt"].append(tilt)
        seg["starts"].append(actor.starts)
        segment = {k: torch.stack(v) for k, v in seg.items()}
        segment.update(h0=h0, c0=c0)
        if not config.tilt_input:
            segment.pop("tilt")
        parts = apply_update(local, shared_params, optimizer, segment, config)
        grad_norm = parts.pop("grad_norm")
        if not parts.pop("applied"):
            messages.put(("nan", rank, {"step": int(counter.value), "what": "loss", "grad_norm": grad_norm,
                                        **parts}))
            return
        with counter.get_lock():
            counter.value += n * batch
        for key in ("policy_loss", "value_loss", "entropy"):
            stats[key] += parts[key]
        stats["grad_norm"] += grad_norm
        stats["updates"] += 1
        since_report += n * batch
        if since_report >= config.log_every:
            count = stats.pop("updates")
            messages.put(("update", rank, {"step": int(counter.value), **{k: v / count for k, v in stats.items()}}))
            stats = {k: 0.0 for k in stats} | {"updates": 0}
            since_report = 0


def _final_values(actor: RecurrentActor, actions: torch.Tensor, reward: np.ndarray, info: dict,
                  cut: np.ndarray, max_tilt: float) -> torch.Tensor:
    """V of the last observation of time-limited episodes (0 elsewhere), from the state after the
    step, without changing the actor."""
    final_obs = info["final_obs"]
    final_tilt = tilt_input(info["final_info"], max_tilt)
    with torch.no_grad():
        _, values, _ = actor.net.step(torch.as_tensor(final_obs), actions,
                                      torch.as_tensor(reward, dtype=torch.float32), final_tilt, actor.state)
    return values * torch.as_tensor(cut, dtype=torch.float32)


def _evaluator(config: A3CConfig, shared: RecurrentActorCritic, counter, stop, messages, start_step: int,
               initial_weights: dict[str, torch.Tensor]) -> None:
    """Evaluator process: greedy and sampled episodes (same start positions every time) of the weights
    the session starts from, at its first step — step 0 of a fresh run (the initial random or
    pre-trained policy), the checkpoint's step of a resumed one, whose earlier rows from that step on
    were dropped — then every ``eval_every`` steps of the shared weights."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    torch.set_num_threads(1)
    try:
        local = network_for(config)
        # A copy of the weights taken before any worker started.
        local.load_state_dict(initial_weights)
        messages.put(("eval", -1, {"step": start_step, **evaluate(local, config)}))
        next_eval = (start_step // config.eval_every + 1) * config.eval_every
        while not stop.is_set() and _parent_alive():
            step = counter.value
            if step >= config.steps:
                break
            if step < next_eval:
                time.sleep(0.1)
                continue
            local.load_state_dict(shared.state_dict())
            messages.put(("eval", -1, {"step": int(step), **evaluate(local, config)}))
            next_eval = (step // config.eval_every + 1) * config.eval_every
    except Exception:
        messages.put(("error", -1, traceback.format_exc()))
    finally:
        messages.put(("exit", -1, None))


def evaluate(net: RecurrentActorCritic, config: A3CConfig) -> dict[str, float]:
    """The run's periodic evaluation: greedy and sampled, on its evaluation episodes and seed."""
    return evaluate_greedy_and_sampled(net, task=config.task, obs=config.obs, episodes=config.eval_episodes,
                                       seed=evaluation_seed(config.seed), time_limit=config.time_limit)


# ---------------------------------------------------------------------- the parent process
_TABLES = {
    "episodes": ["start_step", "worker", "return", "length", "success"],
    "updates": ["seconds", "sps", "policy_loss", "value_loss", "entropy", "grad_norm", "recent_success", "recent_return",
                "recent_length"],
    "eval": ["greedy_success_rate", "greedy_mean_length", "greedy_mean_return", "sampled_success_rate",
             "sampled_mean_length", "sampled_mean_return"],
}


#: Every file and folder a run writes in its directory (removed again if a new run fails at once).
_RUN_FILES = (CONFIG, CHECKPOINT, SUMMARY, "curves.png", "tb", *(f"{name}.csv" for name in _TABLES))


def resolve_config(given: dict[str, Any], run_dir: str | Path, *, resume: bool = False,
                   init: str | Path | None = None) -> A3CConfig:
    """A run's settings from the ones a user gave (``given``: field → value, only those given): the
    defaults, or with ``resume`` the run's stored settings, overridden by ``given``; with ``init``, the
    network settings of the run it points at unless given (a pre-trained π^s fixes the network's
    shape). The command line and the reproduction both build their A3C settings here."""
    if resume:
        check_resumable(run_dir, kind=KIND_A3C, what="A3C")
        return read_run_settings(run_dir, "a3c", lambda stored: A3CConfig.from_dict({**stored, **given}))
    if init is not None:
        given = {**init_network_settings(init), **given}
    return A3CConfig.from_dict(given)


def _check_resume(run_dir: Path, config: A3CConfig) -> None:
    check_resumable(run_dir, kind=KIND_A3C, what="A3C", needs=(CHECKPOINT,))
    previous = read_run_settings(run_dir, "a3c", A3CConfig.from_dict)
    changed = [f.name for f in dataclasses.fields(A3CConfig)
               if getattr(previous, f.name) != getattr(config, f.name) and f.name not in A3CConfig.RESUMABLE_CHANGES]
    if changed:
        raise ValueError("--resume must keep the run's settings; changed: "
                         + ", ".join(f"{k} ({getattr(previous, k)!r} -> {getattr(config, k)!r})" for k in changed)
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
    it) only does that evaluation and writes the summary.

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
    optimiser statistics; ``fresh`` for a new run (``created``: its directory did not exist)."""

    step: int = 0
    seconds: float = 0.0
    optimizer: dict | None = None
    fresh: bool = True
    created: bool = False
    checkpoint_step: int = 0
    """Step of the newest checkpoint written (0 until the first one after the start)."""


def _train(config: A3CConfig, run_dir: Path, *, resume: bool, init: str | Path | None,
           env_wrapper: EnvWrapper | None, progress: bool, extra_config: dict | None) -> TrainResult:
    shared = network_for(config)
    if resume:
        _check_resume(run_dir, config)
        payload = load_checkpoint(run_dir / CHECKPOINT)
        load_weights(shared, run_dir / CHECKPOINT)
        start = _Start(step=payload["step"], seconds=float(payload.get("seconds", 0.0)),
                       optimizer=payload.get("optimizer"), fresh=False, checkpoint_step=payload["step"])
        if start.step >= config.steps and _summarised(run_dir, start.step):
            raise ValueError(f"the run in {run_dir} already has {start.step} steps >= steps={config.steps}; "
                             f"pass a larger --steps to continue")
    else:
        start = _Start(created=prepare_new_run(run_dir, what="A3C", flag="--run-dir", kind=KIND_A3C))
        if init is not None:
            try:
                load_weights(shared, init)
            except CheckpointError as error:
                raise CheckpointError(f"--init: {error}") from None
    try:
        if start.fresh:
            write_run_json(run_dir / CONFIG, {"a3c": config.to_dict(), "net": shared.config.to_dict(),
                                              "init": str(init) if init is not None else None, **(extra_config or {})})
            save_checkpoint(run_dir / CHECKPOINT, model=shared.state_dict(), step=0, seconds=0.0,
                            config=json.dumps(config.to_dict()))
        return _session(config, run_dir, shared, start, env_wrapper=env_wrapper, progress=progress)
    except Exception:
        if start.fresh and start.checkpoint_step == 0:
            discard_new_run(run_dir, start.created, _RUN_FILES)  # nothing trained: a rerun starts afresh
        raise


def _session(config: A3CConfig, run_dir: Path, shared: RecurrentActorCritic, start: _Start, *,
             env_wrapper: EnvWrapper | None, progress: bool) -> TrainResult:
    """Train from ``start`` to ``config.steps`` (nothing if the steps are all done), then evaluate
    and write the summary."""
    log = MetricLog(run_dir, _TABLES, resume_step=None if start.fresh else start.step,
                    keep_at_resume_step=("updates",))  # an update's row is logged before its step's checkpoint
    monitor = _Monitor(config, start.step)
    monitor.restore(log.kept["episodes"])
    started = time.monotonic() - start.seconds  # seconds count the whole run, across resumes
    step, stopped = start.step, "finished"
    if step < config.steps:
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
        write_run_json(run_dir / SUMMARY, {"steps": step, "stopped": stopped, "seconds": seconds,
                                           "final_eval": final_eval, **monitor.recent()})
    except RunWriteError as error:
        log.close()
        raise TrainingError(f"{error}. The checkpoint {run_dir / CHECKPOINT} (step {step:,}) is saved: free some "
                            f"space and continue with --resume (a run whose steps are all done then only evaluates "
                            f"and writes its summary)") from error
    try:
        plot_run(run_dir, title=f"A3C on {config.task} ({config.obs})")
    except (ValueError, OSError):
        pass  # no finished episode yet (nothing to plot), or no room for the figure: the logs hold it all
    return TrainResult(run_dir, step, stopped, final_eval, seconds)


def _run_processes(config: A3CConfig, run_dir: Path, shared: RecurrentActorCritic, start: _Start, log: MetricLog,
                   monitor: _Monitor, started: float, *, env_wrapper: EnvWrapper | None, progress: bool,
                   ) -> tuple[int, str]:
    """The workers and the evaluator, until the steps are done, Ctrl-C, or a failure; writes the
    checkpoints. Returns (step, "finished" or "interrupted"); raises :class:`TrainingError`."""
    shared.share_memory()
    optimizer = make_optimizer(config, shared.parameters())
    if start.optimizer is not None:
        optimizer.load_state_dict(start.optimizer)
    optimizer_state = shared_optimizer_state(optimizer)

    initial_weights = {k: v.detach().clone() for k, v in shared.state_dict().items()}
    context = mp.get_context("spawn")
    counter = context.Value("q", start.step)
    stop = context.Event()
    messages = context.Queue()
    processes = [context.Process(target=_worker, name=f"a3c-worker-{rank}",
                                 args=(rank, config, shared, optimizer_state, counter, stop, messages,
                                       env_wrapper, start.step), daemon=True)
                 for rank in range(config.workers)]
    if config.eval_every > 0:
        processes.append(context.Process(target=_evaluator, name="a3c-evaluator",
                                         args=(config, shared, counter, stop, messages, start.step,
                                               initial_weights), daemon=True))
    stopped = "finished"
    failure: str | None = None
    write_failure: RunWriteError | None = None

    def checkpoint() -> None:
        step = int(counter.value)
        save_checkpoint(run_dir / CHECKPOINT, model=shared.state_dict(), optimizer=optimizer.state_dict(),
                        step=step, seconds=time.monotonic() - started, config=json.dumps(config.to_dict()))
        start.checkpoint_step = step

    shown_at = 0.0
    try:
        with sigterm_as_interrupt(), ProgressBar(f"A3C {config.task} {config.obs}", config.steps,
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
                              scalars=("sps", "policy_loss", "value_loss", "entropy", "grad_norm", "recent_success"))
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
                if failure is None and step - start.checkpoint_step >= config.checkpoint_every:
                    checkpoint()
    except KeyboardInterrupt:
        stopped = "interrupted"
    except RunWriteError as error:
        write_failure = error
    finally:
        stop.set()
        for process in processes:
            if process.pid is None:
                continue  # never started (e.g. its arguments could not be sent to it)
            process.join(timeout=30)
            if process.is_alive():
                process.terminate()
                process.join()
    step = int(counter.value)
    saved = False
    try:
        if failure is None and write_failure is None:
            checkpoint()
        elif write_failure is None and not (start.fresh and step == 0) and \
                all(torch.isfinite(p).all() for p in shared.parameters()):
            checkpoint()  # the weights before the failing update, for inspection or a resume
            saved = True
    except RunWriteError as error:
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


class _Monitor:
    """Recent training episodes (by the step they started at) and throughput, for the progress bar
    and the logs."""

    def __init__(self, config: A3CConfig, start_step: int, window: int = 100):
        self.window = window
        self.episodes: list[dict] = []
        self.start_step = start_step
        self.start_time = time.monotonic()
        self._marks: list[tuple[float, int]] = [(self.start_time, start_step)]

    def restore(self, rows: list[dict[str, str]]) -> None:
        """The episodes a resumed run logged before its checkpoint (rows of episodes.csv), so that the
        recent success continues where it was."""
        for row in rows[-4 * self.window:]:
            try:
                self.episode({"start_step": int(float(row["start_step"])), "return": float(row["return"]),
                              "length": int(float(row["length"])), "success": row["success"] == "True"})
            except (KeyError, ValueError):
                continue  # a row another version wrote differently: not worth refusing the resume for

    def episode(self, payload: dict) -> None:
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


def default_workers() -> int:
    return max(1, os.cpu_count() or 1)
