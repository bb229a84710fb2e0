"""Collecting on-policy experience: the rollout collector every on-policy learner shares.

:class:`RolloutCollector` steps a batched vector env with a :class:`~bimgame.learn.actor.RecurrentActor`
for a fixed number of steps and returns a :class:`Segment`: the network's inputs, the actions taken,
their rewards and the episode boundaries, as tensors laid out (time, environment). On the way it

- carries the actor's recurrent state from one segment to the next (the segment records the LSTM
  state it started from, so that a learner can unroll the network over it again with gradients);
- bootstraps at time limits: a truncated episode is not a terminal state, so γ·V of its last
  observation (which SAME_STEP autoreset keeps in ``info["final_obs"]``) is added to the reward of
  the step that cut it;
- books every finished episode (:class:`FinishedEpisode`), counted from the environment step at which
  it started, and tells a start curriculum how each of its starts went.

What a learner does with a segment — A3C's one gradient step, PPO's epochs of minibatches — is not
the collector's business; :func:`advantages_and_targets` is the advantage estimate both use.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
import torch

from bimgame.envs.puzzles import PuzzleVectorEnv, puzzle
from bimgame.learn.actor import RecurrentActor, episode_successes, tilt_input
from bimgame.learn.nets import LSTMState, RecurrentActorCritic, Unrolled
from bimgame.learn.start_stages import TRUE_START

__all__ = [
    "Segment",
    "FinishedEpisode",
    "NonFiniteReward",
    "StartCurriculum",
    "RolloutCollector",
    "unroll",
    "sequence_start_states",
    "in_sequences",
    "training_env",
    "advantages_and_targets",
]


@dataclasses.dataclass(frozen=True)
class Segment:
    """T acting steps of B environments, as tensors with time first.

    The network's inputs hold T+1 steps: the T steps acted on and the observation after the last
    one, whose value bootstraps the returns."""

    obs: torch.Tensor
    """(T+1, B, …) observations (uint8 frames or float32 state vectors)."""
    prev_action: torch.Tensor
    """(T+1, B) the action before each step (NO_ACTION at an episode's first step); a continuous
    network's (T+1, B, 2), the executed (clipped) action, zeros at an episode's first step."""
    prev_reward: torch.Tensor
    """(T+1, B) the reward before each step (0 at an episode's first step)."""
    tilt: torch.Tensor | None
    """(T+1, B, 2) the board tilt in units of the maximum tilt; None for networks that do not read it."""
    starts: torch.Tensor
    """(T+1, B) bool: the step is an episode's first (the LSTM state is zeroed there)."""
    actions: torch.Tensor
    """(T, B) the actions taken; continuous: (T, B, 2) float, the policy's samples before the env's
    clipping to [-1, 1] (what their log-probabilities are of)."""
    rewards: torch.Tensor
    """(T, B) float32 rewards, with γ·V(final observation) already added at time-limit truncations."""
    ends: torch.Tensor
    """(T, B) bool: the episode ended after this step (terminated or truncated)."""
    initial_state: LSTMState
    """The LSTM state (B, H) each environment's first step started from."""
    privileged: torch.Tensor | None = None
    """(T+1, B, P) the simulator's state observations, for auxiliary heads and an asymmetric critic;
    never a policy input. None when the run does not use them."""
    log_probs: torch.Tensor | None = None
    """(T, B) log π(a_t|s_t) of the actions under the policy that acted (for importance ratios)."""
    values: torch.Tensor | None = None
    """(T, B) V(s_t) of the network that acted, when the segment was collected."""
    step_at_start: int = 0
    """The run's environment step count when the segment's collection began."""

    @property
    def steps(self) -> int:
        """T, the acting steps."""
        return int(self.actions.shape[0])

    @property
    def batch(self) -> int:
        """B, the environments."""
        return int(self.actions.shape[1])

    def replace(self, **changes: Any) -> Segment:
        """A copy with some fields replaced (e.g. augmented observations)."""
        return dataclasses.replace(self, **changes)

    def envs(self, index: torch.Tensor) -> Segment:
        """The segment of the environments ``index`` (a 1-D tensor of environment indices), each
        sequence whole: what a learner that splits a segment into minibatches (PPO) trains on, so
        that the LSTM is unrolled over every step of each environment it sees."""
        by_env: dict[str, Any] = {}
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if isinstance(value, torch.Tensor):
                by_env[field.name] = value[:, index]
        h, c = self.initial_state
        return dataclasses.replace(self, **by_env, initial_state=LSTMState(h[index], c[index]))

    @classmethod
    def side_by_side(cls, parts: list[Segment]) -> Segment:
        """The segments of several groups of environments, collected over the same steps, as one:
        their environments in the order of ``parts`` (what PPO's collector processes return)."""
        first = parts[0]
        joined: dict[str, Any] = {
            field.name: torch.cat([getattr(part, field.name) for part in parts], dim=1)
            for field in dataclasses.fields(first)
            if isinstance(getattr(first, field.name), torch.Tensor)
        }
        states = LSTMState(
            torch.cat([part.initial_state.h for part in parts]), torch.cat([part.initial_state.c for part in parts])
        )
        return dataclasses.replace(first, **joined, initial_state=states)

    def to(self, device: torch.device) -> Segment:
        """The segment on ``device`` (where a learner's update runs)."""
        moved: dict[str, Any] = {
            field.name: value.to(device)
            for field in dataclasses.fields(self)
            if isinstance(value := getattr(self, field.name), torch.Tensor)
        }
        h, c = self.initial_state
        return dataclasses.replace(self, **moved, initial_state=LSTMState(h.to(device), c.to(device)))

    def sequences(self, length: int, states: LSTMState) -> Segment:
        """The segment cut into sequences of ``length`` acting steps, each laid out as an environment
        of its own: (``length``, K·B) with K = T / ``length``, sequence k·B + b holding environment
        b's steps [k·length, (k+1)·length) and the observation after them. ``states`` (K·B, H) are
        the LSTM states the sequences start from, in that order (:func:`sequence_start_states`).

        What a recurrent learner trains on when it unrolls short sequences from stored states
        (truncated backpropagation through time; R2D2's "stored state", Kapturowski et al. 2019)
        instead of whole rollouts: K times fewer steps to backpropagate one after the other."""
        if length < 1 or self.steps % length:
            raise ValueError(f"sequence length must divide the segment's {self.steps} steps, got {length}")
        needed = self.steps // length * self.batch
        if states.h.shape[0] != needed:
            raise ValueError(f"{needed} sequence start states needed, got {states.h.shape[0]}")
        cut: dict[str, Any] = {}
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if isinstance(value, torch.Tensor):
                cut[field.name] = in_sequences(value, length, self.steps)
        return dataclasses.replace(self, **cut, initial_state=states)


def in_sequences(value: torch.Tensor, length: int, steps: int) -> torch.Tensor:
    """A (T or T+1, B, …) tensor of a ``steps``-step segment as (``length`` or ``length``+1, K·B, …)
    sequences, as :meth:`Segment.sequences` lays them out: a tensor of T+1 steps (the network's
    inputs) keeps, for each sequence, the step after its last."""
    extra = value.shape[0] - steps
    pieces = [value[k * length : (k + 1) * length + extra] for k in range(steps // length)]
    return torch.stack(pieces, dim=1).flatten(1, 2)


def unroll(net: RecurrentActorCritic, segment: Segment) -> Unrolled:
    """``net`` unrolled over ``segment`` (T+1 steps) from the LSTM state the segment started with,
    with gradients: the policy and values a learner's loss is taken of, exactly those of the policy
    that acted if ``net`` holds the acting weights."""
    return net.unroll_features(
        segment.obs,
        segment.prev_action,
        segment.prev_reward,
        segment.tilt,
        segment.initial_state,
        segment.starts,
        privileged=segment.privileged,
    )


@torch.no_grad()
def sequence_start_states(net: RecurrentActorCritic, segment: Segment, length: int) -> tuple[torch.Tensor, LSTMState]:
    """``net``'s values over the segment's T+1 steps, unrolled from the state it started with, and
    the LSTM states that its sequences of ``length`` steps start from, stacked as
    :meth:`Segment.sequences` lays them out (K·B, H)."""
    if length < 1 or segment.steps % length:
        raise ValueError(f"sequence length must divide the segment's {segment.steps} steps, got {length}")
    state, values, starts = segment.initial_state, [], []
    for begin in range(0, segment.steps + 1, length):
        end = min(begin + length, segment.steps + 1)  # the last piece: the observation after the last step
        if begin < segment.steps:
            starts.append(state)
        tilt = segment.tilt[begin:end] if segment.tilt is not None else None
        privileged = segment.privileged[begin:end] if segment.privileged is not None else None
        out = net.unroll_features(
            segment.obs[begin:end],
            segment.prev_action[begin:end],
            segment.prev_reward[begin:end],
            tilt,
            state,
            segment.starts[begin:end],
            privileged=privileged,
        )
        values.append(out.values)
        state = out.state
    stacked = LSTMState(torch.cat([s.h for s in starts]), torch.cat([s.c for s in starts]))
    return torch.cat(values), stacked


def training_env(
    num_envs: int,
    *,
    task: str,
    obs: str,
    time_limit: int,
    privileged: bool,
    action_type: str = "discrete",
    **options: Any,
) -> PuzzleVectorEnv:
    """The batched env a learner's :class:`RolloutCollector` steps, of ``task``'s puzzle (the maze's
    or the labyrinth's: :mod:`bimgame.envs.puzzles`): one MuJoCo thread per process (the learners'
    processes share the cores), and same-step autoreset, whose ``final_obs`` the collector's
    time-limit bootstrap reads; its actions are the network's ``action_type``. ``options`` go to the
    env (the maze's start sampler, randomisation: on the labyrinth they must be None)."""
    return puzzle(task).vector_env(
        num_envs,
        obs_mode=obs,
        nthread=1,
        max_episode_steps=time_limit,
        autoreset_mode="same_step",
        state_info=privileged,
        action_type=action_type,
        **options,
    )


def advantages_and_targets(
    rewards: torch.Tensor,
    ends: torch.Tensor,
    values: torch.Tensor,
    bootstrap: torch.Tensor,
    gamma: float,
    gae_lambda: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalised advantage estimates (T, B) and value targets (advantage + V) of a segment.

    ``values`` (T, B) and ``bootstrap`` (B,) (V of the observation after the last step) must carry
    no gradient; ``ends`` cuts the recursion where an episode ended. λ = 1 gives A3C's n-step
    returns, λ < 1 GAE (Schulman et al. 2016)."""
    advantages = torch.zeros_like(rewards)
    next_value, running = bootstrap, torch.zeros_like(bootstrap)
    ends_f = ends.float()
    for t in reversed(range(rewards.shape[0])):
        not_end = 1.0 - ends_f[t]
        delta = rewards[t] + gamma * next_value * not_end - values[t]
        running = delta + gamma * gae_lambda * not_end * running
        advantages[t] = running
        next_value = values[t]
    return advantages, advantages + values


@dataclasses.dataclass(frozen=True)
class FinishedEpisode:
    """One finished training episode, as the learning curves count it."""

    start_step: int
    """The run's step count when the segment in which the episode started began (counting episodes
    by their start keeps early success rates unbiased: short successful episodes finish first)."""
    end_step: int
    """The run's step count when the episode ended."""
    episode_return: float
    """The task's own reward summed over the episode (not a shaped one)."""
    length: int
    success: bool
    """The episode reached the task's goal (:func:`~bimgame.learn.actor.episode_successes`): not its
    time limit, nor a labyrinth's hole or leaving its path."""
    true_start: bool
    """It started where the task starts (not a start curriculum's start)."""

    def row(self) -> dict[str, Any]:
        """The episode as a row of the run's ``episodes`` log."""
        return {
            "start_step": self.start_step,
            "end_step": self.end_step,
            "return": self.episode_return,
            "length": self.length,
            "success": self.success,
            "true_start": self.true_start,
        }


def _check_action_type(env: Any, net: RecurrentActorCritic) -> None:
    """Refuse an env whose actions are not the network's kind (``training_env(action_type=...)``)."""
    template = getattr(env, "template", None)  # the vector env's single env (either puzzle's)
    env_type, net_type = getattr(template, "action_type", None), net.config.action_type
    if env_type is not None and env_type != net_type:
        raise ValueError(
            f"the env takes {env_type} actions but the network acts with {net_type} ones; "
            f"build the env with action_type={net_type!r} (training_env(..., action_type=...))"
        )


class NonFiniteReward(ValueError):
    """The env returned a NaN or infinite reward: the segment cannot be learned from."""

    def __init__(self, step: int, rewards: np.ndarray):
        super().__init__(f"non-finite reward from the env at step {step}: {rewards.tolist()}")
        self.step = step
        self.rewards = rewards


class StartCurriculum(Protocol):
    """What the collector needs of a start curriculum (:mod:`bimgame.learn.starts`)."""

    def record(self, tag: int, success: bool) -> None: ...

    def status(self) -> dict[str, float]: ...


class RolloutCollector:
    """Steps ``env`` (a batched vector env, possibly wrapped) with ``actor`` and returns segments.

    ``base_env`` is the unwrapped env of :func:`training_env` (its board's ``max_tilt``, as ``maze``,
    and its start tags); ``curriculum`` the start curriculum it samples starts from, told each episode's
    outcome; ``on_episode`` receives every finished episode as it ends; ``global_step`` reads the
    run's step count (shared by all workers) for the episodes' end steps. ``tilt_input`` and
    ``privileged`` say whether the segments keep the tilt and the simulator's state."""

    def __init__(
        self,
        env: Any,
        base_env: Any,
        actor: RecurrentActor,
        *,
        gamma: float,
        tilt_input: bool = True,
        privileged: bool = False,
        curriculum: StartCurriculum | None = None,
        on_episode: Callable[[FinishedEpisode], None] = lambda episode: None,
        global_step: Callable[[], int] = lambda: 0,
    ):
        self.env, self.base_env, self.actor = env, base_env, actor
        _check_action_type(base_env, actor.net)
        self.gamma = gamma
        self.keeps_tilt, self.privileged = tilt_input, privileged
        self.curriculum = curriculum
        self.on_episode, self.global_step = on_episode, global_step
        self.max_tilt = base_env.maze.max_tilt
        batch = actor.num_envs
        self.episode_return = np.zeros(batch)
        self.episode_length = np.zeros(batch, dtype=np.int64)
        self.episode_start = np.zeros(batch, dtype=np.int64)
        self.obs: Any = None
        self.info: dict[str, Any] = {}

    def reset(self, seed: int, step: int) -> None:
        """Start every environment's first episode (at the run's step ``step``)."""
        self.obs, self.info = self.env.reset(seed=seed)
        self.episode_start[:] = step

    @torch.no_grad()
    def collect(self, n_steps: int, step_at_start: int) -> Segment:
        """Act for ``n_steps`` steps and return them as a segment (no gradients: a learner unrolls the
        network over it again). Raises :class:`NonFiniteReward` (after booking the episodes that ended
        before it) when the env returns a non-finite reward."""
        actor = self.actor
        initial_state = actor.state
        columns: dict[str, list[torch.Tensor]] = {
            name: []
            for name in (
                "obs",
                "prev_action",
                "prev_reward",
                "tilt",
                "starts",
                "privileged",
                "actions",
                "rewards",
                "log_probs",
                "values",
            )
        }
        tilt = tilt_input(self.info, self.max_tilt)
        for _ in range(n_steps):
            obs = torch.as_tensor(self.obs)
            self._record_inputs(columns, obs, tilt)
            actions, output, values = actor.act(obs, tilt)
            columns["log_probs"].append(actor.distribution(output).log_prob(actions))
            columns["values"].append(values)
            rewards = self._step(actions, step_at_start)
            columns["actions"].append(actions)
            columns["rewards"].append(rewards)
            tilt = tilt_input(self.info, self.max_tilt)
        self._record_inputs(columns, torch.as_tensor(self.obs), tilt)
        stacked = {name: torch.stack(values) for name, values in columns.items() if values}
        starts = stacked["starts"]
        return Segment(
            obs=stacked["obs"],
            prev_action=stacked["prev_action"],
            prev_reward=stacked["prev_reward"],
            tilt=stacked.get("tilt"),
            starts=starts,
            actions=stacked["actions"],
            rewards=stacked["rewards"],
            # Which episodes ended at each step: what the actor marks as starting the step after.
            ends=starts[1:],
            initial_state=initial_state,
            privileged=stacked.get("privileged"),
            log_probs=stacked["log_probs"],
            values=stacked["values"],
            step_at_start=step_at_start,
        )

    def close(self) -> None:
        """Close the environments (the collector is not used afterwards)."""
        self.env.close()

    def curriculum_status(self) -> dict[str, float]:
        """The start curriculum's status (empty without one): what a learner's update log adds."""
        return self.curriculum.status() if self.curriculum is not None else {}

    def _record_inputs(self, columns: dict[str, list[torch.Tensor]], obs: torch.Tensor, tilt: torch.Tensor) -> None:
        """Append one step's network inputs (and, where the segment keeps it, the privileged state of
        the same step)."""
        actor = self.actor
        columns["obs"].append(obs)
        columns["prev_action"].append(actor.prev_action)
        columns["prev_reward"].append(actor.prev_reward)
        if self.keeps_tilt:
            columns["tilt"].append(tilt)
        columns["starts"].append(actor.starts)
        if self.privileged:
            columns["privileged"].append(torch.as_tensor(self.info["state"]))

    def _step(self, actions: torch.Tensor, step_at_start: int) -> torch.Tensor:
        """Step the env with ``actions``, book the episodes that ended; returns the rewards to learn from."""
        start_tags = self.base_env.start_tags.copy() if self.curriculum is not None else None
        # (the step resets finished envs and their tags: read them before)
        self.obs, reward, terminated, truncated, self.info = self.env.step(self.actor.executed(actions).numpy())
        reward = np.asarray(reward, dtype=np.float64)
        if not np.all(np.isfinite(reward)):
            raise NonFiniteReward(int(self.global_step()), reward)
        done = terminated | truncated
        rewards = torch.as_tensor(reward, dtype=torch.float32)
        cut = truncated & ~terminated
        if cut.any():
            rewards = rewards + self.gamma * self._final_values(actions, reward, cut)
        # Learning curves show the task's own reward, also when a wrapper shapes it.
        self.episode_return += np.asarray(self.info.get("task_reward", reward), dtype=np.float64)
        self.episode_length += 1
        if done.any():  # (most steps end no episode)
            successes = episode_successes(self.info, terminated)
            for i in np.flatnonzero(done):
                self._book(int(i), bool(successes[i]), start_tags)
        self.episode_return[done] = 0.0
        self.episode_length[done] = 0
        self.episode_start[done] = step_at_start
        self.actor.observe(actions, reward, done)
        return rewards

    def _book(self, i: int, success: bool, start_tags: np.ndarray | None) -> None:
        tag = TRUE_START
        if self.curriculum is not None and start_tags is not None:  # (tags are read only with a curriculum)
            tag = int(start_tags[i])
            self.curriculum.record(tag, success)
        self.on_episode(
            FinishedEpisode(
                start_step=int(self.episode_start[i]),
                end_step=int(self.global_step()),
                episode_return=float(self.episode_return[i]),
                length=int(self.episode_length[i]),
                success=success,
                true_start=tag == TRUE_START,
            )
        )

    def _final_values(self, actions: torch.Tensor, reward: np.ndarray, cut: np.ndarray) -> torch.Tensor:
        """V of the last observation of time-limited episodes (0 elsewhere), from the state after the
        step, without changing the actor; an asymmetric critic also reads the final state."""
        final_info = self.info["final_info"]
        final_tilt = tilt_input(final_info, self.max_tilt)
        final_state = torch.as_tensor(final_info["state"]) if self.privileged else None
        with torch.no_grad():
            _, values, _ = self.actor.net.step(
                torch.as_tensor(self.info["final_obs"]),
                self.actor.executed(actions),
                torch.as_tensor(reward, dtype=torch.float32),
                final_tilt,
                self.actor.state,
                privileged=final_state,
            )
        # Envs that were not cut hold NaN with an asymmetric critic's partial state; only cut ones count.
        return torch.where(torch.as_tensor(cut), values, torch.zeros_like(values))
