"""Acting with a recurrent actor-critic (RecurrentActor): what the network is fed between steps and
at episode boundaries, seeded sampling and greedy acting; the tilt input; and evaluate_network's
bookkeeping of the first episode of each environment."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.learn.actor import EvalResult, RecurrentActor, evaluate_network, tilt_input
from bimgame.learn.nets import NO_ACTION, NetConfig, build_network, state_obs_scale
from bimgame.sim.maze import MazeSpec

SPEC = MazeSpec.merl()
MAX_TILT = SPEC.max_tilt
BATCH = 4


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread():
    """Tiny networks: a second intra-op thread only slows them down on the shared 2-core machine."""
    from bimgame.learn.runs import torch_threads

    with torch_threads(1):
        yield


def _net(seed: int = 0, hidden: int = 8, tilt: bool = True):
    """A small state-observation network (MLP 16 -> LSTM ``hidden``)."""
    return build_network(NetConfig(encoder="mlp", obs_shape=(7,), features=16, hidden=hidden, tilt_input=tilt),
                         obs_scale=state_obs_scale(SPEC), seed=seed)


def _inputs(steps: int, batch: int = BATCH, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Random state observations (steps, batch, 7) and tilts (steps, batch, 2) in [-1, 1]."""
    g = torch.Generator().manual_seed(seed)
    obs = torch.randn(steps, batch, 7, generator=g) * torch.as_tensor(state_obs_scale(SPEC))
    tilt = torch.rand(steps, batch, 2, generator=g) * 2 - 1
    return obs, tilt


# ------------------------------------------------------------------------------ RecurrentActor
def test_a_new_actor_starts_every_environment_afresh():
    net = _net()
    actor = RecurrentActor(net, BATCH)
    assert torch.equal(actor.prev_action, torch.full((BATCH,), NO_ACTION))
    assert torch.equal(actor.prev_reward, torch.zeros(BATCH))
    assert actor.state.h.shape == actor.state.c.shape == (BATCH, 8)
    assert not actor.state.h.any() and not actor.state.c.any()
    assert actor.starts.all()

    # act() feeds the network exactly these fresh inputs.
    obs, tilt = _inputs(1)
    actions, logits, values = actor.act(obs[0], tilt[0])
    expected_logits, expected_values, expected_state = net.step(
        obs[0], torch.full((BATCH,), NO_ACTION), torch.zeros(BATCH), tilt[0], net.initial_state(BATCH))
    torch.testing.assert_close(logits, expected_logits)
    torch.testing.assert_close(values, expected_values)
    torch.testing.assert_close(actor.state.h, expected_state.h)
    torch.testing.assert_close(actor.state.c, expected_state.c)
    assert actions.shape == (BATCH,) and actions.dtype == torch.long
    assert logits.shape == (BATCH, 5) and values.shape == (BATCH,)
    assert ((actions >= 0) & (actions < 5)).all()


def test_observe_resets_the_inputs_and_lstm_state_of_ended_episodes_and_carries_the_others():
    net = _net()
    actor = RecurrentActor(net, BATCH, generator=torch.Generator().manual_seed(0))
    obs, tilt = _inputs(3)
    actor.act(obs[0], tilt[0])
    actions = torch.tensor([1, 2, 3, 4])
    rewards = np.array([0.5, -1.0, 2.0, 0.25], dtype=np.float64)
    actor.observe(actions, rewards, np.zeros(BATCH, dtype=bool))
    # Nothing ended: every environment carries its action, reward and LSTM state.
    carried = actor.state
    assert torch.equal(actor.prev_action, actions)
    torch.testing.assert_close(actor.prev_reward, torch.tensor([0.5, -1.0, 2.0, 0.25]))
    assert actor.prev_reward.dtype == torch.float32
    assert not actor.starts.any()
    assert carried.h.abs().min() > 0 and carried.c.abs().min() > 0  # a real state to keep or drop

    actor.act(obs[1], tilt[1])
    before = actor.state
    assert not torch.equal(before.h, carried.h)  # act() advanced the LSTM
    done = np.array([False, True, False, True])
    actor.observe(torch.tensor([0, 4, 2, 1]), np.array([3.0, 1.0, -2.0, 1.0]), done)
    assert actor.prev_action.tolist() == [0, NO_ACTION, 2, NO_ACTION]
    assert actor.prev_reward.tolist() == [3.0, 0.0, -2.0, 0.0]
    assert actor.starts.tolist() == done.tolist()
    for name in ("h", "c"):
        after, kept = getattr(actor.state, name), getattr(before, name)
        assert not after[[1, 3]].any(), name  # ended episodes: zero state
        assert torch.equal(after[[0, 2]], kept[[0, 2]]), name  # the others: unchanged

    # The next step: an environment whose episode ended is fed exactly what a brand-new actor
    # feeds it; the others what they carried.
    _, logits, values = actor.act(obs[2], tilt[2])
    _, fresh_logits, fresh_values = RecurrentActor(net, BATCH, greedy=True).act(obs[2], tilt[2])
    torch.testing.assert_close(logits[[1, 3]], fresh_logits[[1, 3]])
    torch.testing.assert_close(values[[1, 3]], fresh_values[[1, 3]])
    carry_logits, carry_values, _ = net.step(obs[2], torch.tensor([0, 4, 2, 1]), torch.tensor([3.0, 1.0, -2.0, 1.0]),
                                             tilt[2], before)
    torch.testing.assert_close(logits[[0, 2]], carry_logits[[0, 2]])
    torch.testing.assert_close(values[[0, 2]], carry_values[[0, 2]])
    assert not torch.allclose(logits[[0, 2]], fresh_logits[[0, 2]])  # carrying made a difference


def test_reset_starts_all_environments_again():
    net = _net()
    actor = RecurrentActor(net, BATCH)
    obs, tilt = _inputs(1)
    actions, _, _ = actor.act(obs[0], tilt[0])
    actor.observe(actions, np.ones(BATCH), np.zeros(BATCH, dtype=bool))
    actor.reset()
    assert torch.equal(actor.prev_action, torch.full((BATCH,), NO_ACTION))
    assert not actor.prev_reward.any() and not actor.state.h.any() and not actor.state.c.any()
    assert actor.starts.all()


def _sampled_actions(net, seed: int, steps: int = 30, batch: int = 8, greedy: bool = False) -> torch.Tensor:
    """(steps, batch) actions of an actor fed random observations, rewards and episode ends."""
    actor = RecurrentActor(net, batch, generator=torch.Generator().manual_seed(seed), greedy=greedy)
    obs, tilt = _inputs(steps, batch, seed=99)
    inputs = np.random.default_rng(7)
    out = []
    for t in range(steps):
        actions, _, _ = actor.act(obs[t], tilt[t])
        out.append(actions)
        actor.observe(actions, inputs.normal(size=batch), inputs.random(batch) < 0.1)
    return torch.stack(out)


def test_the_same_generator_seed_samples_the_same_actions():
    net = _net()
    first, again = _sampled_actions(net, seed=3), _sampled_actions(net, seed=3)
    assert torch.equal(first, again)
    other = _sampled_actions(net, seed=4)
    assert not torch.equal(first, other)
    # A fresh network is near uniform: sampling uses all five actions.
    assert set(first.unique().tolist()) == set(range(5))


def test_sampled_actions_follow_the_policy_probabilities():
    """Actions are drawn from softmax(logits), not e.g. the argmax or the raw logits."""
    net = _net()
    probs = torch.tensor([0.05, 0.1, 0.15, 0.3, 0.4])
    with torch.no_grad():
        net.policy.weight.zero_()
        net.policy.bias.copy_(probs.log())
    batch = 4000
    actor = RecurrentActor(net, batch, generator=torch.Generator().manual_seed(0))
    obs, tilt = _inputs(1, batch)
    actions, logits, _ = actor.act(obs[0], tilt[0])
    torch.testing.assert_close(torch.softmax(logits, -1), probs.expand(batch, 5))
    freq = torch.bincount(actions, minlength=5).float() / batch
    # 4000 draws: the standard error of each frequency is below 0.008.
    assert torch.allclose(freq, probs, atol=0.03), freq


def test_greedy_acting_is_the_argmax_and_ignores_the_generator():
    net = _net()
    greedy_a = _sampled_actions(net, seed=1, greedy=True)
    greedy_b = _sampled_actions(net, seed=2, greedy=True)
    assert torch.equal(greedy_a, greedy_b)
    actor = RecurrentActor(net, BATCH, greedy=True)
    obs, tilt = _inputs(1)
    actions, logits, _ = actor.act(obs[0], tilt[0])
    assert torch.equal(actions, logits.argmax(-1))


def test_a_network_without_tilt_input_acts_without_tilt():
    net = _net(tilt=False)
    actor = RecurrentActor(net, BATCH, greedy=True)
    obs, _ = _inputs(1)
    actions, logits, _ = actor.act(obs[0], None)
    assert actions.shape == (BATCH,) and torch.isfinite(logits).all()
    with pytest.raises(ValueError, match="takes the board tilt"):
        RecurrentActor(_net(), BATCH).act(obs[0], None)


# ---------------------------------------------------------------------------------- tilt_input
def test_tilt_input_is_the_tilt_in_units_of_the_maximum():
    out = tilt_input({"tilt": np.array([[0.05, -0.025], [0.0, 0.1]])}, 0.1)
    assert out.dtype == torch.float32 and out.shape == (2, 2)
    torch.testing.assert_close(out, torch.tensor([[0.5, -0.25], [0.0, 1.0]]))

    # From the env: one tilt step (1°) of a 5° maximum is about 0.2, with the action's sign and axis.
    env = BallInMazeVectorEnv(5, task="STG1", obs_mode="state", nthread=1)
    try:
        _, info = env.reset(seed=0)
        assert not tilt_input(info, env.maze.max_tilt).any()
        _, _, _, _, info = env.step(np.arange(5))  # noop, +x, -x, +y, -y
    finally:
        env.close()
    step = math.radians(1.0) / env.maze.max_tilt
    expected = torch.tensor([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]], dtype=torch.float32) * step
    torch.testing.assert_close(tilt_input(info, env.maze.max_tilt), expected, atol=0.02, rtol=0)


# ---------------------------------------------------------------------------- evaluate_network
def _check_first_episodes(result: EvalResult, episodes: int, limit: int) -> None:
    """STG1: reward 1 exactly when the marble passes the wall (the episode then ends); otherwise
    the episode runs to the time limit with return 0."""
    assert len(result.successes) == len(result.lengths) == len(result.returns) == episodes
    for success, length, episode_return in zip(result.successes, result.lengths, result.returns):
        assert 1 <= length <= limit
        if success:
            assert episode_return == 1.0
        else:
            assert (episode_return, length) == (0.0, limit)


def test_evaluate_network_is_seeded_and_counts_one_episode_per_environment():
    net = _net(seed=1)
    episodes = 16
    first = evaluate_network(net, task="STG1", obs_mode="state", episodes=episodes, seed=5, greedy=False)
    _check_first_episodes(first, episodes, 300)  # STG1's time limit
    # A random network solves STG1 sometimes (~16% in 300 steps): lengths vary.
    assert 0 < sum(first.successes) < episodes, first
    again = evaluate_network(net, task="STG1", obs_mode="state", episodes=episodes, seed=5, greedy=False)
    assert (again.successes, again.lengths, again.returns) == (first.successes, first.lengths, first.returns)
    assert again.frames == []
    other = evaluate_network(net, task="STG1", obs_mode="state", episodes=episodes, seed=6, greedy=False)
    assert (other.successes, other.lengths) != (first.successes, first.lengths)

    summary = first.summary()
    assert summary["episodes"] == episodes
    assert summary["success_rate"] == pytest.approx(sum(first.successes) / episodes)
    assert summary["mean_length"] == pytest.approx(sum(first.lengths) / episodes)
    assert summary["mean_return"] == pytest.approx(sum(first.returns) / episodes)
    assert (first.success_rate, first.mean_length, first.mean_return) == (
        summary["success_rate"], summary["mean_length"], summary["mean_return"])


def test_greedy_evaluation_is_deterministic_and_respects_the_time_limit():
    net = _net(seed=2)
    a = evaluate_network(net, task="STG1", obs_mode="state", episodes=6, seed=0, greedy=True, max_episode_steps=25)
    b = evaluate_network(net, task="STG1", obs_mode="state", episodes=6, seed=0, greedy=True, max_episode_steps=25)
    _check_first_episodes(a, 6, 25)
    assert (a.successes, a.lengths, a.returns) == (b.successes, b.lengths, b.returns)


def test_recording_keeps_the_first_episodes_frames_and_changes_nothing_else():
    net = _net(seed=1)
    plain = evaluate_network(net, task="STG1", obs_mode="state", episodes=3, seed=2, greedy=False,
                             max_episode_steps=40)
    recorded = evaluate_network(net, task="STG1", obs_mode="state", episodes=3, seed=2, greedy=False,
                                max_episode_steps=40, record=True, render_size=48)
    assert (recorded.successes, recorded.lengths, recorded.returns) == (plain.successes, plain.lengths,
                                                                        plain.returns)
    # One frame before each of the first episode's steps.
    assert len(recorded.frames) == recorded.lengths[0]
    assert all(f.shape == (48, 48, 3) and f.dtype == np.uint8 for f in recorded.frames)
    assert not np.array_equal(recorded.frames[0], recorded.frames[-1])  # the board tilts, the marble rolls


def test_eval_result_summary_of_nothing_is_nan():
    empty = EvalResult([], [], [])
    summary = empty.summary()
    assert summary["episodes"] == 0
    assert all(math.isnan(summary[k]) for k in ("success_rate", "mean_length", "mean_return"))
    result = EvalResult([True, False, False, True], [10, 300, 300, 30], [1.0, 0.0, 0.0, 1.0])
    assert result.summary() == {"success_rate": 0.5, "mean_length": 160.0, "mean_return": 0.5, "episodes": 4}


# ------------------------------------------------------------------------------ continuous actions
def _continuous_net(seed: int = 0):
    """A small state-observation network with a Gaussian policy over the 2 tilt changes."""
    config = NetConfig(encoder="mlp", obs_shape=(7,), features=16, hidden=8, action_type="continuous")
    return build_network(config, obs_scale=state_obs_scale(SPEC), seed=seed)


def test_a_continuous_actor_feeds_back_the_executed_action_and_zeros_at_a_start():
    net = _continuous_net()
    actor = RecurrentActor(net, BATCH, generator=torch.Generator().manual_seed(0))
    assert torch.equal(actor.prev_action, torch.zeros(BATCH, 2)) and actor.starts.all()
    obs, tilt = _inputs(2)
    actions, means, values = actor.act(obs[0], tilt[0])
    assert actions.shape == means.shape == (BATCH, 2) and actions.dtype == torch.float32 and values.shape == (BATCH,)
    actions = torch.tensor([[0.5, -0.25], [1.7, -3.0], [0.0, 0.1], [-1.2, 0.9]])
    executed = actor.executed(actions)
    assert torch.equal(executed, torch.tensor([[0.5, -0.25], [1.0, -1.0], [0.0, 0.1], [-1.0, 0.9]]))
    actor.observe(actions, np.array([0.0, 1.0, 0.0, 0.5]), np.array([False, False, True, False]))
    assert torch.equal(actor.prev_action, executed * torch.tensor([[1.0], [1.0], [0.0], [1.0]]))
    assert actor.starts.tolist() == [False, False, True, False]
    actor.reset()
    assert torch.equal(actor.prev_action, torch.zeros(BATCH, 2))


def test_continuous_sampling_is_seeded_and_greedy_acting_is_the_mean():
    net = _continuous_net()
    first, again = _sampled_actions(net, seed=3), _sampled_actions(net, seed=3)
    assert first.shape == (30, 8, 2) and torch.equal(first, again)
    assert not torch.equal(first, _sampled_actions(net, seed=4))
    # The initial spread: σ = exp(LOG_STD_INIT) around means near 0.
    assert first.std().item() == pytest.approx(math.exp(-0.5), rel=0.15)
    assert torch.equal(_sampled_actions(net, seed=1, greedy=True), _sampled_actions(net, seed=2, greedy=True))
    actor = RecurrentActor(net, BATCH, greedy=True)
    obs, tilt = _inputs(1)
    actions, means, _ = actor.act(obs[0], tilt[0])
    assert torch.equal(actions, means)


def test_evaluate_network_steps_a_continuous_env_for_a_continuous_network():
    net = _continuous_net(seed=1)
    for greedy in (True, False):
        result = evaluate_network(net, task="STG1", obs_mode="state", episodes=3, seed=0, greedy=greedy,
                                  max_episode_steps=25)
        _check_first_episodes(result, 3, 25)
    with torch.no_grad():
        net.policy.bias.fill_(5.0)  # greedy means far outside [-1, 1]: executed clipped, not refused
    _check_first_episodes(evaluate_network(net, task="STG1", obs_mode="state", episodes=2, seed=0,
                                           max_episode_steps=10), 2, 10)


@pytest.mark.parametrize(("layout", "lean", "hole"), [("hard", (0.3, -0.1), True), ("easy", (0.3, -0.1), False)])
def test_evaluate_network_tells_a_labyrinth_episode_that_fell_into_a_hole_from_one_that_left_the_path(
        layout, lean, hole):
    """A network whose greedy action is a constant tilt rate (policy weights zero, bias the lean) on
    the batched labyrinth; the single env replayed from the same start seeds with the same action
    ends the same way: in a hole on the hard layout, off the path on the easy one."""
    net = build_network(NetConfig(encoder="mlp", obs_shape=(17,), features=16, hidden=8, action_type="continuous"))
    with torch.no_grad():
        net.policy.weight.zero_()
        net.policy.bias[:2] = torch.tensor(lean)
    result = evaluate_network(net, task=f"LABYRINTH-{layout.upper()}", obs_mode="state", episodes=3, seed=10,
                              max_episode_steps=300)
    env = LabyrinthEnv(layout)
    for i in range(3):
        env.reset(seed=10 + i)  # board i of the batched env starts as reset(seed=seed + i)
        for step in range(1, 301):
            _, _, terminated, _, info = env.step(np.asarray(lean, dtype=np.float32))
            if terminated:
                break
        assert terminated and not info["is_success"] and result.lengths[i] == step < 300
        assert result.holes[i] == info["over_hole"] == hole and info["off_path"] != hole
    # The circular maze has no holes: its results leave them empty.
    assert evaluate_network(_net(), task="STG1", obs_mode="state", episodes=2, seed=0, max_episode_steps=5).holes == []

