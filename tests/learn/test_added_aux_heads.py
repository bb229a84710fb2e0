"""A run that adds auxiliary heads to a policy trained without them (bimgame.learn.checkpoints.
with_added_aux_heads, bimgame.learn.init_network): every weight the policy has is kept, so it acts as
loaded, the heads start fresh and learn; a PPO run from the command line starts so on the labyrinth,
and one that would drop trained heads is refused by name."""

from __future__ import annotations

import json

import torch

from bimgame.cli.main import main
from bimgame.learn.checkpoints import load_checkpoint, with_added_aux_heads
from bimgame.learn.learner_settings import policy_network
from bimgame.learn.curves import read_table
from bimgame.learn.ppo import PPOConfig
from support.labyrinth_runs import SMALL_STATE_FLAGS, SMALL_STATE_RUN

SMALL, CLI = SMALL_STATE_RUN, SMALL_STATE_FLAGS


def test_the_added_heads_start_fresh_and_the_policy_acts_as_loaded():
    old = policy_network(PPOConfig.from_flat(SMALL, seed=1))
    new = policy_network(PPOConfig.from_flat(SMALL, seed=2, aux_heads=True))
    fresh_heads = {k: v.clone() for k, v in new.state_dict().items() if k.startswith("aux_")}
    assert set(fresh_heads) == {"aux_frame.weight", "aux_frame.bias", "aux_memory.weight", "aux_memory.bias"}
    new.load_state_dict(with_added_aux_heads(old.state_dict(), new))
    for name, weight in old.state_dict().items():
        torch.testing.assert_close(new.state_dict()[name], weight)
    for name, weight in fresh_heads.items():
        torch.testing.assert_close(new.state_dict()[name], weight)
    obs = torch.randn(6, 3, 17, generator=torch.Generator().manual_seed(0))
    starts = torch.zeros(6, 3, dtype=torch.bool)
    args = (obs, torch.zeros(6, 3, 2), torch.zeros(6, 3), torch.zeros(6, 3, 2))
    before = old.unroll_features(*args, old.initial_state(3), starts)
    after = new.unroll_features(*args, new.initial_state(3), starts)
    torch.testing.assert_close(after.logits, before.logits)
    # The heads' loss reaches the shared encoder: the state is learned into the features the policy reads.
    loss, parts = new.aux_loss(after.features, after.hidden, torch.randn(6, 3, 17))
    loss.backward()
    assert new.encoder.net[0].weight.grad.abs().sum() > 0 and set(parts) == {"aux_frame", "aux_memory"}
    # Weights that already have heads (or a network without them) are left as they are.
    fitting, same = new.state_dict(), old.state_dict()
    assert with_added_aux_heads(fitting, new) is fitting and with_added_aux_heads(same, old) is same


def test_ppo_adds_heads_to_a_policy_without_them_and_refuses_to_drop_them(tmp_path, capsys):
    plain, heads = tmp_path / "plain", tmp_path / "heads"
    assert main(["train", "--algo", "ppo", "--run-dir", str(plain), "--steps", "128", *CLI]) == 0
    assert main(["train", "--algo", "ppo", "--run-dir", str(heads), "--steps", "128", "--init", str(plain),
                 "--aux-heads", "--kl-coef", "0.1", "--log-every", "64", *CLI]) == 0
    capsys.readouterr()
    stored = json.loads((heads / "config.json").read_text())
    assert stored["network"]["aux_heads"] is True and stored["net"]["state_layout"] == "labyrinth"
    start = load_checkpoint(heads / "teacher.pt")["model"]  # the weights the run started from
    source = load_checkpoint(plain / "checkpoint.pt")["model"]
    assert all(torch.equal(start[name], weight) for name, weight in source.items())
    after = load_checkpoint(heads / "checkpoint.pt")["model"]
    assert after["aux_frame.weight"].shape == (13, 16) and after["aux_memory.weight"].shape == (17, 16)
    assert not torch.equal(after["aux_memory.weight"], start["aux_memory.weight"])  # the heads learned
    log = read_table(heads / "updates.csv")
    assert len(log["aux_memory"]) and (log["aux_memory"] >= 0).all() and (log["aux_frame"] >= 0).all()
    # The other way would throw trained heads away: refused, naming the setting, writing nothing.
    assert main(["train", "--algo", "ppo", "--run-dir", str(tmp_path / "drop"), "--steps", "128", "--init",
                 str(heads), "--no-aux-heads", *CLI]) == 2
    assert "aux_heads: True there, False here" in capsys.readouterr().err
    assert not (tmp_path / "drop").exists()
