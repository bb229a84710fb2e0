"""Training a PPO run in its directory: collect a rollout of every environment with the shared
:class:`~bimgame.learn.rollout.RolloutCollector`, update (:func:`~bimgame.learn.ppo.update.ppo_update`),
log, evaluate, checkpoint — in this process, the environments stepped as one batch on one MuJoCo
thread, the network on ``torch_threads`` threads.

The run directory is the same as A3C's (config.json, checkpoint.pt, episodes/updates/eval CSV logs,
TensorBoard, summary.json, curves.png) with kind ``ppo``; ``bimgame evaluate`` and ``--init`` read it.
With in-run evaluations (``eval_every``) the run also keeps the weights that evaluated best in
``best.pt`` (:mod:`bimgame.learn.best_iterate`; the final evaluation is a candidate too).
A resumed run continues from its checkpoint (weights, Adam's statistics, steps) with fresh episodes
(environment and sampling seeds derived from the run's seed and the step it resumes at)."""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import time
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import torch

from bimgame.learn.best_iterate import evaluation_rank, is_better, read_best, save_best
from bimgame.learn.checkpoints import apply_weights, load_checkpoint, load_init_weights, save_checkpoint
from bimgame.learn.common import run_evaluation
from bimgame.learn.curricula import CURRICULUM_COLUMNS, CURRICULUM_SCALARS
from bimgame.learn.curves import plot_run
from bimgame.learn.devices import resolve_device
from bimgame.learn.episode_monitor import Monitor
from bimgame.learn.evaluations import EVAL_COLUMNS
from bimgame.learn.init_network import check_init_network, init_settings_for
from bimgame.learn.learner_settings import check_init_puzzle, policy_network
from bimgame.learn.metric_logs import MetricLog
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.ppo.learner import RankLearner, adam, state_teacher
from bimgame.learn.ppo.parallel import WorkerGroup
from bimgame.learn.ppo.settings import PPOConfig
from bimgame.learn.ppo.update import AUX_LOSSES, UPDATE_STATISTICS
from bimgame.learn.rewards import EnvWrapper, RewardSettings, run_reward
from bimgame.learn.rollout import FinishedEpisode
from bimgame.learn.run_dir import BEST, TEACHER, RunDirectory, TrainResult, stored_run_config
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
        *UPDATE_STATISTICS,
        "recent_success",
        "recent_return",
        "recent_length",
        *CURRICULUM_COLUMNS,
    ],
    "eval": list(EVAL_COLUMNS),
}
_UPDATE_SCALARS = (
    "sps",
    "policy_loss",
    "value_loss",
    "entropy",
    "approx_kl",
    "clip_fraction",
    "recent_success",
    *CURRICULUM_SCALARS,
)


def run_tables(net: RecurrentActorCritic) -> dict[str, list[str]]:
    """:data:`TABLES` of a run of ``net``: with auxiliary heads its updates also log their losses (a
    column of their own only then, so the logs of runs without heads keep their header and resume)."""
    if not net.config.aux_heads:
        return TABLES
    return {**TABLES, "updates": [*TABLES["updates"], *AUX_LOSSES]}


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
        check_init_puzzle(init, given.get("task", PPOConfig.task))  # before its network settings are taken
        given = {**init_settings_for(init, given.get("num_mazes")), **given}
    return PPOConfig.from_flat(given)


def train_ppo(
    config: PPOConfig,
    run_dir: str | Path,
    *,
    resume: bool = False,
    init: str | Path | None = None,
    progress: bool = True,
    reward: RewardSettings | None = None,
) -> TrainResult:
    """Train with PPO; everything is saved in ``run_dir`` (a new or empty directory, or with
    ``resume`` the PPO run in it). ``init``: a checkpoint file or run directory whose weights the
    network starts from (e.g. a pre-trained π^s; its network settings must match ``config``'s).
    ``reward``: how the training reward is shaped (None: the task's reward; a resumed run keeps its
    own, the same wrappers as A3C's: :func:`~bimgame.learn.rewards.run_reward`). Raises
    :class:`TrainingError` for a non-finite reward, loss or gradient (the last checkpoint is kept)."""
    if resume and init is not None:
        raise ValueError("--init with --resume: a resumed run continues from its own checkpoint")
    check_init_puzzle(init, config.task)  # before the run directory: a refused start writes nothing
    check_init_network(init, config.network)
    reward, wrapper = run_reward(
        reward or RewardSettings(),
        run_dir,
        resume=resume,
        task=config.task,
        obs=config.network.obs,
        gamma=config.optimization.gamma,
    )
    # With worker processes every rank has one core's share: one thread each; with a policy lag the
    # collecting and the updating thread have one core each.
    threads = 1 if config.schedule.workers > 1 or config.optimization.policy_lag else None
    device = resolve_device(config.device)
    if device.type != "cpu" and config.schedule.workers > 1:
        raise ValueError(f"device {config.device!r} ({device}) takes one process (workers 1)")
    if config.state_teacher is not None:
        state_teacher(config, batch=1)  # a teacher that cannot teach is refused before the run directory is made
    with torch_threads(threads), RunDirectory(run_dir, KIND_PPO, resume=resume) as run:
        net = policy_network(config)
        learning = learning_copy(net, device, separate=bool(config.optimization.policy_lag))
        optimizer = adam(learning if learning is not None else net, config)
        start = _resumed(config, run, net, optimizer) if resume else _started(config, run, net, init, reward)
        if learning is not None:
            learning.load_state_dict(net.state_dict())  # the weights the run starts from
        return _Session(config, run, net, optimizer, start, learning, wrapper).run(progress)


def learning_copy(
    net: RecurrentActorCritic, device: torch.device, *, separate: bool = False
) -> RecurrentActorCritic | None:
    """The copy of ``net`` the update trains on ``device``, or None on the CPU (``net`` itself learns)
    unless ``separate`` (a policy lag: the update trains while ``net`` acts)."""
    return None if device.type == "cpu" and not separate else copy.deepcopy(net).to(device)


@dataclasses.dataclass(frozen=True)
class _Start:
    """Where a session starts: the run's step and seconds so far, and the KL term's teacher (π^s, or
    with ``kl_teacher_refresh_steps`` the policy at its last refresh) with the step it was set at."""

    step: int
    seconds: float
    teacher: dict[str, torch.Tensor] | None = None
    taught_since: int = 0


def _started(
    config: PPOConfig, run: RunDirectory, net: RecurrentActorCritic, init: str | Path | None, reward: RewardSettings
) -> _Start:
    """A new run: ``net`` from ``init`` (if given), π^s kept for a KL term to it (``teacher.pt``); its
    settings (the reward's too) and step-0 checkpoint written first."""
    if config.keeps_pi_s and init is None:
        raise ValueError(
            "PPOFinetuneSettings.kl_coef > 0 (kickstarting) needs a pre-trained policy to stay close to: "
            "pass --init (or set kl_coef to 0)"
        )
    load_init_weights(net, init)
    teacher = {k: v.detach().clone() for k, v in net.state_dict().items()} if config.keeps_pi_s else None
    if teacher is not None:
        save_checkpoint(run / TEACHER, model=teacher, step=0, source=str(init))
    run.write_config(
        {
            "task": config.task,
            "seed": config.seed,
            "max_episode_steps": config.max_episode_steps,
            "network": config.network.to_dict(),
            "ppo": config.to_dict(),
            "net": net.config.to_dict(),
            "init": str(init) if init is not None else None,
            "reward": reward.to_dict(),
        }
    )
    save_checkpoint(run / CHECKPOINT, model=net.state_dict(), step=0, seconds=0.0, config=json.dumps(config.to_dict()))
    return _Start(0, 0.0, teacher)


def _resumed(
    config: PPOConfig, run: RunDirectory, net: RecurrentActorCritic, optimizer: torch.optim.Optimizer
) -> _Start:
    """A resumed run: its checkpoint's weights, Adam's statistics and its teacher (the checkpoint's when
    the teacher moves, else π^s's ``teacher.pt``); refuses other settings."""
    config.check_resumable_from(PPOConfig.from_dict((run.config or {}).get("ppo", {})))
    payload = load_checkpoint(run / CHECKPOINT)
    apply_weights(net, payload, run / CHECKPOINT)
    if payload.get("optimizer") is not None:
        optimizer.load_state_dict(payload["optimizer"])
    step, seconds = int(payload["step"]), float(payload.get("seconds", 0.0))
    if not config.keeps_pi_s:
        return _Start(step, seconds)
    if payload.get("teacher") is not None:  # a teacher that moves: the one the checkpoint's step had
        return _Start(step, seconds, payload["teacher"], int(payload["taught_since"]))
    return _Start(step, seconds, load_checkpoint(run / TEACHER)["model"])


class _Session:
    """One session of a PPO run, from its start step to the run's steps (or an interruption)."""

    def __init__(
        self,
        config: PPOConfig,
        run: RunDirectory,
        net: RecurrentActorCritic,
        optimizer: torch.optim.Optimizer,
        start: _Start,
        learning: RecurrentActorCritic | None = None,
        env_wrapper: EnvWrapper | None = None,
    ):
        self.config, self.directory, self.net, self.optimizer = config, run, net, optimizer
        step = self.step = self.checkpoint_step = self.eval_step = self.log_step = start.step
        self.start, self.learning, self.env_wrapper = start, learning, env_wrapper
        self.learner: RankLearner | None = None
        self.started = time.monotonic() - start.seconds  # seconds count the whole run, across resumes
        fresh = step == 0 and not run.resume
        # An update's row is logged before its step's checkpoint: a resumed run keeps it.
        tables = run_tables(net)
        self.log: MetricLog = run.metric_log(
            tables, resume_step=None if fresh else step, keep_at_resume_step=("updates",)
        )
        # The columns TensorBoard also gets: the usual ones, and the heads' losses the run's table logs.
        self.update_scalars = (*_UPDATE_SCALARS, *(c for c in AUX_LOSSES if c in tables["updates"]))
        self.monitor = Monitor(step)
        self.monitor.restore(self.log.kept["episodes"])
        # The best so far is best.pt's own record: written when its evaluation ran, it may be newer
        # than the checkpoint a resumed run continues from (weights this run did produce).
        self.best = read_best(run / BEST) if run.resume else None

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
        """Rollouts and updates to the run's steps (with the worker processes, if any), then the final
        evaluation (logged)."""
        config = self.config
        title = f"PPO {config.task} {config.network.obs}"
        group = WorkerGroup(config) if config.schedule.workers > 1 else None
        with (
            sigterm_as_interrupt(),
            group.start(
                self.net, self.optimizer, self.step, self.start.teacher, self.start.taught_since, self.env_wrapper
            )
            if group is not None
            else nullcontext(),
            ProgressBar(title, config.schedule.steps, completed=self.step, enabled=progress, eta=True) as bar,
        ):
            learner = self.learner = RankLearner(
                config,
                self.net,
                self.optimizer,
                rank=0,
                step=self.step,
                on_episode=self._book,
                global_step=lambda: self.step,
                average=group.average if group is not None else None,
                teacher=self.start.teacher,
                taught_since=self.start.taught_since,
                learning=self.learning,
                env_wrapper=self.env_wrapper,
            )
            try:
                while self.step < config.schedule.steps:
                    self._rollout_and_update(learner, group)
                    success = self.monitor.recent()["recent_success"]
                    shown = "-" if math.isnan(success) else f"{success:.0%}"
                    bar.update(completed=self.step, info=f"{self.monitor.sps(self.step):,.0f} SPS  success {shown}")
            finally:
                learner.close()
            return self._evaluate()

    def _rollout_and_update(self, learner: RankLearner, group: WorkerGroup | None) -> None:
        config = self.config
        if group is not None:
            group.go(self.step)
        last = self.step + config.steps_per_rollout >= config.schedule.steps
        parts = learner.rollout_and_update(self.step, collect_next=not last)
        if group is not None:
            for episode in group.episodes():
                self._book(episode)
        self.step += config.steps_per_rollout
        if self.step - self.log_step >= config.schedule.log_every:  # the update's losses, every log_every steps
            self.log_step = self.step
            timing = {"sps": self.monitor.sps(self.step), "seconds": time.monotonic() - self.started}
            row = {**parts, **self.monitor.recent(), **timing, **learner.curriculum_status()}
            self.log.write("updates", self.step, row, scalars=self.update_scalars)
        if config.schedule.eval_every and self.step - self.eval_step >= config.schedule.eval_every:
            self.eval_step = self.step
            self._evaluate()
        if self.step - self.checkpoint_step >= config.schedule.checkpoint_every:
            self._checkpoint()

    def _evaluate(self) -> dict[str, Any]:
        """Evaluate the acting weights (logged); keep them in ``best.pt`` if they rank above the best."""
        evaluation = {"step": self.step, **run_evaluation(self.net, self.config)}
        self.log.write("eval", self.step, evaluation, scalars=tuple(TABLES["eval"]))
        if is_better(evaluation, self.best):
            self.best = {"step": self.step, "rank": evaluation_rank(evaluation)}
            save_best(self.directory / BEST, self.net.state_dict(), self.best)
        return evaluation

    def _checkpoint(self) -> None:
        moving_teacher = {} if self.learner is None else self.learner.moving_teacher()
        save_checkpoint(
            self.directory / CHECKPOINT,
            model=self.net.state_dict(),
            optimizer=self.optimizer.state_dict(),
            step=self.step,
            seconds=time.monotonic() - self.started,
            config=json.dumps(self.config.to_dict()),
            **moving_teacher,
        )
        self.checkpoint_step = self.step
