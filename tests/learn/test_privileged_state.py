"""Which privileged state values the encoder's input shows (bimgame.learn.privileged_state): the
auxiliary frame head's targets, checked against the envs' own observations — a value the frames do
not show would be noise for the head to fit."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.learn.nets import NetConfig, RecurrentActorCritic
from bimgame.learn.privileged_state import frame_visible


def test_the_mazes_frame_head_reads_position_and_channel_only():
    assert frame_visible(7) == [0, 1, 6]  # x, y, channel of one marble
    assert frame_visible(12) == [0, 1, 4, 5, 10, 11]  # two marbles
    assert frame_visible(7, "maze", frames=2) == [0, 1, 6]


def _moving_state(env: LabyrinthEnv) -> np.ndarray:
    """A physics state of ``env`` with the marble rolling on a tilted board."""
    env.reset(seed=3)
    for _ in range(12):
        env.step(np.array([1.0, -1.0], dtype=np.float32))
    return env.sim.get_state()


def test_the_labyrinths_frames_show_the_marbles_position_and_with_two_frames_its_velocity():
    state_env, pixel_env = LabyrinthEnv("easy", action_type="continuous"), LabyrinthEnv("easy", obs_mode="pixels")
    moving = _moving_state(state_env)
    nq, nv = state_env.sim.model.nq, state_env.sim.model.nv
    still = moving.copy()
    still[1 + nq : 1 + nq + nv] = 0.0  # the same positions and tilt, nothing moving
    a, b = state_env.observe_state(moving, 0.05), state_env.observe_state(still, 0.05)
    assert np.flatnonzero(a != b).tolist() == [2, 3]  # only vx, vy differ
    assert np.abs(a[2:4]).max() > 0.01 and np.abs(a[4:6]).max() > 0.01  # it moves on a tilted board
    # One frame is the same for both: it shows neither the velocity nor (drawn in the board's frame)
    # the tilt; the head reads the position and what follows from it, all 13 values but those four.
    np.testing.assert_array_equal(pixel_env.observe_state(moving, 0.05), pixel_env.observe_state(still, 0.05))
    one = frame_visible(17, "labyrinth")
    assert one == [0, 1, *range(6, 17)] and not {2, 3, 4, 5} & set(one)
    # Two frames (the previous one drawn where the marble was) show where it is going: vx, vy too.
    assert frame_visible(17, "labyrinth", frames=2) == [0, 1, 2, 3, *range(6, 17)]
    state_env.close()
    pixel_env.close()


def test_a_labyrinth_pixel_network_predicts_what_its_frames_show():
    config = NetConfig(obs_shape=(2, 84, 84), privileged_size=17, aux_heads=True, state_layout="labyrinth",
                       keypoints=True, action_type="continuous", features=16, hidden=16)
    net = RecurrentActorCritic(config)
    assert net.frame_index.tolist() == frame_visible(17, "labyrinth", frames=2)
    assert net.aux_frame.out_features == 15 and net.aux_memory.out_features == 17
    features, hidden = torch.zeros(4, 16), torch.zeros(4, 16)
    loss, parts = net.aux_loss(features, hidden, torch.ones(4, 17))
    assert torch.isfinite(loss) and set(parts) == {"aux_frame", "aux_memory"}


def test_unknown_layouts_and_sizes_are_refused_by_name():
    with pytest.raises(ValueError, match=r"state_layout must be one of \('maze', 'labyrinth'\), got 'brio'"):
        frame_visible(17, "brio")
    with pytest.raises(ValueError, match="the labyrinth's privileged state has 17 values, got privileged_size 7"):
        frame_visible(7, "labyrinth")
    with pytest.raises(ValueError, match=r"NetConfig.state_layout must be one of \('maze', 'labyrinth'\)"):
        NetConfig(privileged_size=17, state_layout="board")
