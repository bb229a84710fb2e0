"""The rollout collector: what a segment records reproduces what the actor saw, time limits are
bootstrapped, episodes are booked from their true start, the recurrent state carries over, and the
advantage estimate is GAE / n-step returns."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.learn.a3c import A3CConfig, network_for
from bimgame.learn.actor import RecurrentActor
from bimgame.learn.rollout import FinishedEpisode, NonFiniteReward, RolloutCollector, Segment, advantages_and_targets

SMALL = dict(task="STG1", obs="state", hidden=16, features=16)


def _collector(batch: int = 3, limit: int = 300, seed: int = 0, *, env_wrapper=None, **kwargs):
    config = A3CConfig.from_flat(**SMALL, seed=seed)
    net = network_for(config)
    base = BallInMazeVectorEnv(batch, task="STG1", obs_mode="state", nthread=1, max_episode_steps=limit,
                               autoreset_mode="same_step", state_info=kwargs.get("privileged", False))
    env = env_wrapper(base) if env_wrapper is not None else base
    actor = RecurrentActor(net, batch, generator=torch.Generator().manual_seed(seed))
    episodes: list[FinishedEpisode] = []
    step = {"now": 0}
    collector = RolloutCollector(env, base, actor, gamma=0.9, on_episode=episodes.append,
                                 global_step=lambda: step["now"], **kwargs)
    collector.reset(seed, 0)
    return collector, net, episodes, step


def test_segment_inputs_replay_to_the_actions_log_probs_and_values_of_acting():
    """Unrolling the network over a segment's recorded inputs from its initial state gives exactly
    the distributions and values the actor acted with: the learner sees what the actor saw."""
    collector, net, _, _ = _collector(batch=3, limit=7)
    collector.collect(5, 0)  # so that the second segment starts mid-episode, with a non-zero LSTM state
    segment = collector.collect(9, 15)
    assert segment.steps == 9 and segment.batch == 3 and segment.step_at_start == 15
    assert segment.obs.shape == (10, 3, 7) and segment.tilt.shape == (10, 3, 2)
    assert float(segment.initial_state.h.abs().sum()) > 0
    with torch.no_grad():
        logits, values, _ = net.unroll(segment.obs, segment.prev_action, segment.prev_reward, segment.tilt,
                                       segment.initial_state, segment.starts)
    log_probs = torch.log_softmax(logits[:-1], dim=-1).gather(-1, segment.actions.unsqueeze(-1)).squeeze(-1)
    assert torch.allclose(log_probs, segment.log_probs, atol=1e-5)
    assert torch.allclose(values[:-1], segment.values, atol=1e-5)
    assert torch.equal(segment.ends, segment.starts[1:])


def test_the_next_segment_starts_from_the_state_the_last_one_ended_in():
    collector, _, _, _ = _collector(batch=2)
    collector.collect(4, 0)
    state = collector.actor.state
    following = collector.collect(4, 8)
    assert torch.equal(following.initial_state.h, state.h) and torch.equal(following.initial_state.c, state.c)


def test_time_limits_bootstrap_from_the_value_of_the_last_observation():
    """STG1 is not solved in 4 steps: every episode is cut by the time limit, whose step's reward is
    γ·V(final observation) ≠ 0, while the other steps' rewards are the task's 0."""
    collector, net, episodes, step = _collector(batch=2, limit=4)
    step["now"] = 123
    segment = collector.collect(10, 100)
    cut = segment.ends
    assert cut[3].all() and cut[7].all() and int(cut.sum()) == 4
    assert torch.all(segment.rewards[~cut] == 0)
    assert torch.all(segment.rewards[cut] != 0)
    assert [(e.length, e.success, e.true_start, e.episode_return) for e in episodes] == [(4, False, True, 0.0)] * 4
    # The first two episodes started with the run (step 0), the next two in this segment (step 100).
    assert [e.start_step for e in episodes] == [0, 0, 100, 100]
    assert all(e.end_step == 123 for e in episodes)
    assert episodes[0].row() == {"start_step": 0, "end_step": 123, "return": 0.0, "length": 4, "success": False,
                                 "true_start": True}


def test_episodes_are_told_to_the_start_curriculum():
    class Recorder:
        def __init__(self):
            self.outcomes: list[tuple[int, bool]] = []

        def record(self, tag: int, success: bool) -> None:
            self.outcomes.append((tag, success))

        def status(self) -> dict[str, float]:
            return {}

    recorder = Recorder()
    collector, _, episodes, _ = _collector(batch=2, limit=3, curriculum=recorder)
    collector.collect(6, 0)
    assert len(recorder.outcomes) == len(episodes) == 4
    assert all(success is False for _, success in recorder.outcomes)


class _NanAfter:
    """Rewards turn NaN from the ``after``-th step on."""

    def __init__(self, env, after: int):
        self.env, self.after, self.count = env, after, 0

    def reset(self, **kwargs):
        return self.env.reset(**kwargs)

    def step(self, actions):
        obs, reward, terminated, truncated, info = self.env.step(actions)
        self.count += 1
        if self.count >= self.after:
            reward = np.full_like(np.asarray(reward, dtype=np.float64), np.nan)
        return obs, reward, terminated, truncated, info


def test_a_non_finite_reward_is_refused_after_booking_earlier_episodes():
    collector, _, episodes, _ = _collector(batch=2, limit=2, env_wrapper=lambda env: _NanAfter(env, 3))
    with pytest.raises(NonFiniteReward, match="non-finite reward") as caught:
        collector.collect(5, 0)
    assert np.isnan(caught.value.rewards).all()
    assert len(episodes) == 2  # the episodes that ended at step 2, before the NaN


def test_privileged_segments_keep_the_state_and_tilt_can_be_left_out():
    collector, _, _, _ = _collector(batch=2, privileged=True, tilt_input=False)
    segment = collector.collect(3, 0)
    assert segment.privileged is not None and segment.privileged.shape == (4, 2, 7)
    assert segment.tilt is None


@pytest.mark.parametrize("gae_lambda", [0.0, 1.0])
def test_advantages_are_one_step_td_errors_at_lambda_0_and_n_step_returns_at_lambda_1(gae_lambda):
    g = torch.Generator().manual_seed(0)
    rewards = torch.rand(6, 2, generator=g)
    values = torch.rand(6, 2, generator=g)
    bootstrap = torch.rand(2, generator=g)
    ends = torch.zeros(6, 2, dtype=torch.bool)
    ends[2, 0] = True
    advantages, targets = advantages_and_targets(rewards, ends, values, bootstrap, 0.9, gae_lambda)
    assert torch.allclose(targets, advantages + values)
    following = torch.cat([values[1:], bootstrap[None]])
    not_end = 1.0 - ends.float()
    if gae_lambda == 0.0:
        assert torch.allclose(advantages, rewards + 0.9 * following * not_end - values, atol=1e-6)
    else:
        ret = bootstrap.clone()
        for t in reversed(range(6)):
            ret = rewards[t] + 0.9 * ret * not_end[t]
            assert torch.allclose(targets[t], ret, atol=1e-6)


def test_segments_of_some_environments_side_by_side_are_the_whole_segment():
    collector, _, _, _ = _collector(batch=3, privileged=True)
    segment = collector.collect(12, 0)
    parts = [segment.envs(torch.tensor([0, 1])), segment.envs(torch.tensor([2]))]
    joined = Segment.side_by_side(parts)
    for field in dataclasses.fields(segment):
        value = getattr(segment, field.name)
        if isinstance(value, torch.Tensor):
            assert torch.equal(getattr(joined, field.name), value), field.name
    assert torch.equal(joined.initial_state.h, segment.initial_state.h)
    assert torch.equal(joined.initial_state.c, segment.initial_state.c)
    assert joined.step_at_start == segment.step_at_start and joined.privileged is not None
