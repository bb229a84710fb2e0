"""PPO's rollouts collected in child processes (bimgame.learn.ppo.collectors, ``collectors`` ≥ 1).
Checked here: the settings refuse what cannot be split; one collector without a lag is the run that
collects in its own process, bit for bit; two collectors with a policy lag repeat themselves for the
same seed and book every environment's episodes; a rollout of several collectors is their
environments side by side; a child that fails or vanishes is reported, not waited for."""

from __future__ import annotations

import csv
import queue

import pytest
import torch

from bimgame.learn.checkpoints import load_checkpoint
from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.learn.ppo.processes import next_message
from bimgame.learn.run_dir import TrainingError

TINY = dict(task="STG1", obs="state", hidden=16, features=16, envs_per_worker=4, n_steps=16, minibatches=2,
            eval_every=0, eval_episodes=2, log_every=64, max_episode_steps=20)


def _rows(path):
    with open(path) as handle:
        return list(csv.DictReader(handle))


def _weights(run):
    return load_checkpoint(run)["model"]


def test_the_settings_split_one_process_environments_evenly():
    assert PPOConfig.from_flat(TINY).collectors == 0
    assert PPOConfig.from_flat(TINY, collectors=2).collectors == 2
    assert PPOConfig.from_flat(TINY, collectors=4, policy_lag=1).collectors == 4
    for bad in (3, 5, 8):
        with pytest.raises(ValueError, match=r"collectors must be 0 .* or a divisor of envs_per_worker \(4\)"):
            PPOConfig.from_flat(TINY, collectors=bad)
    for bad in (-1, True, 1.5, "2"):
        with pytest.raises(ValueError, match=r"PPOConfig\.collectors must be an integer >= 0"):
            PPOConfig.from_flat(TINY, collectors=bad)
    with pytest.raises(ValueError, match=r"collectors 2 feed one learning process \(workers 1\)"):
        PPOConfig.from_flat(TINY, collectors=2, workers=2)


def test_one_collector_without_a_lag_is_the_run_that_collects_in_its_own_process(tmp_path):
    """Collector 0 draws the seeds of the learning process's own environments and acts with the same
    weights: moving the collection to a child changes nothing of what is learned."""
    for collectors in (0, 1):
        config = PPOConfig.from_flat(TINY, steps=192, collectors=collectors, seed=5)
        train_ppo(config, tmp_path / f"c{collectors}", progress=False)
    episodes = [_rows(tmp_path / f"c{collectors}" / "episodes.csv") for collectors in (0, 1)]
    assert len(episodes[0]) >= 4 and episodes[0] == episodes[1]
    first, second = _weights(tmp_path / "c0"), _weights(tmp_path / "c1")
    assert all(torch.equal(first[key], second[key]) for key in first)


def test_two_collectors_with_a_lag_repeat_for_the_same_seed_and_book_every_environment(tmp_path):
    config = PPOConfig.from_flat(TINY, steps=192, collectors=2, policy_lag=1, seed=2)
    for name in ("a", "b"):
        train_ppo(config, tmp_path / name, progress=False)
    first, second = _weights(tmp_path / "a"), _weights(tmp_path / "b")
    assert all(torch.equal(first[key], second[key]) for key in first)
    episodes = _rows(tmp_path / "a" / "episodes.csv")
    assert episodes == _rows(tmp_path / "b" / "episodes.csv")
    # 4 environments of 48 steps each (2 × 2 in the children), episodes cut at 20 steps: 2 each at least.
    assert len(episodes) >= 8
    assert sum(int(row["length"]) for row in episodes) <= 192
    start = PPOConfig.from_flat(TINY, steps=192, seed=2)
    train_ppo(start, tmp_path / "own", progress=False)
    own = _weights(tmp_path / "own")  # collector 1's environments have seeds of their own: another run
    assert not all(torch.equal(own[key], first[key]) for key in own)


class _Process:
    def __init__(self, alive: bool, exitcode: int | None = None):
        self.alive, self.exitcode = alive, exitcode

    def is_alive(self) -> bool:
        return self.alive


def test_a_childs_error_and_a_child_that_ends_without_a_word_are_raised():
    messages: queue.Queue = queue.Queue()
    messages.put(("segment", 0, "payload"))
    messages.put(("error", 1, "Traceback: boom"))
    children = [_Process(True), _Process(True)]
    assert next_message(messages, children, "PPO collector") == ("segment", 0, "payload")
    with pytest.raises(TrainingError, match=r"PPO collector 1 failed:\nTraceback: boom"):
        next_message(messages, children, "PPO collector")
    with pytest.raises(TrainingError, match=r"PPO worker 2 ended without a word \(exit code -9\)"):
        next_message(messages, [_Process(True), _Process(False, -9)], "PPO worker", first=1)
