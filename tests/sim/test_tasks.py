"""Task rules: the batched and the scalar implementation agree, and follow the rules of the README's
"Using the environments" (and of :mod:`bimgame.sim.tasks`)."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.sim.maze import MazeSpec
from bimgame.sim.tasks import Task, TaskState, initial_task_state, parse_task, task_step, task_step_one

SPEC = MazeSpec.merl()


def _radii_for_channels(channels: list[int]) -> list[float]:
    return [SPEC.channel_centre_radius(c) if c else 0.0 for c in channels]


@pytest.mark.parametrize("task", list(Task))
def test_batched_and_scalar_task_steps_agree_on_random_walks(task):
    rng = np.random.default_rng(hash(task.value) % 2 ** 32)
    batch, n, steps = 6, 2, 80
    state = TaskState(np.full((batch, n), 4), np.zeros((batch, n), dtype=bool))
    scalar = [([4] * n, [False] * n) for _ in range(batch)]
    radius = np.full((batch, n), SPEC.channel_centre_radius(4))
    for _ in range(steps):
        # Radial random walk, including points inside walls (the hysteresis band).
        radius = np.clip(radius + rng.normal(0, 0.006, size=radius.shape), 0.0, 0.0904)
        xy = np.stack([radius, np.zeros_like(radius)], axis=-1)
        state, reward, terminated, crossings = task_step(task, SPEC, state, xy)
        for b in range(batch):
            r, t, c = task_step_one(task, SPEC, scalar[b][0], scalar[b][1], radius[b].tolist())
            assert r == reward[b] and t == terminated[b] and c == crossings[b].tolist()
            assert scalar[b][0] == state.channel[b].tolist()


def test_full_rewards_net_inward_crossings():
    state = TaskState(np.array([[4]]), np.array([[False]]))
    total = 0.0
    for channel in [4, 3, 3, 4, 3, 2, 1, 0]:
        xy = np.array([[[_radii_for_channels([channel])[0], 0.0]]])
        state, reward, terminated, _ = task_step(Task.FULL, SPEC, state, xy)
        total += reward[0]
    assert total == 4.0 and terminated[0]


def test_stg_rewards_once_at_the_kth_wall():
    for k in (1, 2, 3, 4):
        state = TaskState(np.array([[4]]), np.array([[False]]))
        rewards = []
        for channel in [4, 3, 4, 3, 2, 1, 0]:
            xy = np.array([[[_radii_for_channels([channel])[0], 0.0]]])
            state, reward, terminated, _ = task_step(Task(f"STG{k}"), SPEC, state, xy)
            rewards.append(reward[0])
            if terminated[0]:
                break
        assert sum(rewards) == 1.0 and rewards[-1] == 1.0
        assert state.channel[0, 0] == 4 - k


def test_two_marbles_end_only_when_both_arrive():
    state = TaskState(np.array([[1, 1]]), np.zeros((1, 2), dtype=bool))
    xy = np.array([[[0.0, 0.0], [SPEC.channel_centre_radius(1), 0.0]]])
    state, reward, terminated, _ = task_step(Task.FULL, SPEC, state, xy)
    assert reward[0] == 1.0 and not terminated[0]
    xy = np.zeros((1, 2, 2))
    state, reward, terminated, _ = task_step(Task.FULL, SPEC, state, xy)
    assert reward[0] == 1.0 and terminated[0]


def test_parse_task_errors():
    assert parse_task("stg2") is Task.STG2
    with pytest.raises(ValueError, match="unknown task 'STG5'; allowed: FULL, STG1, STG2, STG3, STG4"):
        parse_task("STG5")
    small = MazeSpec(walls=SPEC.walls[:1], rim_radius=0.04)
    with pytest.raises(ValueError, match="STG2 needs a maze with at least 2 walls"):
        parse_task("STG2", small)


@pytest.mark.parametrize("task", list(Task))
def test_a_marble_starting_at_its_goal_earns_nothing(task):
    """A marble placed past the task's goal counts as arrived: no step pays for it (STGk used to pay
    +1 at the first step, for no action)."""
    goal = task.goal_channel(SPEC)
    xy = np.array([[[SPEC.channel_centre_radius(goal), 0.0], [SPEC.channel_centre_radius(4), 0.0]]])
    state = initial_task_state(SPEC, xy, task)
    assert state.reached.tolist() == [[True, False]]
    after, reward, terminated, _ = task_step(task, SPEC, state, xy)
    assert reward[0] == 0.0 and not terminated[0]
    channels, reached = state.channel[0].tolist(), state.reached[0].tolist()
    assert task_step_one(task, SPEC, channels, reached, [float(np.hypot(*p)) for p in xy[0]]) == (0.0, False, [0, 0])
    # Without the task nobody has arrived (the old behaviour, kept for callers that do not pass it).
    assert not initial_task_state(SPEC, xy).reached.any()
