"""Multi-process PPO (bimgame.learn.ppo.parallel, learner): ranks with their own environments whose
averaged gradients keep one set of weights — a run with two workers trains, logs every rank's
episodes, gives the same run for the same seed, and refuses what it cannot do."""

from __future__ import annotations

import csv

import pytest
import torch

from bimgame.learn.checkpoints import load_checkpoint
from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.learn.ppo.collectors import rank_seeds

TWO_RANKS = dict(task="STG1", obs="state", hidden=16, features=16, workers=2, envs_per_worker=2, n_steps=32,
                 minibatches=2, sequence_length=8, steps=256, eval_every=0, eval_episodes=2, log_every=64,
                 max_episode_steps=10)


def _rows(path):
    with open(path) as handle:
        return list(csv.DictReader(handle))


def test_a_rollout_holds_every_ranks_environments():
    config = PPOConfig.from_flat(TWO_RANKS)
    assert config.steps_per_rollout == 2 * 2 * 32
    assert config.sequences_per_rollout == 2 * 32 // 8  # per rank: what its minibatches split


def test_ranks_draw_their_own_seeds_and_rank_0_keeps_the_one_process_seeds():
    assert rank_seeds(3, 0, 1) != rank_seeds(3, 0, 0)
    assert rank_seeds(3, 0, 0) == rank_seeds(3, 0, 0) != rank_seeds(3, 128, 0)


def test_two_workers_train_log_both_ranks_episodes_and_repeat_for_the_same_seed(tmp_path):
    config = PPOConfig.from_flat(TWO_RANKS)
    results = [train_ppo(config, tmp_path / name, progress=False) for name in ("a", "b")]
    assert all(result.stopped == "finished" and result.steps == 256 for result in results)
    assert [int(r["step"]) for r in _rows(tmp_path / "a" / "updates.csv")] == [128, 256]
    episodes = _rows(tmp_path / "a" / "episodes.csv")
    assert episodes == _rows(tmp_path / "b" / "episodes.csv")
    # The first rollout's rank 0 is a one-process run's first rollout; the log also holds rank 1's episodes.
    train_ppo(PPOConfig.from_flat(TWO_RANKS, workers=1, steps=64), tmp_path / "one", progress=False)
    first = lambda rows: [r for r in rows if int(r["step"]) == 0]  # noqa: E731
    alone, together = first(_rows(tmp_path / "one" / "episodes.csv")), first(episodes)
    assert alone and all(row in together for row in alone) and len(together) > len(alone)
    drop = lambda rows: [{k: v for k, v in r.items() if k not in ("seconds", "sps")} for r in rows]  # noqa: E731
    assert drop(_rows(tmp_path / "a" / "updates.csv")) == drop(_rows(tmp_path / "b" / "updates.csv"))
    weights = [load_checkpoint(tmp_path / name)["model"] for name in ("a", "b")]
    assert all(torch.equal(weights[0][key], weights[1][key]) for key in weights[0])
    before = config.network.build_policy(config.seed).state_dict()
    assert any(not torch.equal(before[key], weights[0][key]) for key in before)


def test_a_process_group_of_its_own_is_refused_inside_a_distributed_job(tmp_path, monkeypatch):
    import torch.distributed as dist

    monkeypatch.setattr(dist, "is_initialized", lambda: True)
    with pytest.raises(RuntimeError, match="makes its own torch.distributed process group"):
        train_ppo(PPOConfig.from_flat(TWO_RANKS), tmp_path / "run", progress=False)


def test_fine_tuning_keeps_pi_s_with_a_kl_term_on_every_rank(tmp_path):
    """kl_coef with --init: π^s is kept as teacher.pt, every rank's loss holds the KL (logged), and
    without --init the term is refused."""
    config = PPOConfig.from_flat(TWO_RANKS, workers=1, steps=64)
    train_ppo(config, tmp_path / "pi_s", progress=False)
    finetune = PPOConfig.from_flat(TWO_RANKS, kl_coef=0.5, kl_temperature=0.5)
    assert finetune.has_teacher and finetune.finetuning.kl_weight(10**6) == 0.5
    with pytest.raises(ValueError, match="kl_coef > 0 .* needs a pre-trained policy"):
        train_ppo(finetune, tmp_path / "no-init", progress=False)
    train_ppo(finetune, tmp_path / "tuned", init=tmp_path / "pi_s", progress=False)
    teacher = load_checkpoint(tmp_path / "tuned" / "teacher.pt")["model"]
    start = load_checkpoint(tmp_path / "pi_s")["model"]
    assert all(torch.equal(teacher[key], start[key]) for key in start)
    kl = [float(row["kl"]) for row in _rows(tmp_path / "tuned" / "updates.csv")]
    assert len(kl) == 2 and all(value >= 0 for value in kl) and kl[-1] > 0  # π moved away from π^s a little
    assert PPOConfig.from_flat(TWO_RANKS, kl_coef=0.0).finetuning is None
    decaying = PPOConfig.from_flat(TWO_RANKS, kl_coef=0.4, kl_decay_steps=100).finetuning
    assert decaying.kl_weight(50) == pytest.approx(0.2) and decaying.kl_weight(200) == 0.0
