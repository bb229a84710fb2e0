"""Stable-Baselines3 baselines for benchmarks/bench_learners.py: SB3's PPO (``sb3-ppo``) and
sb3-contrib's RecurrentPPO (``sb3-recurrentppo``) trained on bimgame's Gymnasium env, each run in a
directory laid out like a bimgame run's, so that the benchmark measures every variant with the same
code:

- ``episodes.csv`` — every finished training episode, with bimgame's columns (``step``,
  ``start_step``, ``return``, ``length``, ``success``, ``true_start``) and bimgame's step convention:
  ``start_step`` is the run's step count when the rollout in which the episode started began, ``step``
  the count when the rollout in which it ended began. ``success`` is the env's ``info["is_success"]``
  at the episode's last step (the task's goal reached: what bimgame counts as a terminated episode).
- ``updates.csv`` — after every rollout: ``sps`` (environment steps per second over the last 30 s,
  bimgame's :class:`~bimgame.learn.episode_monitor.Monitor`), ``seconds`` and the recent success.
- ``eval.csv`` and ``summary.json`` — the final evaluation, greedy (``deterministic=True``) and
  sampled (``deterministic=False``), over bimgame's evaluation start positions of the run's seed
  (:func:`~bimgame.learn.evaluations.evaluation_seed`), in bimgame's keys (``greedy_success_rate``, …).
- ``config.json`` (the algorithm, policy, every hyperparameter, package versions) and ``model.zip``.

The environments: ``make_vec_env`` of the registered id ``BiMGame/<task>-v0`` (Gymnasium's
``TimeLimit`` at the run's time limit, SB3's ``Monitor``) in a ``DummyVecEnv`` — 16 single envs
stepped one after the other in this process, as bimgame's PPO steps its batch in one process. The
network runs on the CPU with 1 torch thread.

Hyperparameters: SB3's defaults except ``n_steps``. SB3's PPO default (2048 steps per env) was
chosen for one env; with 16 it makes a rollout of 32,768 steps, 9 updates in a 300k-step budget.
The benchmark uses 128 steps per env (:data:`N_STEPS`): 2,048 steps per rollout, SB3's default
rollout size for one env, the same rollouts as bimgame's PPO (16 × 128) and RecurrentPPO's own
default. Everything else (lr 3e-4, batch 64 / 128, 10 epochs, no entropy bonus, …) is SB3's.

A run that is only timed (``sps_only``) trains a short budget, skips the evaluation and says so in
its summary (``"sps_only": true``): its steps/s is measured, its learning is not.
"""

from __future__ import annotations

import dataclasses
import importlib
import io
import time
from pathlib import Path
from typing import Any

import numpy as np
import stable_baselines3
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import DummyVecEnv

from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.learn.actor import EvalResult
from bimgame.learn.episode_monitor import Monitor
from bimgame.learn.evaluations import EVAL_COLUMNS, evaluation_seed
from bimgame.learn.metric_logs import MetricLog
from bimgame.learn.runs import torch_threads
from bimgame.util.files import atomic_write_bytes, exclusive_lock, read_json, write_json

__all__ = ["VARIANTS", "N_STEPS", "SB3Run", "train_sb3", "evaluate_sb3"]

#: Each variant's package, algorithm class and policy per observation mode.
VARIANTS: dict[str, dict[str, Any]] = {
    "sb3-ppo": {
        "module": "stable_baselines3",
        "algorithm": "PPO",
        "policy": {"state": "MlpPolicy", "pixels": "CnnPolicy"},
    },
    "sb3-recurrentppo": {
        "module": "sb3_contrib",
        "algorithm": "RecurrentPPO",
        "policy": {"state": "MlpLstmPolicy", "pixels": "CnnLstmPolicy"},
    },
}
#: Steps per environment per rollout (see the module notes: SB3's PPO default is for one env).
N_STEPS = 128
#: The run's CSV logs and their columns (``step`` first, as bimgame's :class:`MetricLog` writes them).
TABLES = {
    "episodes": ["start_step", "return", "length", "success", "true_start"],
    "updates": ["seconds", "sps", "recent_success", "recent_return", "recent_length"],
    "eval": list(EVAL_COLUMNS),
}


@dataclasses.dataclass(frozen=True)
class SB3Run:
    """One SB3 run of the benchmark: what it trains on and for how long."""

    variant: str
    """A key of :data:`VARIANTS`."""
    task: str
    obs: str
    """``state`` or ``pixels``."""
    steps: int
    """The step budget (SB3 stops at the first whole rollout at or past it, as bimgame's learners do)."""
    seed: int
    time_limit: int
    """Steps per episode before Gymnasium's ``TimeLimit`` truncates it."""
    envs: int = 16
    n_steps: int = N_STEPS
    eval_episodes: int = 50
    sps_only: bool = False
    """Only time the run: no evaluation, and reported as steps/s only."""

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise ValueError(f"unknown SB3 variant {self.variant!r}; allowed: {', '.join(VARIANTS)}")
        if self.obs not in ("state", "pixels"):
            raise ValueError(f"unknown obs {self.obs!r}; allowed: state, pixels")
        for name in ("steps", "time_limit", "envs", "n_steps", "eval_episodes"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"SB3Run.{name} must be an integer >= 1, got {value!r}")


def _algorithm(variant: str) -> type[BaseAlgorithm]:
    """The SB3 algorithm class of ``variant`` (sb3-contrib imported only when asked for)."""
    spec = VARIANTS[variant]
    return getattr(importlib.import_module(spec["module"]), spec["algorithm"])


def train_sb3(run: SB3Run, run_dir: Path) -> dict[str, Any]:
    """Train ``run`` into ``run_dir`` and return its summary; a finished run with the same budget
    there is kept as it is (its summary returned), anything else in the directory is started over."""
    run_dir.mkdir(parents=True, exist_ok=True)
    with exclusive_lock(run_dir / ".lock", f"{run_dir} is being trained by another process"):
        summary = read_json(run_dir / "summary.json")
        if summary and summary.get("stopped") == "finished" and summary.get("budget") == run.steps:
            return summary
        (run_dir / "summary.json").unlink(missing_ok=True)
        with torch_threads(1):
            return _train(run, run_dir)


def _train(run: SB3Run, run_dir: Path) -> dict[str, Any]:
    algorithm = _algorithm(run.variant)
    env = make_vec_env(
        f"BiMGame/{run.task}-v0",
        n_envs=run.envs,
        seed=run.seed,
        env_kwargs={"obs_mode": run.obs, "max_episode_steps": run.time_limit},
        vec_env_cls=DummyVecEnv,
    )
    policy = VARIANTS[run.variant]["policy"][run.obs]
    model = algorithm(policy, env, n_steps=run.n_steps, seed=run.seed, device="cpu", verbose=0)
    write_json(run_dir / "config.json", _config(run, model, policy))
    log = MetricLog(run_dir, TABLES, tensorboard=False)
    started = time.monotonic()
    try:
        recorder = _Recorder(log, Monitor(0), run.envs, started)
        model.learn(total_timesteps=run.steps, callback=recorder)
        final_eval = None
        if not run.sps_only:
            seed = evaluation_seed(run.seed)
            final_eval = {
                "step": model.num_timesteps,
                **evaluate_sb3(model, run, episodes=run.eval_episodes, seed=seed),
            }
            log.write("eval", model.num_timesteps, final_eval)
    finally:
        log.close()
        env.close()
    buffer = io.BytesIO()
    model.save(buffer)
    atomic_write_bytes(run_dir / "model.zip", buffer.getvalue())
    summary = {
        "learner": run.variant,
        "steps": model.num_timesteps,
        "budget": run.steps,
        "sps_only": run.sps_only,
        "stopped": "finished",
        "seconds": time.monotonic() - started,
        "final_eval": final_eval,
        **recorder.monitor.recent(),
    }
    write_json(run_dir / "summary.json", summary)
    return summary


def _config(run: SB3Run, model: BaseAlgorithm, policy: str) -> dict[str, Any]:
    """The run's config.json: the benchmark's settings and the algorithm's hyperparameters as used."""
    names = (
        "learning_rate",
        "n_steps",
        "batch_size",
        "n_epochs",
        "gamma",
        "gae_lambda",
        "ent_coef",
        "vf_coef",
        "max_grad_norm",
        "normalize_advantage",
        "target_kl",
    )
    hyper = {name: getattr(model, name) for name in names if hasattr(model, name)}
    hyper["clip_range"] = model.clip_range(1.0) if callable(getattr(model, "clip_range", None)) else None
    versions = {"stable_baselines3": stable_baselines3.__version__, "torch": torch.__version__}
    if VARIANTS[run.variant]["module"] == "sb3_contrib":
        versions["sb3_contrib"] = importlib.import_module("sb3_contrib").__version__
    return {
        "kind": run.variant,
        "task": run.task,
        "seed": run.seed,
        "max_episode_steps": run.time_limit,
        "sb3": {
            **dataclasses.asdict(run),
            "algorithm": VARIANTS[run.variant]["algorithm"],
            "policy": policy,
            "hyperparameters": {k: v for k, v in hyper.items() if isinstance(v, (int, float, bool, type(None)))},
            "torch_threads": torch.get_num_threads(),
            "versions": versions,
        },
    }


class _Recorder(BaseCallback):
    """Writes every finished training episode to ``episodes`` and, after every rollout, the run's
    throughput to ``updates``, in bimgame's columns and step convention (see the module notes)."""

    def __init__(self, log: MetricLog, monitor: Monitor, envs: int, started: float):
        super().__init__()
        self.log, self.monitor, self.started = log, monitor, started
        self.rollout_start = 0
        self.episode_start = np.zeros(envs, dtype=np.int64)
        self.returns = np.zeros(envs)
        self.lengths = np.zeros(envs, dtype=np.int64)

    def _on_rollout_start(self) -> None:
        self.rollout_start = self.num_timesteps

    def _on_step(self) -> bool:
        dones, infos = self.locals["dones"], self.locals["infos"]
        self.returns += np.asarray(self.locals["rewards"], dtype=np.float64)
        self.lengths += 1
        for i in np.flatnonzero(dones):
            row = {
                "start_step": int(self.episode_start[i]),
                "return": float(self.returns[i]),
                "length": int(self.lengths[i]),
                "success": bool(infos[i].get("is_success", False)),
                "true_start": True,
            }
            self.monitor.episode(row)
            self.log.write("episodes", self.rollout_start, row)
        self.episode_start[dones] = self.rollout_start
        self.returns[dones] = 0.0
        self.lengths[dones] = 0
        return True

    def _on_rollout_end(self) -> None:
        step = self.num_timesteps
        row = {"sps": self.monitor.sps(step), "seconds": time.monotonic() - self.started, **self.monitor.recent()}
        self.log.write("updates", step, row)


def evaluate_sb3(model: BaseAlgorithm, run: SB3Run, *, episodes: int, seed: int) -> dict[str, float]:
    """Success rate, mean length and return of ``model`` acting greedily (``deterministic=True``) and
    sampling, one episode in each of ``episodes`` environments of bimgame's batched env reset with
    ``seed`` — the start positions bimgame's evaluation of a run with the same seed uses — with the
    sampling seeded by ``seed`` too. Keys as bimgame's (``greedy_success_rate``, …)."""
    values: dict[str, float] = {}
    for mode, deterministic in (("greedy", True), ("sampled", False)):
        set_random_seed(seed)
        env = BallInMazeVectorEnv(
            episodes,
            task=run.task,
            obs_mode=run.obs,
            max_episode_steps=run.time_limit,
            nthread=1,
            autoreset_mode="same_step",
        )
        try:
            result = _episodes(model, env, episodes, seed, deterministic)
        finally:
            env.close()
        values.update({f"{mode}_{k}": v for k, v in result.summary().items() if k != "episodes"})
    return values


def _episodes(model: BaseAlgorithm, env: BallInMazeVectorEnv, episodes: int, seed: int, deterministic: bool):
    """The first episode of each of ``env``'s environments under ``model`` (an LSTM policy's state
    carried along, reset where an episode starts)."""
    obs, _ = env.reset(seed=seed)
    state, starts = None, np.ones(episodes, dtype=bool)
    finished = np.zeros(episodes, dtype=bool)
    result = EvalResult([False] * episodes, [0] * episodes, [0.0] * episodes)
    returns, lengths = np.zeros(episodes), np.zeros(episodes, dtype=np.int64)
    while not finished.all():
        actions, state = model.predict(obs, state=state, episode_start=starts, deterministic=deterministic)
        obs, reward, terminated, truncated, _ = env.step(actions)
        returns += reward
        lengths += 1
        done = terminated | truncated
        for i in np.flatnonzero(done & ~finished):
            result.successes[i] = bool(terminated[i])
            result.lengths[i] = int(lengths[i])
            result.returns[i] = float(returns[i])
        finished |= done
        returns[done], lengths[done] = 0.0, 0
        starts = done
    return result
