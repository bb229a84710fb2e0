"""The paper's tasks: rewards and termination from the marble's channel transitions.

- ``FULL``: +1 for every wall crossed towards the centre, -1 for every wall crossed outwards; the
  episode ends when the marble reaches the centre.
- ``STG1`` … ``STG4`` ("steps to go"): reward 0 everywhere, +1 and the episode ends when the marble
  passes through the k-th wall counted from the outside (STG1: out of the outermost channel,
  STG4 on MERL's maze: into the centre).

With several marbles, rewards add up over marbles and an episode ends when every marble has done
what the task asks (reached the centre; passed the k-th wall).

Everything is vectorised over a leading batch dimension so that the single env, the batched
vector env and the expert's rollouts share one implementation.
"""

from __future__ import annotations

import dataclasses
import enum

import numpy as np

from bimgame.sim.maze import MazeSpec

__all__ = [
    "Task",
    "TaskState",
    "parse_task",
    "task_step",
    "task_step_one",
    "initial_task_state",
    "MAX_EPISODE_STEPS",
    "rewards_from_channels",
    "task_setting",
]


class Task(str, enum.Enum):
    FULL = "FULL"
    STG1 = "STG1"
    STG2 = "STG2"
    STG3 = "STG3"
    STG4 = "STG4"

    @property
    def steps_to_go(self) -> int | None:
        """k for STGk, None for FULL."""
        return None if self is Task.FULL else int(self.value[3:])

    def goal_channel(self, spec: MazeSpec) -> int:
        """The channel the marble must reach: 0 (the centre) for FULL, the channel inside the
        k-th wall from the outside for STGk."""
        return 0 if self.steps_to_go is None else spec.outermost_channel - self.steps_to_go

    def walls_to_pass(self, spec: MazeSpec) -> int:
        """How many walls an episode of this task passes: k for STGk, every wall of ``spec`` for FULL.
        A dataset of a task labels every task that passes no more walls (see ``relabel``)."""
        return len(spec.walls) if self.steps_to_go is None else self.steps_to_go

    @property
    def time_limit(self) -> int:
        """The task's time limit in action steps (:data:`MAX_EPISODE_STEPS`)."""
        return MAX_EPISODE_STEPS[self]


#: Time limits (action steps at 30 Hz) per task. A uniformly random policy solves STG1 16% of the
#: time within 300 steps but 82% within 3000, solves STG2 2/50 and FULL 0/50 within 3000, while the
#: MPC expert solves FULL in a median of 145 steps (README, "The MPC expert and its datasets"). These
#: limits give a competent controller ample time and keep luck from solving the task.
MAX_EPISODE_STEPS = {Task.STG1: 300, Task.STG2: 500, Task.STG3: 750, Task.STG4: 1000, Task.FULL: 1000}


def parse_task(task: str | Task, spec: MazeSpec | None = None) -> Task:
    """A :class:`Task` from its name, checked against the maze (STGk needs at least k walls)."""
    if isinstance(task, Task):
        parsed = task
    else:
        try:
            parsed = Task(str(task).upper())
        except ValueError:
            allowed = ", ".join(t.value for t in Task)
            raise ValueError(f"unknown task {task!r}; allowed: {allowed}") from None
    if spec is not None and parsed.steps_to_go is not None and parsed.steps_to_go > len(spec.walls):
        raise ValueError(
            f"task {parsed.value} needs a maze with at least {parsed.steps_to_go} walls; "
            f"this maze has {len(spec.walls)}"
        )
    return parsed


def task_setting(owner: str, task: str | Task) -> str:
    """The name of ``task`` (``FULL``, ``STG1`` …) as a settings class stores it; a ``ValueError``
    names the setting (``owner.task``) and the allowed tasks."""
    try:
        return parse_task(task).value
    except ValueError as error:
        raise ValueError(f"{owner}.task: {error}") from None


@dataclasses.dataclass
class TaskState:
    """Per-episode task bookkeeping, batched: ``channel`` and ``reached`` are (B, n_marbles)."""

    channel: np.ndarray
    reached: np.ndarray

    def copy(self) -> TaskState:
        return TaskState(self.channel.copy(), self.reached.copy())


def initial_task_state(spec: MazeSpec, marble_xy: np.ndarray, task: Task | None = None) -> TaskState:
    """Task state of marbles at board-frame positions ``marble_xy`` (B, n, 2).

    With ``task``, a marble that starts at the task's goal already (FULL: in the centre; STGk: past
    the k-th wall) counts as having reached it, so no step rewards it for being there (without
    ``task``, none has: an STGk step would pay +1 for a marble that started past the goal)."""
    channel = spec.channel_of(marble_xy[..., 0], marble_xy[..., 1])
    if task is None:
        return TaskState(channel=channel, reached=np.zeros(channel.shape, dtype=bool))
    return TaskState(channel=channel, reached=channel <= task.goal_channel(spec))


def task_step(
    task: Task,
    spec: MazeSpec,
    state: TaskState,
    marble_xy: np.ndarray,
) -> tuple[TaskState, np.ndarray, np.ndarray, np.ndarray]:
    """Advance the task by one step of the marbles to ``marble_xy`` (B, n, 2).

    Returns ``(new_state, reward (B,), terminated (B,), crossings (B, n))`` where ``crossings``
    is +1 per marble that passed a wall inwards this step, -1 outwards, 0 otherwise (it can exceed
    1 in magnitude only if a marble crossed several walls in one step).
    """
    channel = spec.update_channel(state.channel, marble_xy[..., 0], marble_xy[..., 1])
    crossings = state.channel - channel
    if task is Task.FULL:
        reward = crossings.sum(axis=-1).astype(np.float64)
        reached = channel == 0
        terminated = reached.all(axis=-1)
    else:
        goal_channel = task.goal_channel(spec)
        newly = (channel <= goal_channel) & ~state.reached
        reached = state.reached | newly
        reward = newly.sum(axis=-1).astype(np.float64)
        terminated = reached.all(axis=-1)
    return TaskState(channel=channel, reached=reached), reward, terminated, crossings


def task_step_one(
    task: Task, spec: MazeSpec, channels: list[int], reached: list[bool], radii: list[float]
) -> tuple[float, bool, list[int]]:
    """Scalar :func:`task_step` for one environment, updating ``channels`` and ``reached`` in
    place from the marbles' radii. Returns ``(reward, terminated, crossings)``.

    The single env calls this every step: plain Python on a handful of numbers is several times
    faster than numpy on (1, n) arrays (tests check both agree)."""
    crossings = []
    reward = 0.0
    goal_channel = None if task is Task.FULL else task.goal_channel(spec)
    for i, r in enumerate(radii):
        new = spec.next_channel(channels[i], r)
        crossings.append(channels[i] - new)
        channels[i] = new
        if goal_channel is None:
            reward += crossings[-1]
            reached[i] = new == 0
        elif not reached[i] and new <= goal_channel:
            reached[i] = True
            reward += 1.0
    return float(reward), all(reached), crossings


def rewards_from_channels(task: Task, spec: MazeSpec, channels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rewards and goal flags of a recorded episode under ``task``, from each marble's channel
    before and after every step (``channels``: (T+1, n)): ``(rewards (T,), done (T,))``, ``done[t]``
    saying whether the goal was reached by step t. The same rules as :func:`task_step`, applied to a
    whole recorded episode at once (how a FULL episode is relabelled for STGk)."""
    channels = np.asarray(channels)
    after = channels[1:]
    if task is Task.FULL:
        rewards = (channels[:-1] - after).sum(axis=-1).astype(np.float64)
        return rewards, (after == 0).all(axis=-1)
    reached = np.logical_or.accumulate(after <= task.goal_channel(spec), axis=0)
    before = np.vstack([np.zeros_like(reached[:1]), reached[:-1]])
    return (reached & ~before).sum(axis=-1).astype(np.float64), np.asarray(reached.all(axis=-1))
