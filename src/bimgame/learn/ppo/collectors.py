"""Where PPO's rollouts are collected: in the learning process, or in child processes (``collectors``).

:func:`rollout_collector` builds a process's environments and the shared
:class:`~bimgame.learn.rollout.RolloutCollector` that steps them; :class:`CollectorProcesses` runs
``collectors`` of them in child processes and gives the learning process the same ``collect`` a
collector of its own would.

Why child processes: from state, stepping the 16 boards with the network acting takes about 0.10 ms
per environment step on this project's 2-core machine and PPO's update of the rollout about 0.07 ms
(STG1, 2,048-step rollouts, one thread each): one process alternating them uses one core at a time.
A collector process steps its share of the environments with its own copy of the acting network;
before every rollout the learning process writes the acting weights into shared memory (one copy,
no pickling) and the collectors read them; the segments come back (tensors in shared memory) and
are laid side by side (:meth:`~bimgame.learn.rollout.Segment.side_by_side`) for one update in the
learning process. With ``policy_lag`` 1 the learner's update thread trains on one rollout while the
collector steps the next, each on its own core; the same overlap with a thread only (the collector in
the learning process) measured 1.25×, the two threads taking turns at the interpreter.

Unlike ``workers`` (ranks that each collect and update, averaging gradients:
:mod:`~bimgame.learn.ppo.parallel`), the update stays one process's and nothing is averaged.

Same seed, same run: collector *i*'s environments and action samples draw from
:func:`rank_seeds` (seed, step, *i*), so collector 0's are those of a run collecting in its own
process — one collector without a policy lag gives exactly that run (tested). Each collector has its
own start curriculum (as each of A3C's workers has); the ``updates`` log shows the first one's.
"""

from __future__ import annotations

import dataclasses
import signal
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
import torch.multiprocessing

from bimgame.learn.actor import RecurrentActor
from bimgame.learn.curricula import start_curriculum
from bimgame.learn.learner_settings import policy_network
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.ppo.processes import next_message, stop_children
from bimgame.learn.ppo.settings import PPOConfig
from bimgame.learn.rewards import EnvWrapper, shaped_env
from bimgame.learn.rollout import FinishedEpisode, NonFiniteReward, RolloutCollector, Segment, training_env
from bimgame.util.processes import exit_when_parent_dies

__all__ = ["CollectorProcesses", "rank_seeds", "rollout_collector"]


def rank_seeds(seed: int, step: int, rank: int) -> tuple[int, int, int]:
    """The seeds of a rank's (or a collector's) environments, action sampling and minibatch order for
    a session that starts at ``step`` (fresh episodes at every resume). Rank 0's are those of a
    one-process run."""
    entropy = [seed, step] if rank == 0 else [seed, step, rank]
    env_seed, act_seed, batch_seed = np.random.SeedSequence(entropy).generate_state(3)
    return int(env_seed), int(act_seed), int(batch_seed)


def rollout_collector(
    config: PPOConfig,
    net: RecurrentActorCritic,
    *,
    envs: int,
    rank: int,
    step: int,
    on_episode: Callable[[FinishedEpisode], None],
    global_step: Callable[[], int],
    env_wrapper: EnvWrapper | None = None,
) -> RolloutCollector:
    """``envs`` training environments of ``config``'s task (through the run's reward shaping
    ``env_wrapper``) stepped by ``net``, reset for a session that starts at ``step``, with the seeds
    and start curriculum of ``rank``."""
    env_seed, act_seed, _ = rank_seeds(config.seed, step, rank)
    curriculum = start_curriculum(config.task, config.curriculum, config.expert_data)
    env = training_env(
        envs,
        task=config.task,
        obs=config.network.obs,
        time_limit=config.time_limit,
        privileged=config.records_state,
        action_type=config.network.action_type,
        start_sampler=curriculum,
        **config.maze_options,
    )
    actor = RecurrentActor(
        net,
        envs,
        generator=torch.Generator().manual_seed(act_seed),
        temperature=config.optimization.sample_temperature,
    )
    collector = RolloutCollector(
        shaped_env(env, env_wrapper),
        env,
        actor,
        gamma=config.optimization.gamma,
        tilt_input=config.network.tilt_input,
        privileged=config.records_state,
        on_episode=on_episode,
        global_step=global_step,
        curriculum=curriculum,
    )
    collector.reset(env_seed, step)
    return collector


@dataclasses.dataclass(frozen=True)
class _CollectorStart:
    """What a collector process starts from."""

    config: dict[str, Any]
    index: int
    step: int
    """The run's step the session starts at (the seeds derive from it)."""
    weights: dict[str, torch.Tensor]
    """The acting weights, in shared memory: the learning process writes them before every rollout."""
    env_wrapper: EnvWrapper | None = None
    """The reward shaping the environments are stepped through (picklable)."""


def _collector_main(start: _CollectorStart, commands: Any, results: Any) -> None:
    """A collector process: for every ``("collect", step)`` it reads the shared weights, steps its
    environments for one rollout and sends ``("segment", index, (segment, episodes, curriculum
    status))``; ``("stop", _)`` ends it. A non-finite reward is sent as ``("nonfinite", index, (step,
    rewards, episodes))``, any other failure as a traceback."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the learning process decides when the run stops
    exit_when_parent_dies()  # a learning process killed with kill -9 leaves no collector behind
    torch.set_num_threads(1)
    try:
        config = PPOConfig.from_dict(start.config)
        net = policy_network(config)
        finished: list[FinishedEpisode] = []
        now = [start.step]
        collector = rollout_collector(
            config,
            net,
            envs=config.schedule.envs_per_worker // config.collectors,
            rank=start.index,
            step=start.step,
            on_episode=finished.append,
            global_step=lambda: now[0],
            env_wrapper=start.env_wrapper,
        )
        while True:
            command, now[0] = commands.get()
            if command == "stop":
                break
            net.load_state_dict(start.weights)
            try:
                segment = collector.collect(config.optimization.n_steps, now[0])
            except NonFiniteReward as error:
                results.put(("nonfinite", start.index, (error.step, error.rewards, list(finished))))
                break
            results.put(("segment", start.index, (segment, list(finished), collector.curriculum_status())))
            finished.clear()
        collector.close()
    except BaseException:
        results.put(("error", start.index, traceback.format_exc()))
        raise


class CollectorProcesses:
    """``config.collectors`` child processes, each stepping ``envs_per_worker / collectors`` of the
    run's environments with a copy of ``net`` (the acting network, whose weights each rollout uses);
    ``on_episode`` receives every finished episode, in the collectors' order, when a rollout is in.
    Close it (:meth:`close`) to end the processes."""

    def __init__(
        self,
        config: PPOConfig,
        net: RecurrentActorCritic,
        *,
        step: int,
        on_episode: Callable[[FinishedEpisode], None],
        env_wrapper: EnvWrapper | None = None,
    ):
        self.net, self.on_episode = net, on_episode
        self.weights = {name: value.detach().clone().share_memory_() for name, value in net.state_dict().items()}
        context = torch.multiprocessing.get_context("spawn")
        self.results = context.Queue()
        self.commands = [context.Queue() for _ in range(config.collectors)]
        self.processes: list[Any] = []
        self.status: dict[str, float] = {}
        try:
            for index, commands in enumerate(self.commands):
                start = _CollectorStart(config.to_dict(), index, step, self.weights, env_wrapper)
                process = context.Process(
                    target=_collector_main,
                    args=(start, commands, self.results),
                    daemon=True,
                    name=f"bimgame-ppo-collector-{index}",
                )
                process.start()
                self.processes.append(process)
        except BaseException:
            self.close(terminate=True)
            raise

    def collect(self, n_steps: int, step_at_start: int) -> Segment:
        """One rollout of every collector's environments, acting with ``net``'s current weights, side by
        side in the collectors' order. ``n_steps`` is the run's, which each collector steps (the same
        call as :meth:`RolloutCollector.collect`); raises
        :class:`NonFiniteReward` (after booking the episodes that ended before it) when an env
        returns a non-finite reward."""
        for name, value in self.net.state_dict().items():
            self.weights[name].copy_(value)
        for commands in self.commands:
            commands.put(("collect", step_at_start))
        replies: dict[int, tuple[str, Any]] = {}
        while len(replies) < len(self.processes):
            kind, index, payload = next_message(self.results, self.processes, "PPO collector")
            replies[index] = (kind, payload)
        segments, failure = [], None
        for index in sorted(replies):
            kind, payload = replies[index]
            if kind == "nonfinite":
                step, rewards, episodes = payload
                failure = failure or NonFiniteReward(step, rewards)
            else:
                segment, episodes, status = payload
                segments.append(segment)
                if index == 0:
                    self.status = status
            for episode in episodes:
                self.on_episode(episode)
        if failure is not None:
            raise failure
        return Segment.side_by_side(segments)

    def curriculum_status(self) -> dict[str, float]:
        """The first collector's start curriculum's status after the last rollout (empty without one)."""
        return self.status

    def close(self, *, terminate: bool = False) -> None:
        """End the collector processes (at once with ``terminate``)."""
        stop_children(self.commands, self.processes, terminate=terminate, grace=10.0)
