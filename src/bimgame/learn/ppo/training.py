"""Training a PPO run in its directory: collect a rollout of every environment with the shared
:class:`~bimgame.learn.rollout.RolloutCollector`, update (:func:`~bimgame.learn.ppo.update.ppo_update`),
log, evaluate, checkpoint — in this process, the environments stepped as one batch on one MuJoCo
thread, the network on ``torch_threads`` threads.

The run directory is the same as A3C's (config.json, checkpoint.pt, episodes/updates/eval CSV logs,
TensorBoard, summary.json, curves.png) with kind ``ppo``; ``bimgame evaluate`` and ``--init`` read it.
A resumed run continues from its checkpoint (weights, Adam's statistics, steps) with fresh episodes
(environment and sampling seeds derived from the run's seed and the step it resumes at)."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bimgame.learn.actor import RecurrentActor
from bimgame.learn.checkpoints import apply_weights, load_checkpoint, load_init_weights, save_checkpoint
from bimgame.learn.common import EVAL_COLUMNS, init_network_settings, run_evaluation
from bimgame.learn.curves import plot_run
from bimgame.learn.episode_monitor import Monitor
from bimgame.learn.metric_logs import MetricLog
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.ppo.settings import PPOConfig
from bimgame.learn.ppo.update import ppo_update
from bimgame.learn.rollout import FinishedEpisode, NonFiniteReward, RolloutCollector, training_env
from bimgame.learn.run_dir import RunDirectory, TrainingError, TrainResult, stored_run_config
from bimgame.learn.runs import CHECKPOINT, KIND_PPO, torch_threads
from bimgame.util.progress import ProgressBar
from bimgame.util.signals import sigterm_as_interrupt

__all__ = ["resolve_ppo_config", "train_ppo", "TABLES"]

#: The run's CSV logs and their columns.
TABLES = {
    "episodes": ["start_step", "return", "length", "success", "true_start"],
    "updates": [
        "seconds",
        "sps",
        "policy_loss",
        "value_loss",
        "entropy",
        "approx_kl",
        "clip_fraction",
        "grad_norm",
        "recent_success",
        "recent_return",
        "recent_length",
    ],
    "eval": list(EVAL_COLUMNS),
}
_UPDATE_SCALARS = ("sps", "policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction", "recent_success")


def resolve_ppo_config(
    given: dict[str, Any], run_dir: str | Path, *, resume: bool = False, init: str | Path | None = None
) -> PPOConfig:
    """A run's settings from the ones a user gave (flat names, only those given): the defaults, or with
    ``resume`` the run's stored settings, overridden by ``given``; with ``init``, the network settings
    of the run it points at unless given (a pre-trained π^s fixes the network's shape)."""
    if resume:
        stored = stored_run_config(run_dir, KIND_PPO).get("ppo")
        if not isinstance(stored, dict):
            raise ValueError(f"{Path(run_dir) / 'config.json'} holds no PPO settings ('ppo')")
        return PPOConfig.from_flat({**stored, **given})
    if init is not None:
        given = {**init_network_settings(init), **given}
    return PPOConfig.from_flat(given)


def train_ppo(
    config: PPOConfig,
    run_dir: str | Path,
    *,
    resume: bool = False,
    init: str | Path | None = None,
    progress: bool = True,
) -> TrainResult:
    """Train with PPO; everything is saved in ``run_dir`` (a new or empty directory, or with
    ``resume`` the PPO run in it). ``init``: a checkpoint file or run directory whose weights the
    network starts from (e.g. a pre-trained π^s; its network settings must match ``config``'s).
    Raises :class:`TrainingError` for a non-finite reward, loss or gradient (the last checkpoint
    is kept)."""
    if resume and init is not None:
        raise ValueError("--init with --resume: a resumed run continues from its own checkpoint")
    with torch_threads(), RunDirectory(run_dir, KIND_PPO, resume=resume) as run:
        net = config.network.build_policy(config.seed)
        optimizer = torch.optim.Adam(net.parameters(), lr=config.optimization.lr, eps=config.optimization.optimizer_eps)
        step, seconds = _resumed(config, run, net, optimizer) if resume else _started(config, run, net, init)
        result = _Session(config, run, net, optimizer, step, seconds).run(progress)
        return result


def _started(
    config: PPOConfig, run: RunDirectory, net: RecurrentActorCritic, init: str | Path | None
) -> tuple[int, float]:
    """A new run: ``net`` from ``init`` (if given); its settings and step-0 checkpoint written first."""
    load_init_weights(net, init)
    run.write_config(
        {
            "task": config.task,
            "seed": config.seed,
            "max_episode_steps": config.max_episode_steps,
            "network": config.network.to_dict(),
            "ppo": config.to_dict(),
            "net": net.config.to_dict(),
            "init": str(init) if init is not None else None,
        }
    )
    save_checkpoint(run / CHECKPOINT, model=net.state_dict(), step=0, seconds=0.0, config=json.dumps(config.to_dict()))
    return 0, 0.0


def _resumed(
    config: PPOConfig, run: RunDirectory, net: RecurrentActorCritic, optimizer: torch.optim.Optimizer
) -> tuple[int, float]:
    """A resumed run: its checkpoint's weights and Adam's statistics; refuses other settings."""
    config.check_resumable_from(PPOConfig.from_dict((run.config or {}).get("ppo", {})))
    payload = load_checkpoint(run / CHECKPOINT)
    apply_weights(net, payload, run / CHECKPOINT)
    if payload.get("optimizer") is not None:
        optimizer.load_state_dict(payload["optimizer"])
    return int(payload["step"]), float(payload.get("seconds", 0.0))


class _Session:
    """One session of a PPO run, from its start step to the run's steps (or an interruption)."""

    def __init__(
        self,
        config: PPOConfig,
        run: RunDirectory,
        net: RecurrentActorCritic,
        optimizer: torch.optim.Optimizer,
        step: int,
        seconds: float,
    ):
        self.config, self.directory, self.net, self.optimizer = config, run, net, optimizer
        self.step = self.checkpoint_step = self.eval_step = self.log_step = step
        self.started = time.monotonic() - seconds  # seconds count the whole run, across resumes
        fresh = step == 0 and not run.resume
        # An update's row is logged before its step's checkpoint: a resumed run keeps it.
        self.log: MetricLog = run.metric_log(
            TABLES, resume_step=None if fresh else step, keep_at_resume_step=("updates",)
        )
        self.monitor = Monitor(step)
        self.monitor.restore(self.log.kept["episodes"])
        env_seed, act_seed, batch_seed = np.random.SeedSequence([config.seed, step]).generate_state(3)
        self.batches = torch.Generator().manual_seed(int(batch_seed))
        self.collector = self._collector(int(act_seed))
        self.collector.reset(int(env_seed), step)

    def _collector(self, act_seed: int) -> RolloutCollector:
        config, envs = self.config, self.config.schedule.envs_per_worker
        env = training_env(
            envs,
            task=config.task,
            obs=config.network.obs,
            time_limit=config.time_limit,
            privileged=config.network.privileged,
            action_type=config.network.action_type,
        )
        actor = RecurrentActor(self.net, envs, generator=torch.Generator().manual_seed(act_seed))
        return RolloutCollector(
            env,
            env,
            actor,
            gamma=config.optimization.gamma,
            tilt_input=config.network.tilt_input,
            privileged=config.network.privileged,
            on_episode=self._book,
            global_step=lambda: self.step,
        )

    def _book(self, episode: FinishedEpisode) -> None:
        row = episode.row()
        self.monitor.episode(row)
        self.log.write("episodes", row["end_step"], row, scalars=("return", "length", "success"))

    def run(self, progress: bool) -> TrainResult:
        """Train to the run's steps, then evaluate and write the summary; Ctrl-C or SIGTERM stops with a
        checkpoint (``--resume`` continues). A failure keeps the last checkpoint (and removes a new run
        that had not trained)."""
        config = self.config
        try:
            final_eval = self._train_and_evaluate(progress)
            stopped = "finished"
        except KeyboardInterrupt:
            stopped, final_eval = "interrupted", None
        except BaseException:
            self.log.close()
            if self.checkpoint_step > 0:
                self.directory.keep()
            raise
        self._checkpoint()
        self.directory.keep()
        self.log.close()
        seconds = time.monotonic() - self.started
        summary = {"steps": self.step, "stopped": stopped, "seconds": seconds, "final_eval": final_eval}
        self.directory.write_summary({**summary, **self.monitor.recent()})
        try:
            plot_run(self.directory.path, title=f"PPO on {config.task} ({config.network.obs})")
        except (ValueError, OSError):
            pass  # no finished episode yet (nothing to plot), or no room for the figure: the logs hold it all
        return TrainResult(self.directory.path, self.step, stopped, final_eval, seconds)

    def _train_and_evaluate(self, progress: bool) -> dict[str, Any]:
        """Rollouts and updates to the run's steps, then the final evaluation (logged)."""
        config = self.config
        title = f"PPO {config.task} {config.network.obs}"
        with (
            sigterm_as_interrupt(),
            ProgressBar(title, config.schedule.steps, completed=self.step, enabled=progress, eta=True) as bar,
        ):
            while self.step < config.schedule.steps:
                self._rollout_and_update()
                success = self.monitor.recent()["recent_success"]
                shown = "-" if math.isnan(success) else f"{success:.0%}"
                bar.update(completed=self.step, info=f"{self.monitor.sps(self.step):,.0f} SPS  success {shown}")
            final_eval = {"step": self.step, **run_evaluation(self.net, config)}
        self.log.write("eval", self.step, final_eval, scalars=tuple(TABLES["eval"]))
        return final_eval

    def _rollout_and_update(self) -> None:
        config = self.config
        try:
            segment = self.collector.collect(config.optimization.n_steps, self.step)
        except NonFiniteReward as error:
            raise TrainingError(f"non-finite reward from the env at step {error.step}: {error.rewards}") from error
        parts = ppo_update(self.net, self.optimizer, segment, config.optimization, self.batches)
        if not parts.pop("applied"):
            raise TrainingError(
                f"non-finite loss or gradient at step {self.step:,} ({parts}); the update was not applied. "
                f"Lower --lr or --max-grad-norm. The last checkpoint is kept."
            )
        self.step += config.steps_per_rollout
        if self.step - self.log_step >= config.schedule.log_every:  # the update's losses, every log_every steps
            self.log_step = self.step
            timing = {"sps": self.monitor.sps(self.step), "seconds": time.monotonic() - self.started}
            row = {**parts, **self.monitor.recent(), **timing}
            self.log.write("updates", self.step, row, scalars=_UPDATE_SCALARS)
        if config.schedule.eval_every and self.step - self.eval_step >= config.schedule.eval_every:
            self.eval_step = self.step
            self.log.write("eval", self.step, {"step": self.step, **run_evaluation(self.net, config)})
        if self.step - self.checkpoint_step >= config.schedule.checkpoint_every:
            self._checkpoint()

    def _checkpoint(self) -> None:
        save_checkpoint(
            self.directory / CHECKPOINT,
            model=self.net.state_dict(),
            optimizer=self.optimizer.state_dict(),
            step=self.step,
            seconds=time.monotonic() - self.started,
            config=json.dumps(self.config.to_dict()),
        )
        self.checkpoint_step = self.step
