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
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np
import torch

from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.envs.puzzles import puzzle
from bimgame.expert.episode import Episode
from bimgame.expert.labyrinth_mpc import LabyrinthMPC, LabyrinthMPCConfig
from bimgame.expert.mpc import MPCConfig, RandomShootingMPC
from bimgame.learn.actor import RecurrentActor, env_action, tilt_input
from bimgame.learn.dagger.settings import DAggerConfig
from bimgame.learn.dagger.starts import draw_demo_starts
from bimgame.learn.dagger.teacher import PolicyTeacher
from bimgame.learn.nets import RecurrentActorCritic

__all__ = ["STALL_PROGRESS_M", "Labeller", "collect_episodes", "make_expert", "expert_label"]

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


class Labeller(Protocol):
    """Who labels the rollouts' states, step by step: the MPC experts (:class:`_ExpertLabels`) or a
    trained policy (:class:`~bimgame.learn.dagger.teacher.PolicyTeacher`)."""

    #: Simulator steps spent planning one label (K·H for the MPC expert, 0 for a policy).
    sim_steps_per_label: int

    def labels(
        self,
        envs: Sequence[BallInMazeEnv | LabyrinthEnv],
        infos: list[dict[str, Any]],
        tilt: torch.Tensor,
        active: np.ndarray,
    ) -> list[Any]:
        """Each running rollout's label in its env's current state (``tilt``: the (B, 2) tilt input the
        learner reads); None where ``active`` is False."""
        ...

    def observe(self, executed: torch.Tensor, rewards: np.ndarray, done: np.ndarray) -> None:
        """The step's executed actions, rewards and ended rollouts (what a recurrent labeller reads next)."""
        ...

    def close(self) -> None:
        """Release what the labeller holds."""
        ...


class _ExpertLabels:
    """The MPC experts' labels, one expert per rollout, asked only where the rollout still runs."""

    def __init__(self, experts: list[Expert], sim_steps_per_label: int):
        self.experts = experts
        self.sim_steps_per_label = sim_steps_per_label

    def labels(
        self,
        envs: Sequence[BallInMazeEnv | LabyrinthEnv],
        infos: list[dict[str, Any]],
        tilt: torch.Tensor,
        active: np.ndarray,
    ) -> list[Any]:
        return [
            expert_label(expert, env, info) if running else None
            for expert, env, info, running in zip(self.experts, envs, infos, active, strict=True)
        ]

    def observe(self, executed: torch.Tensor, rewards: np.ndarray, done: np.ndarray) -> None:
        """The experts plan from the physics state alone: nothing to carry between steps."""

    def close(self) -> None:
        for expert in self.experts:
            expert.close()


@dataclasses.dataclass
class _Rollouts:
    """The rollouts of one iteration while they run side by side: each one's environment and record,
    who labels them, their latest observations and infos, which still run, and how many succeeded."""

    envs: list[BallInMazeEnv | LabyrinthEnv]
    labeller: Labeller
    observations: list[np.ndarray]
    infos: list[dict[str, Any]]
    records: list[_Record]
    active: np.ndarray
    stall_steps: int | None = None
    record_states: bool = False
    successes: int = 0
    stalled: int = 0
    best_progress: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    since_best: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @classmethod
    def start(
        cls,
        envs: list[BallInMazeEnv | LabyrinthEnv],
        labeller_of: Callable[[list[BallInMazeEnv | LabyrinthEnv]], Labeller],
        env_seed: int,
        start_states: list[np.ndarray | None],
        stall_steps: int | None = None,
        record_states: bool = False,
    ) -> _Rollouts:
        """Reset every environment (the ``i``-th with seed ``env_seed + i``, in the physics state
        ``start_states[i]`` if not None), then make their labeller (``labeller_of(envs)``): after the
        resets, so that on random mazes each expert plans on its episode's maze. ``stall_steps``: end a
        labyrinth rollout whose progress has not passed its best by :data:`STALL_PROGRESS_M` for
        that many steps. ``record_states``: record each step's state observation too (the labyrinth's
        :meth:`~bimgame.envs.labyrinth_env.LabyrinthEnv.state_observation`)."""
        observations, infos = [], []
        for i, (env, start) in enumerate(zip(envs, start_states, strict=True)):
            options = None if start is None else {"sim_state": start}
            obs, info = env.reset(seed=env_seed + i, options=options)
            observations.append(obs)
            infos.append(info)
        records = [_Record() for _ in envs]
        best = np.array([float(info.get("progress", 0.0)) for info in infos])
        return cls(
            envs,
            labeller_of(envs),
            observations,
            infos,
            records,
            np.ones(len(envs), dtype=bool),
            stall_steps,
            record_states,
            best_progress=best,
            since_best=np.zeros(len(envs), dtype=np.int64),
        )

    def step(self, actor: RecurrentActor, mix: np.random.Generator, beta: float, max_tilt: float) -> None:
        """One step of every running rollout: the labeller labels the state, and the label
        (with probability ``beta``) or the learner's is executed. Finished rollouts keep stepping the
        actor on stale inputs; their records are closed."""
        obs_batch = np.stack(self.observations)
        tilt_batch = tilt_input({"tilt": np.stack([info["tilt"] for info in self.infos])}, max_tilt)
        policy_actions, _, _ = actor.act(obs_batch, tilt_batch)
        executed = actor.executed(policy_actions).clone()
        rewards = np.zeros(len(self.envs))
        done = ~self.active.copy()
        labels = self.labeller.labels(self.envs, self.infos, tilt_batch, self.active)
        for i in map(int, np.flatnonzero(self.active)):
            if mix.random() < beta:
                executed[i] = torch.as_tensor(labels[i], dtype=executed.dtype)
            rewards[i], done[i] = self._step_one(i, labels[i], env_action(executed[i]))
        actor.observe(executed, rewards, done)
        self.labeller.observe(executed, rewards, done)

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
        """Close every environment and the labeller."""
        for env in self.envs:
            env.close()
        self.labeller.close()


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

    def labeller_of(envs: list[BallInMazeEnv | LabyrinthEnv]) -> Labeller:
        if teacher is not None:
            return teacher
        experts = [
            make_expert(env, config.planner, np.random.default_rng(int(seed)), learner.task)
            for env, seed in zip(envs, expert_seeds, strict=True)
        ]
        for expert in experts:
            if isinstance(expert, LabyrinthMPC):
                expert.reset()
        return _ExpertLabels(experts, config.planner.sim_steps_per_decision)

    # A child of the seed draws the starts, leaving the seeds above as they were without them.
    starts = draw_demo_starts(demo_states, config.demo_start_share, count, np.random.default_rng(sequence.spawn(1)[0]))
    rollouts = _Rollouts.start(envs, labeller_of, int(env_seed), starts, config.stall_steps, learner.privileged)
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
        "expert_sim_steps": labels * rollouts.labeller.sim_steps_per_label,
    }
    return episodes, costs
