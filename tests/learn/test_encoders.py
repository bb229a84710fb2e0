"""The maze encoding in the marble's frame (:func:`bimgame.learn.encoders.marble_frame`) and the
state encoder that reads it."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from bimgame.envs.mazes import MAZE_ENCODING_ANGLES, maze_encoding
from bimgame.learn.encoders import ENCODING_BINS, MLPEncoder, marble_frame
from bimgame.learn.nets import NetConfig
from bimgame.learn.ppo import PPOConfig
from bimgame.sim.maze import MazeSpec

BIN = 2 * math.pi / ENCODING_BINS


def _merl() -> torch.Tensor:
    return torch.as_tensor(maze_encoding(MazeSpec.merl()).copy())


def test_the_networks_bins_are_the_envs():
    assert ENCODING_BINS == MAZE_ENCODING_ANGLES


def test_the_marble_frame_turns_each_wall_by_the_marbles_angle():
    encoding = _merl()
    walls = encoding.view(4, ENCODING_BINS)
    # At angle 0 the marble's frame is the board's; at ±π half a turn; a quarter turn is 8 bins.
    assert torch.equal(marble_frame(encoding, torch.tensor(0.0)), encoding)
    for angle, bins in ((math.pi, 16), (-math.pi, 16), (math.pi / 2, 8), (-math.pi / 2, -8), (3 * BIN, 3)):
        turned = marble_frame(encoding, torch.tensor(angle)).view(4, ENCODING_BINS)
        torch.testing.assert_close(turned, torch.roll(walls, -bins, dims=1), atol=1e-6, rtol=0)
    # Between bins: the neighbours' mean at half a bin, and a batch (T, B, 128) keeps its shape.
    half = marble_frame(encoding, torch.tensor(BIN / 2)).view(4, ENCODING_BINS)
    torch.testing.assert_close(half, (walls + torch.roll(walls, -1, dims=1)) / 2)
    batch = marble_frame(encoding.expand(3, 5, 128), torch.full((3, 5), BIN))
    assert batch.shape == (3, 5, 128)
    torch.testing.assert_close(batch[2, 4].view(4, ENCODING_BINS), torch.roll(walls, -1, dims=1))


def test_a_maze_and_marble_turned_together_look_the_same_to_the_marble():
    """What the marble-frame network sees depends only on where the gates are relative to the marble:
    a maze turned by any angle, with the marble turned with it, gives the same input."""
    rng = np.random.default_rng(0)
    encoding = _merl().view(4, ENCODING_BINS)
    for _ in range(20):
        bins = int(rng.integers(ENCODING_BINS))
        marble = float(rng.uniform(-math.pi, math.pi))
        turned_maze = torch.roll(encoding, bins, dims=1).reshape(-1)  # the gates bins·Δ further round
        turned_marble = math.remainder(marble + bins * BIN, 2 * math.pi)
        torch.testing.assert_close(
            marble_frame(turned_maze, torch.tensor(turned_marble)),
            marble_frame(encoding.reshape(-1), torch.tensor(marble)),
            atol=1e-5,
            rtol=0,
        )


def test_the_marble_frame_encoder_reads_the_marbles_angle_from_the_observation():
    torch.manual_seed(0)
    board = MLPEncoder(7 + 128, 16, maze_size=128)
    marble = MLPEncoder(7 + 128, 16, maze_size=128, maze_frame="marble")
    marble.load_state_dict(board.state_dict())
    for encoder in (board, marble):
        assert encoder.maze_weight is not None
        torch.nn.init.normal_(encoder.maze_weight)
    marble.maze_weight.data.copy_(board.maze_weight.data)
    state = torch.tensor([[0.0, 0.05, 0.0, 0.0, 0.0, 0.0, 0.0], [0.05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]])
    obs = torch.cat([state, _merl().expand(2, 128)], dim=-1)
    # A marble at angle 0 (x > 0, y = 0) sees the board's frame; at π/2 a quarter turn.
    torch.testing.assert_close(marble(obs[1:]), board(obs[1:]))
    turned = torch.roll(_merl().view(4, ENCODING_BINS), -8, dims=1).reshape(1, -1)
    torch.testing.assert_close(marble(obs[:1]), board(torch.cat([state[:1], turned], dim=-1)))
    assert not torch.allclose(marble(obs[:1]), board(obs[:1]))


def test_maze_frames_are_checked():
    with pytest.raises(ValueError, match=r"unknown maze_frame 'ego'; allowed: board, marble"):
        MLPEncoder(135, 8, 128, "ego")
    with pytest.raises(ValueError, match=r"maze_frame must be one of \('board', 'marble'\)"):
        NetConfig(encoder="mlp", obs_shape=(7,), maze_frame="marble")
    with pytest.raises(ValueError, match="maze_frame 'marble' without num_mazes"):
        PPOConfig.from_flat(task="STG1", obs="state", maze_frame="marble")
    with pytest.raises(ValueError, match="maze_frame applies to state observations only"):
        PPOConfig.from_flat(task="STG1", obs="pixels", num_mazes=10, maze_frame="marble")
    config = PPOConfig.from_flat(task="STG1", obs="state", num_mazes=0, maze_frame="marble")
    net = config.network.build_policy(0)
    assert net.config.maze_frame == "marble" and net.encoder.maze_frame == "marble"
