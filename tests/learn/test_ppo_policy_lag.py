"""PPO with a policy lag of one update (bimgame.learn.ppo.learner, ``policy_lag=1``): the update of a
rollout runs in a second thread while the next rollout is collected with the weights from before it.
Checked here: the settings refuse what it cannot do; a one-rollout run is PPO's own bit for bit; the
rollout collected during an update was acted by the weights before that update; the same seed gives
the same run; episodes are booked at the steps they happened."""

from __future__ import annotations

import copy
import csv

import pytest
import torch

from bimgame.learn.checkpoints import load_checkpoint
from bimgame.learn.learner_settings import policy_network
from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.learn.ppo.learner import RankLearner, adam
from bimgame.learn.rollout import unroll

TINY = dict(task="STG1", obs="state", hidden=16, features=16, envs_per_worker=4, n_steps=16, minibatches=2,
            eval_every=0, eval_episodes=2, log_every=64)


def _rows(path):
    with open(path) as handle:
        return list(csv.DictReader(handle))


def test_the_settings_take_a_lag_of_zero_or_one_in_one_process():
    assert PPOConfig.from_flat(TINY).optimization.policy_lag == 0
    assert PPOConfig.from_flat(TINY, policy_lag=1).optimization.policy_lag == 1
    for bad in (2, -1, True, 1.0, "1"):
        with pytest.raises(ValueError, match=r"PPOOptimizationSettings\.policy_lag must be one of \(0, 1\)"):
            PPOConfig.from_flat(TINY, policy_lag=bad)
    with pytest.raises(ValueError, match=r"policy_lag 1 overlaps one process's rollout and update \(workers 1\)"):
        PPOConfig.from_flat(TINY, policy_lag=1, workers=2)


def test_a_run_of_one_rollout_is_ppos_own_bit_for_bit(tmp_path):
    """The first rollout is acted by the starting weights either way and nothing is collected ahead
    of the last update: with one rollout, the lag changes nothing."""
    for lag in (0, 1):
        train_ppo(PPOConfig.from_flat(TINY, steps=64, policy_lag=lag), tmp_path / f"lag{lag}", progress=False)
    weights = [load_checkpoint(tmp_path / f"lag{lag}")["model"] for lag in (0, 1)]
    assert all(torch.equal(weights[0][key], weights[1][key]) for key in weights[0])
    assert _rows(tmp_path / "lag0" / "episodes.csv") == _rows(tmp_path / "lag1" / "episodes.csv")


def test_the_rollout_collected_during_an_update_was_acted_by_the_weights_before_it():
    config = PPOConfig.from_flat(TINY, policy_lag=1)
    net = policy_network(config)
    before = copy.deepcopy(net)
    learning = copy.deepcopy(net)
    learner = RankLearner(config, net, adam(learning, config), rank=0, step=0, on_episode=lambda episode: None,
                          global_step=lambda: 0, learning=learning)
    try:
        learner.rollout_and_update(0)
        ahead = learner._pending
        assert ahead is not None and ahead.step_at_start == config.steps_per_rollout
        with torch.no_grad():
            acted = unroll(before, ahead)
            updated = unroll(net, ahead)
        # The values the collector recorded are the starting weights' (the ones that acted) ...
        assert torch.allclose(acted.values[:-1], ahead.values, atol=1e-6)
        # ... and the acting network has since taken the update's weights, which value it otherwise.
        assert not torch.allclose(updated.values[:-1], ahead.values, atol=1e-6)
        assert all(torch.equal(a, b) for a, b in zip(net.state_dict().values(), learning.state_dict().values(),
                                                      strict=True))
    finally:
        learner.close()


def test_the_same_seed_gives_the_same_lagged_run_and_its_episodes_keep_their_steps(tmp_path):
    # Rollouts of 16 environments × 64 steps: 1,024 steps, 5 of them.
    config = PPOConfig.from_flat(TINY, envs_per_worker=16, n_steps=64, steps=5120, seed=3, policy_lag=1)
    for name in ("a", "b"):
        result = train_ppo(config, tmp_path / name, progress=False)
        assert result.stopped == "finished" and result.steps == 5120
    drop = lambda rows: [{k: v for k, v in r.items() if k not in ("seconds", "sps")} for r in rows]  # noqa: E731
    assert drop(_rows(tmp_path / "a" / "updates.csv")) == drop(_rows(tmp_path / "b" / "updates.csv"))
    episodes = _rows(tmp_path / "a" / "episodes.csv")
    assert episodes == _rows(tmp_path / "b" / "episodes.csv")
    weights = [load_checkpoint(tmp_path / name)["model"] for name in ("a", "b")]
    assert all(torch.equal(weights[0][k], weights[1][k]) for k in weights[0])
    # Episodes are booked at the first step of the rollouts they started and ended in, as without a
    # lag (the rollout collected ahead counts from the next rollout's step), so an episode of L steps
    # spans the rollouts its steps do; nothing is collected after the last update (from step 4,096).
    assert len(episodes) >= 10 and max(int(e["step"]) for e in episodes) == 4096
    for episode in episodes:
        started, ended = int(episode["start_step"]) // 1024, int(episode["step"]) // 1024
        assert (ended - started - 1) * 64 < int(episode["length"]) <= (ended - started + 1) * 64, episode


def test_a_lagged_run_resumes_from_its_checkpoint(tmp_path):
    """The rollout collected ahead at a stop is not in the checkpoint: a resumed run starts fresh
    episodes (as every resumed run does) and trains to its steps."""
    train_ppo(PPOConfig.from_flat(TINY, steps=128, policy_lag=1), tmp_path / "run", progress=False)
    resumed = train_ppo(PPOConfig.from_flat(TINY, steps=256, policy_lag=1), tmp_path / "run", resume=True,
                        progress=False)
    assert resumed.stopped == "finished" and resumed.steps == 256
    assert [int(r["step"]) for r in _rows(tmp_path / "run" / "updates.csv")] == [64, 128, 192, 256]
    with pytest.raises(ValueError, match=r"--resume must keep the run's settings; changed: policy_lag \(1 -> 0\)"):
        train_ppo(PPOConfig.from_flat(TINY, steps=512), tmp_path / "run", resume=True, progress=False)
