"""DAgger's rollouts (:mod:`bimgame.learn.dagger`): the learner's episodes, run side by side, each
step labelled by the MPC expert in the true simulator state and executed as the expert's action
with probability β, else the learner's.

On either puzzle: the circular maze's :class:`~bimgame.expert.mpc.RandomShootingMPC` labels discrete
actions; the labyrinth's :class:`~bimgame.expert.labyrinth_mpc.LabyrinthMPC` labels the learner's
kind, continuous tilt rates or discrete, following the env's path segment. On the labyrinth a trained
policy may label instead (``DAggerConfig.teacher``: :class:`~bimgame.learn.dagger.teacher.PolicyTeacher`,
one batched pass for all rollouts per step).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.envs.puzzles import puzzle
from bimgame.expert.episode import Episode
from bimgame.expert.labyrinth_mpc import LabyrinthMPC, LabyrinthMPCConfig
from bimgame.expert.mpc import MPCConfig, RandomShootingMPC
from bimgame.learn.actor import RecurrentActor, tilt_input
from bimgame.learn.dagger.settings import DAggerConfig
from bimgame.learn.dagger.starts import draw_demo_starts
from bimgame.learn.dagger.teacher import PolicyTeacher
from bimgame.learn.nets import RecurrentActorCritic

__all__ = ["STALL_PROGRESS_M", "collect_episodes", "make_expert", "expert_label"]

#: With ``DAggerConfig.stall_steps``, a labyrinth rollout progresses when it passes its best progress
#: along the path by this much (m, a twelfth of the marble's diameter): a marble rolling on at a
#: crawl (1 cm/s) passes it within 6 steps at 55 Hz.
STALL_PROGRESS_M = 1e-3


@dataclasses.dataclass
class _Record:
    """What one rollout recorded, step by step: what the learner saw, the expert's label, the action
    executed and the reward it brought (actions: discrete ints or continuous (2,) arrays); for a
    learner with auxiliary heads or an asymmetric critic also the state observation (``states``)."""

    obs: list[np.ndarray] = dataclasses.field(default_factory=list)
    tilt: list[np.ndarray] = dataclasses.field(default_factory=list)
    actions: list[Any] = dataclasses.field(default_factory=list)
    executed: list[Any] = dataclasses.field(default_factory=list)
    rewards: list[float] = dataclasses.field(default_factory=list)
    states: list[np.ndarray] = dataclasses.field(default_factory=list)

    def as_episode(self, gamma: float) -> Episode:
        """The rollout as an :class:`~bimgame.expert.episode.Episode` (``actions``: the expert's labels)."""
        return Episode.from_steps(
            obs=np.stack(self.obs),
            actions=np.asarray(self.actions),
            rewards=np.asarray(self.rewards),
            tilt=np.asarray(self.tilt),
            gamma=gamma,
            executed=np.asarray(self.executed),
            state_obs=np.stack(self.states) if self.states else None,
        )


Expert = RandomShootingMPC | LabyrinthMPC


def make_expert(
    env: BallInMazeEnv | LabyrinthEnv, config: MPCConfig | LabyrinthMPCConfig, rng: np.random.Generator, task: str
) -> Expert:
    """The MPC expert that labels ``env``'s states for ``task``: the labyrinth's, matched to the env
    (board, rate, action type, reward), or the circular maze's for the task's goal."""
    if isinstance(env, LabyrinthEnv):
        assert isinstance(config, LabyrinthMPCConfig)
        return LabyrinthMPC.for_env(env, config, rng=rng)
    assert isinstance(config, MPCConfig)
    return RandomShootingMPC(env.maze, config, rng=rng, task=task)


def expert_label(expert: Expert, env: BallInMazeEnv | LabyrinthEnv, info: dict[str, Any]) -> Any:
    """The expert's action in ``env``'s true physics state (``info``: the env's latest, whose path
    segment the labyrinth's expert follows)."""
    state = env.sim.get_state()
    if isinstance(expert, LabyrinthMPC):
        return expert.act(state, info["segment"])
    return expert.act(state)


@dataclasses.dataclass
class _Rollouts:
    """The rollouts of one iteration while they run side by side: each one's environment, expert and
    record, its latest observation and info, whether it still runs, and how many succeeded. With a
    ``teacher`` the rollouts have no MPC experts (``experts`` empty): the teacher labels them all."""

    envs: list[BallInMazeEnv | LabyrinthEnv]
    experts: list[Expert]
    observations: list[np.ndarray]
    infos: list[dict[str, Any]]
    records: list[_Record]
    active: np.ndarray
    stall_steps: int | None = None
    record_states: bool = False
    teacher: PolicyTeacher | None = None
    successes: int = 0
    stalled: int = 0
    best_progress: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    since_best: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @classmethod
    def start(
        cls,
        envs: list[BallInMazeEnv | LabyrinthEnv],
        make_expert: Callable[[int, BallInMazeEnv | LabyrinthEnv], Expert] | PolicyTeacher,
        env_seed: int,
        start_states: list[np.ndarray | None],
        stall_steps: int | None = None,
        record_states: bool = False,
    ) -> _Rollouts:
        """Reset every environment (the ``i``-th with seed ``env_seed + i``, in the physics state
        ``start_states[i]`` if not None), then make its expert (``make_expert(i, env)``): after the
        reset, so that on random mazes it plans on the episode's maze; or let one
        :class:`~bimgame.learn.dagger.teacher.PolicyTeacher` label every rollout. ``stall_steps``: end a
        labyrinth rollout whose progress has not passed its best by :data:`STALL_PROGRESS_M` for
        that many steps. ``record_states``: record each step's state observation too (the labyrinth's
        :meth:`~bimgame.envs.labyrinth_env.LabyrinthEnv.state_observation`)."""
        observations, infos, experts = [], [], []
        for i, (env, start) in enumerate(zip(envs, start_states, strict=True)):
            options = None if start is None else {"sim_state": start}
            obs, info = env.reset(seed=env_seed + i, options=options)
            if not isinstance(make_expert, PolicyTeacher):
                expert = make_expert(i, env)
                if isinstance(expert, LabyrinthMPC):
                    expert.reset()
                experts.append(expert)
            observations.append(obs)
            infos.append(info)
        records = [_Record() for _ in envs]
        best = np.array([float(info.get("progress", 0.0)) for info in infos])
        return cls(
            envs,
            experts,
            observations,
            infos,
            records,
            np.ones(len(envs), dtype=bool),
            stall_steps,
            record_states,
            teacher=make_expert if isinstance(make_expert, PolicyTeacher) else None,
            best_progress=best,
            since_best=np.zeros(len(envs), dtype=np.int64),
        )

    def step(self, actor: RecurrentActor, mix: np.random.Generator, beta: float, max_tilt: float) -> None:
        """One step of every running rollout: the expert labels the state, and the expert's action
        (with probability ``beta``) or the learner's is executed. Finished rollouts keep stepping the
        actor on stale inputs; their records are closed."""
        obs_batch = np.stack(self.observations)
        tilt_batch = tilt_input({"tilt": np.stack([info["tilt"] for info in self.infos])}, max_tilt)
        policy_actions, _, _ = actor.act(obs_batch, tilt_batch)
        executed = actor.executed(policy_actions).clone()
        rewards = np.zeros(len(self.envs))
        done = ~self.active.copy()
        taught = None if self.teacher is None else self.teacher.labels(self._labyrinths(), self.infos)
        for i in map(int, np.flatnonzero(self.active)):
            label = expert_label(self.experts[i], self.envs[i], self.infos[i]) if taught is None else _one(taught[i])
            if mix.random() < beta:
                executed[i] = torch.as_tensor(label, dtype=executed.dtype)
            action = _one(executed[i])
            rewards[i], done[i] = self._step_one(i, label, action)
        actor.observe(executed, rewards, done)
        if self.teacher is not None:
            self.teacher.observe(executed, rewards, done)

    def _labyrinths(self) -> list[LabyrinthEnv]:
        """The rollouts' envs, which a teacher labels: the labyrinth's (DAggerConfig refuses a teacher
        on the circular maze)."""
        assert all(isinstance(env, LabyrinthEnv) for env in self.envs)
        return [env for env in self.envs if isinstance(env, LabyrinthEnv)]

    def _step_one(self, i: int, label: Any, action: Any) -> tuple[float, bool]:
        """Record rollout ``i``'s step (``label``: the expert's action; ``action``: the one executed)
        and take it; returns its reward and whether the rollout ended (terminated or stalled)."""
        record = self.records[i]
        record.obs.append(self.observations[i])
        record.tilt.append(self.infos[i]["tilt"])
        record.actions.append(label)
        record.executed.append(action)
        if self.record_states:
            env = self.envs[i]
            assert isinstance(env, LabyrinthEnv)  # DAggerConfig refuses the maze's
            record.states.append(env.state_observation())
        obs, reward, terminated, _, info = self.envs[i].step(action)
        record.rewards.append(reward)
        self.observations[i], self.infos[i] = obs, info
        if terminated:
            self.active[i] = False
            self.successes += int(info["is_success"])
        elif self._stalls(i, info):
            self.active[i] = False
            self.stalled += 1
        return reward, not self.active[i]

    def _stalls(self, i: int, info: dict[str, Any]) -> bool:
        """Whether rollout ``i`` has now gone ``stall_steps`` steps without passing its best progress
        by :data:`STALL_PROGRESS_M` (never without ``stall_steps``)."""
        if self.stall_steps is None:
            return False
        if info["progress"] >= self.best_progress[i] + STALL_PROGRESS_M:
            self.best_progress[i], self.since_best[i] = info["progress"], 0
            return False
        self.since_best[i] += 1
        return bool(self.since_best[i] >= self.stall_steps)

    def close(self) -> None:
        """Close every environment and expert (or the teacher)."""
        for env in self.envs:
            env.close()
        for expert in self.experts:
            expert.close()
        if self.teacher is not None:
            self.teacher.close()


def _one(action: torch.Tensor) -> Any:
    """One rollout's action as the env takes it: a (2,) float array (continuous) or an int."""
    return action.numpy().copy() if action.is_floating_point() else int(action)


@torch.no_grad()
def collect_episodes(
    net: RecurrentActorCritic,
    config: DAggerConfig,
    beta: float,
    seed: int,
    demo_states: np.ndarray | None = None,
) -> tuple[list[Episode], dict[str, int]]:
    """``episodes_per_iteration`` episodes, run side by side (one batched forward pass per step),
    executing the expert's action with probability ``beta`` and the learner's sampled action
    otherwise; every visited state is labelled by the expert (or by ``config.teacher``).
    ``demo_states`` (K, S): physics states of the expert's episodes, from which
    ``config.demo_start_share`` of the episodes start (drawn uniformly,
    :mod:`bimgame.learn.dagger.starts`); the others start at the task's start. Returns the episodes
    (as :class:`~bimgame.expert.episode.Episode` records, ``actions`` being the expert's labels and
    ``executed`` what was done) and the costs: ``env_steps``, ``labels``, ``expert_sim_steps``,
    ``successes`` and ``stalled`` (rollouts ended by ``config.stall_steps``)."""
    learner = config.learner
    sequence = np.random.SeedSequence([seed])
    env_seed, torch_seed, mix_seed, *expert_seeds = sequence.generate_state(3 + config.episodes_per_iteration)
    count = config.episodes_per_iteration
    task = puzzle(learner.task)
    teacher = (
        None if config.teacher is None else PolicyTeacher(config.teacher, learner.task, learner.action_type, count)
    )
    envs = [
        task.env(obs_mode=learner.obs, action_type=learner.action_type, **config.maze_options) for _ in range(count)
    ]
    mix = np.random.default_rng(int(mix_seed))
    actor = RecurrentActor(net, count, generator=torch.Generator().manual_seed(int(torch_seed)))
    max_tilt = task.spec.max_tilt

    def expert_of(i: int, env: BallInMazeEnv | LabyrinthEnv) -> Expert:
        return make_expert(env, config.planner, np.random.default_rng(int(expert_seeds[i])), learner.task)

    labeller = expert_of if teacher is None else teacher
    # A child of the seed draws the starts, leaving the seeds above as they were without them.
    starts = draw_demo_starts(demo_states, config.demo_start_share, count, np.random.default_rng(sequence.spawn(1)[0]))
    rollouts = _Rollouts.start(envs, labeller, int(env_seed), starts, config.stall_steps, learner.privileged)
    steps = 0
    try:
        while rollouts.active.any() and steps < config.time_limit:
            rollouts.step(actor, mix, beta, max_tilt)
            steps += 1
    finally:
        rollouts.close()
    episodes = [record.as_episode(learner.gamma) for record in rollouts.records]
    labels = sum(len(e) for e in episodes)
    costs = {
        "env_steps": labels,
        "labels": labels,
        "successes": rollouts.successes,
        "stalled": rollouts.stalled,
        "expert_sim_steps": 0 if config.teacher is not None else labels * config.planner.sim_steps_per_decision,
    }
    return episodes, costs
