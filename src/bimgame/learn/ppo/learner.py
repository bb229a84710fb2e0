"""One PPO rank: its environments, the collector that steps them, and the update of its rollouts.

A run has ``workers`` ranks, each a process with ``envs_per_worker`` environments and its own copy
of the network and of Adam. Rank 0 is the process that called :func:`~bimgame.learn.ppo.train_ppo`
(it also logs, evaluates and checkpoints); the others are the worker processes of
:mod:`bimgame.learn.ppo.parallel`. Every rank collects a rollout and trains on its own sequences;
the gradients of each minibatch are averaged over the ranks before the step (decentralised
distributed PPO, Wijmans et al. 2020), so the copies stay identical and the run is one PPO whose
rollout holds every rank's environments. With one worker nothing is averaged. A rank's
environments are stepped in its own process, or (one rank, ``collectors`` ≥ 1) in collector processes
(:mod:`bimgame.learn.ppo.collectors`); either gives the same ``collect``.

With ``policy_lag`` 1 (one rank) the update of a rollout runs in a second thread while the
collector steps the environments for the next one with the weights from before that update: the
acting network (``net``) and the learning copy are then two networks, and the new weights are
copied to the acting one when both threads are done. Each thread has its own generators and
touches only its own network, so the same seed gives the same run; logging, evaluation and
checkpoints stay in the calling thread. A thread, not a process: PyTorch's kernels and MuJoCo's
rollout release the GIL, and the segment and weights need no copying between address spaces.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor, wait
from typing import Any

import torch

from bimgame.learn.finetune import Teacher
from bimgame.learn.learner_settings import policy_network
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.ppo.collectors import CollectorProcesses, rank_seeds, rollout_collector
from bimgame.learn.ppo.settings import PPOConfig
from bimgame.learn.ppo.update import GradientAverage, KLTarget, ppo_update
from bimgame.learn.rewards import EnvWrapper
from bimgame.learn.rollout import FinishedEpisode, NonFiniteReward, RolloutCollector, Segment
from bimgame.learn.run_dir import TrainingError
from bimgame.learn.teachers import StateTeacher

__all__ = ["RankLearner", "adam", "state_teacher"]


def adam(net: torch.nn.Module, config: PPOConfig) -> torch.optim.Adam:
    """PPO's optimiser (every rank builds the same)."""
    return torch.optim.Adam(net.parameters(), lr=config.optimization.lr, eps=config.optimization.optimizer_eps)


class RankLearner:
    """A rank's collector and update. ``net`` acts (on the CPU); ``learning`` is the copy the update
    trains on another device (``optimizer`` holds its weights), copied back to ``net`` after every
    update — None: ``net`` itself learns. ``on_episode`` receives each episode its environments
    finish; ``global_step`` reads the run's step count (the same on every rank); ``average`` averages
    the gradients over the ranks (None: one rank). ``teacher``: the KL's teacher's weights, set at the
    run's step ``taught_since`` (π^s at 0; with ``kl_teacher_refresh_steps``, the policy at the last
    refresh)."""

    def __init__(
        self,
        config: PPOConfig,
        net: RecurrentActorCritic,
        optimizer: torch.optim.Optimizer,
        *,
        rank: int,
        step: int,
        on_episode: Callable[[FinishedEpisode], None],
        global_step: Callable[[], int],
        average: GradientAverage | None = None,
        teacher: dict[str, torch.Tensor] | None = None,
        taught_since: int = 0,
        learning: RecurrentActorCritic | None = None,
        env_wrapper: EnvWrapper | None = None,
    ):
        self.config, self.net, self.optimizer, self.average = config, net, optimizer, average
        self.lag = config.optimization.policy_lag
        if self.lag and learning is None:
            raise ValueError("policy_lag 1 needs a learning copy of the network (see ppo.training.learning_copy)")
        self.learning = learning if learning is not None else net
        # With a policy lag: the rollout collected ahead, and the thread its update runs in.
        self._pending: Segment | None = None
        # The update thread takes this thread's torch thread count: OpenMP's is per thread, and a new
        # thread would start from the process's initial one (a different summation order).
        self._updater = (
            ThreadPoolExecutor(
                1,
                thread_name_prefix="bimgame-ppo-update",
                initializer=torch.set_num_threads,
                initargs=(torch.get_num_threads(),),
            )
            if self.lag
            else None
        )
        self._ahead = 0  # steps the collector is ahead of the run's count (one rollout while collecting ahead)
        self.device = next(self.learning.parameters()).device
        self.teacher = _teacher(config, teacher)
        self.taught_since = taught_since
        self.batches = torch.Generator().manual_seed(rank_seeds(config.seed, step, rank)[2])
        self.collector: RolloutCollector | CollectorProcesses
        if config.collectors:
            self.collector = CollectorProcesses(config, net, step=step, on_episode=on_episode, env_wrapper=env_wrapper)
        else:
            self.collector = rollout_collector(
                config,
                net,
                envs=config.schedule.envs_per_worker,
                rank=rank,
                step=step,
                on_episode=on_episode,
                global_step=lambda: global_step() + self._ahead,
                env_wrapper=env_wrapper,
            )

    def rollout_and_update(self, step: int, *, collect_next: bool = True) -> dict[str, float]:
        """Collect one rollout (the run at ``step``) and train on it; returns the update's averaged
        losses and statistics. With ``policy_lag`` 1 the rollout trained on is the one collected
        ahead during the previous call, and (unless ``collect_next`` is False: the run's last
        update) the next one is collected while it trains. Raises :class:`TrainingError` for a
        non-finite reward, or a non-finite loss or gradient on any rank (the update is then not
        applied on any rank)."""
        if not self.lag:
            return self._take_weights(self._train(self._collect(step), step), step)
        segment = self._pending if self._pending is not None else self._collect(step)
        self._pending = None
        assert self._updater is not None  # made with the lag
        update: Future[dict[str, float]] = self._updater.submit(self._train, segment, step)
        try:
            if collect_next:
                self._ahead = self.config.steps_per_rollout
                self._pending = self._collect(step + self._ahead)
        except BaseException:
            wait([update])  # an interruption or failure while collecting: let the update finish first
            if update.exception() is None and update.result()["applied"]:
                self.net.load_state_dict(self.learning.state_dict())  # the weights match Adam's statistics
            raise
        finally:
            self._ahead = 0
        return self._take_weights(update.result(), step)

    def close(self) -> None:
        """End the update thread (with a policy lag) and the collector's environments (and processes);
        the learner is not used afterwards."""
        if self._updater is not None:
            self._updater.shutdown(wait=True)
        self.collector.close()

    def _collect(self, step: int) -> Segment:
        try:
            return self.collector.collect(self.config.optimization.n_steps, step)
        except NonFiniteReward as error:
            raise TrainingError(f"non-finite reward from the env at step {error.step}: {error.rewards}") from error

    def _train(self, segment: Segment, step: int) -> dict[str, float]:
        """PPO's update of the learning network on ``segment`` (with π^s's KL, if any; the critic alone
        during a critic warm-up)."""
        kl = self._kl_to_teacher(segment, step)
        for group in self.optimizer.param_groups:
            group["lr"] = self.config.optimization.lr_at(step, self.config.schedule.steps)
        if self.device.type != "cpu":  # the learning copy is on another device
            segment = segment.to(self.device)
            kl = None if kl is None else kl._replace(policy=kl.policy.to(self.device))
        finetuning = self.config.finetuning
        parts = ppo_update(
            self.learning,
            self.optimizer,
            segment,
            self.config.optimization,
            self.batches,
            average=self.average,
            kl=kl,
            critic_only=finetuning is not None and finetuning.critic_only(step),
        )
        ceiling = self.config.optimization.max_log_std_at(
            step + self.config.steps_per_rollout, self.config.schedule.steps
        )
        if ceiling is not None and self.learning.log_std is not None:
            with torch.no_grad():  # a projection after the step: the weights that act next obey it
                self.learning.log_std.clamp_(max=ceiling)
        return parts

    def _take_weights(self, parts: dict[str, float], step: int) -> dict[str, float]:
        """The acting network takes the learning copy's weights; raises if the update was not applied."""
        if self.learning is not self.net:
            self.net.load_state_dict(self.learning.state_dict())
        if not parts.pop("applied"):
            raise TrainingError(
                f"non-finite loss or gradient at step {step:,} ({parts}); the update was not applied. "
                f"Lower --lr or --max-grad-norm. The last checkpoint is kept."
            )
        return parts

    def curriculum_status(self) -> dict[str, float]:
        """This rank's start curriculum's status (empty without one): what the update's log row adds."""
        return self.collector.curriculum_status()

    def _kl_to_teacher(self, segment: Segment, step: int) -> KLTarget | None:
        """π^s's log-probabilities over the segment and the KL weight at ``step`` (None without a
        teacher, or once a decaying weight has reached zero: the teacher then stops following)."""
        finetuning = self.config.finetuning
        if self.teacher is None or finetuning is None:
            return None
        weight = finetuning.kl_weight(step)
        if weight <= 0 and finetuning.kl_decay_steps > 0:
            self.teacher = None  # annealed away: it costs nothing from now on
            return None
        if finetuning.refreshes_teacher(self.taught_since, step):
            self._refresh_teacher(segment, step)
        return KLTarget(self.teacher.follow(segment), weight, finetuning.kl_means_only)

    def _refresh_teacher(self, segment: Segment, step: int) -> None:
        """The teacher becomes the policy as it is before this update (the learning copy's weights, the
        same on every rank), following the segment's environments from the acting network's LSTM state
        at its start: with no policy lag, the very network that collected the segment."""
        assert isinstance(self.teacher, Teacher)  # a state teacher is never refreshed (PPOFinetuneSettings)
        self.teacher.become(self.learning.state_dict(), segment.initial_state)
        self.taught_since = step

    def moving_teacher(self) -> dict[str, Any]:
        """What a checkpoint of a run whose teacher moves (``kl_teacher_refresh_steps``) adds: the
        teacher's weights and the step they were set at (``teacher``, ``taught_since``); empty otherwise
        (its teacher is ``teacher.pt``)."""
        finetuning = self.config.finetuning
        if not isinstance(self.teacher, Teacher) or finetuning is None or not finetuning.kl_teacher_refresh_steps:
            return {}
        return {"teacher": self.teacher.net.state_dict(), "taught_since": self.taught_since}


def _teacher(config: PPOConfig, weights: dict[str, torch.Tensor] | None) -> Teacher | StateTeacher | None:
    """The KL term's teacher following this rank's environments: the state teacher (``kl_teacher``)
    or π^s (its ``weights``); None when the run has no KL term."""
    if not config.has_teacher or config.finetuning is None:
        return None
    if config.state_teacher is not None:
        return state_teacher(config, config.schedule.envs_per_worker)
    assert weights is not None, "a run that keeps π^s starts every rank with its weights (teacher.pt)"
    net = policy_network(config)
    net.load_state_dict(weights)
    return Teacher(net, config.schedule.envs_per_worker, config.finetuning.kl_temperature)


def state_teacher(config: PPOConfig, batch: int) -> StateTeacher:
    """The run's state teacher (``kl_teacher``) following ``batch`` environments; raises ``ValueError``
    naming why a teacher cannot teach this run (another layout, kind of action, observation)."""
    assert config.state_teacher is not None and config.finetuning is not None
    return StateTeacher(
        config.state_teacher,
        config.task,
        config.network.action_type,
        learner_tilt_input=config.network.tilt_input,
        batch=batch,
        temperature=config.finetuning.kl_temperature,
    )
