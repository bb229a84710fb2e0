"""PPO's learning-rate annealing (``lr_anneal``, CleanRL's ``anneal_lr``): each update's Adam step
takes ``lr`` × (1 − step / steps) at its rollout's step; off, every update takes ``lr``."""

from __future__ import annotations

import pytest

from bimgame.learn.checkpoints import load_checkpoint
from bimgame.learn.ppo import PPOConfig, train_ppo

TINY = dict(task="STG1", obs="state", hidden=16, features=16, envs_per_worker=4, n_steps=16, minibatches=2,
            eval_every=0, eval_episodes=2, log_every=64, lr=1e-3)


def test_the_rate_falls_linearly_to_zero_over_the_run():
    optimization = PPOConfig.from_flat(TINY, lr_anneal=True).optimization
    assert optimization.lr_at(0, 1000) == pytest.approx(1e-3)
    assert optimization.lr_at(250, 1000) == pytest.approx(0.75e-3)
    assert optimization.lr_at(1000, 1000) == 0.0
    assert optimization.lr_at(1200, 1000) == 0.0  # a run extended past its schedule stays at zero
    assert PPOConfig.from_flat(TINY).optimization.lr_at(900, 1000) == pytest.approx(1e-3)


@pytest.mark.parametrize("bad", [1, "yes", None])
def test_the_setting_is_a_bool(bad):
    with pytest.raises(ValueError, match=r"PPOOptimizationSettings\.lr_anneal must be True or False"):
        PPOConfig.from_flat(TINY, lr_anneal=bad)


@pytest.mark.parametrize(("anneal", "expected"), [(True, 1e-3 * (1 - 192 / 256)), (False, 1e-3)])
def test_the_last_update_of_a_run_took_the_scheduled_rate(tmp_path, anneal, expected):
    # 4 rollouts of 4 envs × 16 steps: the last one starts at step 192 of 256.
    train_ppo(PPOConfig.from_flat(TINY, steps=256, lr_anneal=anneal), tmp_path / "run", progress=False)
    groups = load_checkpoint(tmp_path / "run" / "checkpoint.pt")["optimizer"]["param_groups"]
    assert [group["lr"] for group in groups] == [pytest.approx(expected)]
