"""The episode record and its relabelling for other tasks from the recorded channels."""

import dataclasses

import numpy as np
import pytest

from bimgame.expert.episode import Episode, relabel
from bimgame.sim.tasks import Task

GAMMA = 0.9


def _episode(channels) -> Episode:
    """A hand-made episode whose marbles visit ``channels`` (T+1 rows)."""
    channels = np.asarray(channels, dtype=np.int64).reshape(len(channels), -1)
    steps = len(channels) - 1
    rng = np.random.default_rng(steps)
    actions = rng.integers(5, size=steps)
    return Episode.from_steps(obs=rng.normal(size=(steps, 7)).astype(np.float32), actions=actions,
                              rewards=np.zeros(steps, np.float32),
                              tilt=rng.normal(scale=0.01, size=(steps, 2)).astype(np.float32), gamma=GAMMA,
                              channels=channels, id=7)


def _discounted(rewards, gamma) -> np.ndarray:
    """G_t = Σ_k γ^k r_{t+k}, written out."""
    rewards = np.asarray(rewards, dtype=np.float64)
    return np.array([sum(gamma ** k * r for k, r in enumerate(rewards[t:])) for t in range(len(rewards))])


def _assert_relabelled(out: Episode, episode: Episode, rewards, terminated: bool) -> None:
    end = len(rewards)
    np.testing.assert_array_equal(out.rewards, rewards)
    np.testing.assert_array_equal(out.prev_rewards, np.concatenate([[0.0], rewards[:-1]]))
    np.testing.assert_allclose(out.returns, _discounted(rewards, GAMMA), rtol=1e-6)
    for key in ("obs", "actions", "prev_actions", "tilt"):
        np.testing.assert_array_equal(getattr(out, key), getattr(episode, key)[:end])
    np.testing.assert_array_equal(out.channels, episode.channels[:end + 1])
    assert (out.terminated, out.truncated, out.id) == (terminated, not terminated, episode.id)


def test_from_steps_derives_the_inputs_and_targets_and_files_round_trip():
    episode = Episode.from_steps(obs=np.arange(6, dtype=np.float32).reshape(3, 2), actions=[1, 2, 3],
                                 rewards=[0.0, 0.0, 1.0], tilt=np.zeros((3, 2)), gamma=0.5, executed=[1, 4, 3])
    np.testing.assert_array_equal(episode.prev_actions, [-1, 1, 4])  # what was executed, not the labels
    np.testing.assert_array_equal(episode.prev_rewards, [0.0, 0.0, 0.0])
    np.testing.assert_allclose(episode.returns, [0.25, 0.5, 1.0])
    assert len(episode) == 3
    other = Episode.from_steps(obs=np.ones((2, 2), np.float32), actions=[0, 0], rewards=[1.0, -1.0],
                               tilt=np.ones((2, 2)), gamma=0.5)
    restored = Episode.split(Episode.concatenate([episode, other]))
    assert [len(e) for e in restored] == [3, 2]
    for before, after in zip([episode, other], restored):
        for name in Episode.STEP_FIELDS:
            np.testing.assert_array_equal(getattr(before, name), getattr(after, name))


def test_continuous_actions_stay_float_with_zero_previous_action_at_the_first_step():
    actions = np.array([[0.5, -1.0], [1.0, 0.25], [0.0, 0.0]])
    episode = Episode.from_steps(obs=np.zeros((3, 17), np.float32), actions=actions, rewards=[0.1, 0.2, 0.0],
                                 tilt=np.zeros((3, 2)), gamma=0.5)
    assert episode.actions.dtype == np.float32 and episode.prev_actions.dtype == np.float32
    np.testing.assert_array_equal(episode.actions, actions.astype(np.float32))
    np.testing.assert_array_equal(episode.prev_actions, [[0.0, 0.0], [0.5, -1.0], [1.0, 0.25]])
    restored = Episode.split(Episode.concatenate([episode, episode]))
    np.testing.assert_array_equal(restored[1].prev_actions, episode.prev_actions)


def test_relabel_cuts_a_full_episode_at_each_tasks_goal_with_its_rewards():
    # Outermost channel 4 → 3 → back out to 4 → 3 → 2 → 2 → 1 → 0 (the centre).
    full = _episode([4, 4, 3, 4, 3, 2, 2, 1, 0])
    # STG1: the marble left channel 4 at step 1; the episode ends there with reward 1.
    _assert_relabelled(relabel(full, "STG1", GAMMA), full, [0.0, 1.0], terminated=True)
    # STG2: channel 2 first reached at step 4 (going back out after STG1's goal does not matter).
    _assert_relabelled(relabel(full, Task.STG2, GAMMA), full, [0.0, 0.0, 0.0, 0.0, 1.0], terminated=True)
    _assert_relabelled(relabel(full, "STG3", GAMMA), full, [0.0] * 6 + [1.0], terminated=True)
    _assert_relabelled(relabel(full, "STG4", GAMMA), full, [0.0] * 7 + [1.0], terminated=True)
    # FULL: +1 per wall crossed inwards, -1 outwards, the whole episode.
    _assert_relabelled(relabel(full, "FULL", GAMMA), full, [0.0, 1.0, -1.0, 1.0, 1.0, 0.0, 1.0, 1.0],
                       terminated=True)

    # An episode that never reaches the goal keeps every step and is truncated, not terminated.
    unfinished = _episode([4, 3, 3, 2])
    _assert_relabelled(relabel(unfinished, "STG3", GAMMA), unfinished, [0.0, 0.0, 0.0], terminated=False)
    _assert_relabelled(relabel(unfinished, "FULL", GAMMA), unfinished, [1.0, 0.0, 1.0], terminated=False)

    # Two marbles: +1 per marble the first time it reaches the goal; the episode ends when both have.
    two = _episode([[4, 4], [3, 4], [4, 4], [4, 3], [3, 3], [2, 2]])
    _assert_relabelled(relabel(two, "STG1", GAMMA), two, [1.0, 0.0, 1.0], terminated=True)

    bad = dataclasses.replace(full, channels=full.channels[:-1])
    with pytest.raises(ValueError, match="channels must have 9 rows, got 8"):
        relabel(bad, "STG1", GAMMA)


