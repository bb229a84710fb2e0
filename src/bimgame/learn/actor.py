"""Acting with a recurrent actor-critic on a batch of environments, and evaluating it.

:class:`RecurrentActor` keeps what the network needs between steps — previous action, previous
reward, LSTM state — and resets it at episode boundaries. The A3C workers, the evaluator,
``bimgame evaluate`` and the learners from trajectories all act through it, so the inputs the
network sees never differ between training and testing. What depends on the network's kind of
action (discrete or continuous) is its :class:`~bimgame.learn.policy_heads.ActionHead`'s: the
actor draws from :meth:`~bimgame.learn.nets.RecurrentActorCritic.distribution` and sends the env
:meth:`RecurrentActor.executed` actions (a Gaussian's samples clipped to [-1, 1]).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from bimgame.envs.puzzles import puzzle
from bimgame.learn.nets import LSTMState, RecurrentActorCritic
from bimgame.learn.policy_heads import ActionDistribution
from bimgame.sim.maze import MazeSpec

__all__ = [
    "RecurrentActor",
    "EvalResult",
    "evaluate_network",
    "tilt_input",
    "env_action",
    "episode_successes",
    "finished_info",
]


def tilt_input(info: dict[str, Any], max_tilt: float) -> torch.Tensor:
    """The board tilt from an env info dict, in units of the maximum tilt, as (B, 2) float32."""
    return torch.as_tensor(np.asarray(info["tilt"], dtype=np.float32) / np.float32(max_tilt))


def env_action(action: torch.Tensor) -> Any:
    """One environment's action, a row of :meth:`RecurrentActor.executed`, as the env takes it: a
    float array (continuous) or an int (discrete)."""
    return action.numpy().copy() if action.is_floating_point() else int(action)


def episode_successes(info: dict[str, Any], terminated: np.ndarray) -> np.ndarray:
    """(B,) bool: whether each episode that ended at this step reached its goal (read where ``done``):
    the env's own ``info["is_success"]`` (Gymnasium's key; both puzzles report it) of the finished
    step — ``final_info`` under same-step autoreset, where the info beside it is the next episode's —
    and a termination. A labyrinth episode also terminates by failing (a hole, leaving the path); a
    maze episode terminates only at its goal. An env that reports no ``is_success`` counts every
    termination as a success."""
    source = finished_info(info, "is_success")
    if "is_success" not in source:
        return np.asarray(terminated, dtype=bool)
    return np.asarray(source["is_success"], dtype=bool) & np.asarray(terminated, dtype=bool)


def finished_info(info: dict[str, Any], key: str) -> dict[str, Any]:
    """The info of the step that finished the episodes: ``final_info`` under same-step autoreset when
    it holds ``key`` (the info beside it is then the next episode's first), else ``info`` itself."""
    final = info.get("final_info")
    return final if isinstance(final, dict) and key in final else info


class RecurrentActor:
    """Acts for ``num_envs`` environments with one batched forward pass per step; sampled actions
    come from π at ``temperature`` (1: the network's own π; a learner's behaviour policy may be
    sharper), greedy ones are the most likely action.

    Call :meth:`act` with the current observations, step the env, then :meth:`observe` the result
    (rewards and which episodes ended) before the next :meth:`act`."""

    def __init__(
        self,
        net: RecurrentActorCritic,
        num_envs: int,
        *,
        generator: torch.Generator | None = None,
        greedy: bool = False,
        temperature: float = 1.0,
    ):
        self.net = net
        self.num_envs = num_envs
        self.generator = generator
        self.greedy = greedy
        self.temperature = temperature
        self.reset()

    def reset(self) -> None:
        """Every environment starts a new episode."""
        self.prev_action = self.net.action_head.no_action(self.num_envs)
        self.prev_reward = torch.zeros(self.num_envs)
        self.state: LSTMState = self.net.initial_state(self.num_envs)
        self.starts = torch.ones(self.num_envs, dtype=torch.bool)

    @torch.no_grad()
    def act(
        self,
        obs: np.ndarray | torch.Tensor,
        tilt: torch.Tensor | None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Actions (B,) (continuous: (B, 2), before clipping), the policy's output (B, A) (logits, or
        the Gaussian's means; :meth:`~bimgame.learn.nets.RecurrentActorCritic.distribution`) and
        values (B,) for the current observations; advances the LSTM state. Greedy: the most likely
        action (the Gaussian's mean); else a sample, every random number from the actor's generator."""
        obs_t = torch.as_tensor(obs)
        output, values, self.state = self.net.step(obs_t, self.prev_action, self.prev_reward, tilt, self.state)
        policy = self.distribution(output)
        actions = policy.greedy() if self.greedy else policy.sample(self.generator)
        return actions, output, values

    def distribution(self, output: torch.Tensor) -> ActionDistribution:
        """The policy the actor samples from: the network's at the actor's ``temperature``."""
        return self.net.distribution(output, self.temperature)

    def executed(self, actions: torch.Tensor) -> torch.Tensor:
        """What the env executes of :meth:`act`'s actions: the same discrete actions, or continuous
        ones clipped to [-1, 1]. Send ``executed(actions).numpy()`` to the env."""
        return self.net.action_head.executed(actions)

    def observe(self, actions: torch.Tensor, rewards: np.ndarray, done: np.ndarray) -> None:
        """Record the step's actions (as :meth:`act` gave them, or as executed) and rewards;
        environments whose episode ended start afresh."""
        done_t = torch.as_tensor(done, dtype=torch.bool)
        executed = self.executed(actions)
        ended = done_t.reshape(done_t.shape + (1,) * (executed.dim() - 1))
        self.prev_action = torch.where(ended, self.net.action_head.no_action(len(done_t)).to(executed.dtype), executed)
        self.prev_reward = torch.where(done_t, torch.zeros(()), torch.as_tensor(rewards, dtype=torch.float32))
        if done_t.any():
            keep = (~done_t).float().unsqueeze(-1)
            self.state = LSTMState(self.state.h * keep, self.state.c * keep)
        self.starts = done_t


@dataclasses.dataclass
class EvalResult:
    """First episode of each evaluation environment."""

    successes: list[bool]
    lengths: list[int]
    returns: list[float]
    frames: list[np.ndarray] = dataclasses.field(default_factory=list)
    holes: list[bool] = dataclasses.field(default_factory=list)
    """Per episode, whether it ended with the marble over a hole (the labyrinth's ``info["over_hole"]``
    at its last step); empty when the env reports no holes (the circular maze)."""

    @property
    def success_rate(self) -> float:
        return float(np.mean(self.successes)) if self.successes else float("nan")

    @property
    def mean_length(self) -> float:
        return float(np.mean(self.lengths)) if self.lengths else float("nan")

    @property
    def mean_return(self) -> float:
        return float(np.mean(self.returns)) if self.returns else float("nan")

    def summary(self) -> dict[str, float]:
        return {
            "success_rate": self.success_rate,
            "mean_length": self.mean_length,
            "mean_return": self.mean_return,
            "episodes": len(self.successes),
        }


@torch.no_grad()
def evaluate_network(
    net: RecurrentActorCritic,
    *,
    task: str,
    obs_mode: str,
    episodes: int,
    seed: int,
    greedy: bool = True,
    maze: MazeSpec | None = None,
    max_episode_steps: int | None = None,
    record: bool = False,
    render_size: int = 240,
    randomize: Any = None,
    mazes: dict[str, Any] | None = None,
    maze_numbers: Sequence[int] | None = None,
) -> EvalResult:
    """Run one episode in each of ``episodes`` environments (batched) with the true task reward.

    Start positions come from ``seed`` (the same seed gives the same starts, so evaluations along a
    run are comparable); sampled actions draw from a generator seeded with ``seed`` too.
    ``record`` keeps RGB frames of the first environment's episode. ``randomize`` (a
    :class:`~bimgame.envs.randomization.Randomization`) evaluates on domain-randomised boards. The
    env has the network's kind of action (``net.config.action_type``). ``mazes``: env arguments of
    many mazes (``num_mazes``, ``start_maze``, ``maze_split``; see :class:`~bimgame.envs.env.BallInMazeEnv`)
    or the labyrinth's ``surroundings``, ``motion`` and ``off_path_rule``;
    each episode's maze drawn from ``seed`` too, or episode ``k`` on maze ``maze_numbers[k]`` of that set.
    ``task`` may be the labyrinth's (:mod:`bimgame.envs.puzzles`; the maze's options must then be None);
    an episode succeeds when it reaches the goal (:func:`episode_successes`), not when it falls."""
    kwargs: dict[str, Any] = {"randomize": randomize}
    if maze is not None:
        kwargs["maze"] = maze
    kwargs.update(mazes or {})
    if record:
        kwargs.update(render_mode="rgb_array", render_size=render_size)
    env = puzzle(task).vector_env(
        episodes,
        obs_mode=obs_mode,
        action_type=net.config.action_type,
        max_episode_steps=max_episode_steps or None,
        nthread=1,
        autoreset_mode="same_step",
        **kwargs,
    )
    generator = torch.Generator().manual_seed(int(seed))
    actor = RecurrentActor(net, episodes, generator=generator, greedy=greedy)
    obs, info = env.reset(seed=int(seed), options=None if maze_numbers is None else {"maze": list(maze_numbers)})
    max_tilt = env.maze.max_tilt
    finished = np.zeros(episodes, dtype=bool)
    result = EvalResult([False] * episodes, [0] * episodes, [0.0] * episodes)
    returns = np.zeros(episodes)
    lengths = np.zeros(episodes, dtype=np.int64)
    try:
        while not finished.all():
            if record and not finished[0]:
                frames = env.render()
                assert frames is not None  # render_mode="rgb_array" renders every environment
                result.frames.append(frames[0])
            actions, _, _ = actor.act(obs, tilt_input(info, max_tilt))
            obs, reward, terminated, truncated, info = env.step(actor.executed(actions).numpy())
            returns += reward
            lengths += 1
            done = terminated | truncated
            successes = episode_successes(info, terminated)
            holes = finished_info(info, "over_hole").get("over_hole")
            if holes is not None and not result.holes:
                result.holes = [False] * episodes
            for i in np.flatnonzero(done & ~finished):
                result.successes[i] = bool(successes[i])
                result.lengths[i] = int(lengths[i])
                result.returns[i] = float(returns[i])
                if holes is not None:
                    result.holes[i] = bool(holes[i])
            finished |= done
            returns[done] = 0.0
            lengths[done] = 0
            actor.observe(actions, reward, done)
    finally:
        env.close()
    return result
