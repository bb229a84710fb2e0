"""Starting a pixel network from another's checkpoint (bimgame.learn.checkpoints.load_init_weights):
the empty-board frame a ``subtract_background`` network subtracts is the new run's board's, not the
checkpoint's, and a network that subtracted a frame is not started where none is (or the reverse)."""

from __future__ import annotations

import pytest
import torch

from bimgame.learn.checkpoints import CheckpointError, load_init_weights, save_checkpoint
from bimgame.learn.learner_settings import policy_network
from bimgame.learn.ppo import PPOConfig

PIXELS = dict(obs="pixels", hidden=16, features=16, action_type="continuous")


def _network(task: str, subtract: bool, seed: int = 0):
    return policy_network(PPOConfig.from_flat({**PIXELS, "task": task, "subtract_background": subtract}, seed=seed))


def _saved(net, path):
    return save_checkpoint(path, model=net.state_dict(), step=0)


def test_a_run_subtracts_its_own_board_and_keeps_every_learned_weight_of_the_checkpoint(tmp_path):
    hard = _network("LABYRINTH-HARD", True, seed=1)
    easy = _network("LABYRINTH-EASY", True, seed=2)
    easy_frame = easy.encoder.background.clone()
    assert not torch.equal(easy_frame, hard.encoder.background)  # two boards, two frames
    load_init_weights(easy, _saved(hard, tmp_path / "hard.pt"))
    assert torch.equal(easy.encoder.background, easy_frame)
    for name, weight in hard.state_dict().items():
        if name != "encoder.background":
            assert torch.equal(easy.state_dict()[name], weight), name


@pytest.mark.parametrize("trained, run", [(True, False), (False, True)])
def test_a_network_is_not_started_where_its_frames_would_be_read_otherwise(trained, run, tmp_path):
    source = _saved(_network("LABYRINTH-EASY", trained, seed=1), tmp_path / "pi.pt")
    target = _network("LABYRINTH-EASY", run, seed=2)
    before = {name: weight.clone() for name, weight in target.state_dict().items()}
    with pytest.raises(CheckpointError, match="--init: .*pi.pt was trained (with|without) --subtract-background"):
        load_init_weights(target, source)
    for name, weight in target.state_dict().items():  # refused before anything was loaded
        assert torch.equal(weight, before[name]), name
