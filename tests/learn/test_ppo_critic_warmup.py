"""PPO's critic warm-up (``critic_warmup_steps``): during it an update changes the critic's weights
alone — not the policy head, σ or the trunk they share — on the value loss alone; after it the whole
network learns; the setting is stored, refused when negative, and given on the command line."""

from __future__ import annotations

import json

import pytest
import torch

from bimgame.cli.main import main
from bimgame.learn.checkpoints import load_checkpoint, save_checkpoint
from bimgame.learn.ppo import PPOConfig, PPOFinetuneSettings, ppo_minibatch_loss, train_ppo
from bimgame.learn.ppo.update import rollout_targets

from tests.learn.test_ppo import _segment

TINY = dict(task="STG1", obs="state", hidden=16, features=16, envs_per_worker=4, n_steps=16, minibatches=2,
            eval_every=0, eval_episodes=2, log_every=64, action_type="continuous")


def _critic_names(config: PPOConfig) -> set[str]:
    net = config.network.build_policy(0)
    critic = {id(param) for param in net.critic_parameters()}
    return {name for name, param in net.named_parameters() if id(param) in critic}


def test_the_warm_up_loss_is_the_value_loss_alone():
    config = PPOConfig.from_flat(TINY)
    net, segment = _segment(config)
    segment, targets = rollout_targets(net, segment, config.optimization)
    full, parts = ppo_minibatch_loss(net, segment, targets, config.optimization)
    warm, warm_parts = ppo_minibatch_loss(net, segment, targets, config.optimization, critic_only=True)
    torch.testing.assert_close(warm, config.optimization.value_coef * torch.tensor(warm_parts["value_loss"]))
    assert warm_parts == parts  # the same numbers logged
    assert not torch.isclose(full, warm)


def test_a_warm_up_run_changes_the_critic_alone_and_then_the_policy(tmp_path):
    source = PPOConfig.from_flat(TINY, steps=64)
    start = source.network.build_policy(3).state_dict()
    save_checkpoint(tmp_path / "pi_s.pt", model=start, step=0)
    critic = _critic_names(source)
    assert critic and critic < set(start)  # the value head, not the whole network
    ends = {}
    for warmup in (0, 512, 256):
        config = PPOConfig.from_flat(TINY, steps=512, critic_warmup_steps=warmup, checkpoint_every=128)
        run = tmp_path / f"warmup{warmup}"
        train_ppo(config, run, init=tmp_path / "pi_s.pt", progress=False)
        ends[warmup] = load_checkpoint(run / "checkpoint.pt")["model"]
        stored = json.loads((run / "config.json").read_text())["ppo"]
        assert warmup == 0 or PPOConfig.from_flat(stored).finetuning.critic_warmup_steps == warmup
    changed = {w: {name for name in start if not torch.equal(start[name], ends[w][name])} for w in ends}
    assert changed[512] and changed[512] <= critic  # warmed up all run long: the policy acts as loaded
    assert changed[0] - critic and changed[256] - critic  # without it, and after it, the policy learns too
    assert "log_std" in changed[256] and "log_std" not in changed[512]


def test_a_negative_warm_up_is_refused_and_the_flag_reaches_the_run(tmp_path):
    with pytest.raises(ValueError, match=r"PPOFinetuneSettings\.critic_warmup_steps must be an integer >= 0"):
        PPOFinetuneSettings(critic_warmup_steps=-1)
    assert not PPOFinetuneSettings(critic_warmup_steps=100).critic_only(100)
    assert PPOFinetuneSettings(critic_warmup_steps=100).critic_only(99)
    run = tmp_path / "cli"
    code = main(["train", "--algo", "ppo", "--task", "STG1", "--obs", "state", "--hidden", "16", "--features", "16",
                 "--envs-per-worker", "4", "--n-steps", "16", "--minibatches", "2", "--steps", "64",
                 "--eval-every", "0", "--eval-episodes", "1", "--critic-warmup-steps", "32", "--no-progress",
                 "--run-dir", str(run)])
    assert code == 0
    assert json.loads((run / "config.json").read_text())["ppo"]["critic_warmup_steps"] == 32
