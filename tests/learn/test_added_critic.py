"""A run that adds an asymmetric critic to a policy trained without one (bimgame.learn.checkpoints.
with_added_critic, bimgame.learn.init_network): the policy's weights are kept, the critic starts as the
old value exactly and reads the state from there; a PPO run from the command line starts so, and one
that would drop a trained critic is refused by name."""

from __future__ import annotations

import json

import torch

from bimgame.cli.main import main
from bimgame.learn.checkpoints import load_checkpoint, with_added_critic
from bimgame.learn.learner_settings import policy_network
from bimgame.learn.ppo import PPOConfig
from support.labyrinth_runs import SMALL_STATE_FLAGS, SMALL_STATE_RUN

SMALL, CLI = SMALL_STATE_RUN, SMALL_STATE_FLAGS


def test_the_added_critic_starts_as_the_old_value_and_the_policy_is_unchanged():
    old = policy_network(PPOConfig.from_flat(SMALL, seed=1))
    with torch.no_grad():
        old.value.bias.fill_(0.3)  # a value the widening must carry over
    new = policy_network(PPOConfig.from_flat(SMALL, seed=2, asymmetric_critic=True))
    fresh_reader = {k: v.clone() for k, v in new.state_dict().items() if k.startswith("critic_state.")}
    new.load_state_dict(with_added_critic(old.state_dict(), new))
    hidden = torch.randn(5, 16, generator=torch.Generator().manual_seed(0))
    privileged = torch.randn(5, 17, generator=torch.Generator().manual_seed(1))
    torch.testing.assert_close(new.values_of(hidden, privileged), old.values_of(hidden, None))
    for name, weight in old.state_dict().items():
        if not name.startswith("value."):
            torch.testing.assert_close(new.state_dict()[name], weight)
    for name, weight in fresh_reader.items():  # the state reader keeps the new network's draw
        torch.testing.assert_close(new.state_dict()[name], weight)
    # Its gradient reaches the state reader through the widened head's zero columns: it can learn.
    new.values_of(hidden, privileged).sum().backward()
    assert new.value.weight.grad[:, 16:].abs().sum() > 0
    # Weights that already fit (or a network without the critic) are left as they are.
    fitting, same = new.state_dict(), old.state_dict()
    assert with_added_critic(fitting, new) is fitting and with_added_critic(same, old) is same


def test_ppo_adds_a_critic_to_a_policy_without_one_and_refuses_to_drop_one(tmp_path, capsys):
    plain, critic = tmp_path / "plain", tmp_path / "critic"
    assert main(["train", "--algo", "ppo", "--run-dir", str(plain), "--steps", "128", *CLI]) == 0
    assert main(["train", "--algo", "ppo", "--run-dir", str(critic), "--steps", "128", "--init", str(plain),
                 "--asymmetric-critic", "--kl-coef", "0.1", *CLI]) == 0
    capsys.readouterr()
    assert json.loads((critic / "config.json").read_text())["network"]["asymmetric_critic"] is True
    start = load_checkpoint(critic / "teacher.pt")["model"]  # the weights the run started from
    source = load_checkpoint(plain / "checkpoint.pt")["model"]
    after = load_checkpoint(critic / "checkpoint.pt")["model"]
    assert after["value.weight"].shape == (1, 16 + 128) and after["critic_state.0.weight"].shape == (128, 17)
    assert torch.equal(start["value.weight"][:, :16], source["value.weight"])
    assert not start["value.weight"][:, 16:].any() and torch.equal(start["policy.weight"], source["policy.weight"])
    # The other way would throw a trained critic away: refused, naming the setting, writing nothing.
    assert main(["train", "--algo", "ppo", "--run-dir", str(tmp_path / "drop"), "--steps", "128", "--init",
                 str(critic), "--no-asymmetric-critic", *CLI]) == 2
    assert "asymmetric_critic: True there, False here" in capsys.readouterr().err
    assert not (tmp_path / "drop").exists()
