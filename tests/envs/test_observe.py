"""Observations from states: the scalar fast path of the env equals the batched decoder."""

from __future__ import annotations

import math

import numpy as np

from bimgame.envs.observe import Observer
from bimgame.sim.maze import MazeSpec
from bimgame.sim.physics import MazeSim


def test_scalar_and_batched_board_frame_agree_while_the_board_moves():
    sim = MazeSim(n_marbles=2)
    sim.reset([[0.0892, 0.0], [-0.0892, 0.0]])
    rng = np.random.default_rng(0)
    for _ in range(60):
        sim.step(rng.choice([-1, 0, 1], size=2) * math.radians(1))
        positions, velocities = sim.layout.board_frame(sim.get_state()[None])
        scalar = np.array(sim.layout.board_frame_one(sim.data.qpos, sim.data.qvel))
        np.testing.assert_allclose(scalar[:, :2], positions[0, :, :2], rtol=0, atol=1e-15)
        np.testing.assert_allclose(scalar[:, 2:], velocities[0, :, :2], rtol=0, atol=1e-14)


def test_state_observation_layout_and_pixels_show_the_marble():
    spec = MazeSpec.merl()
    sim = MazeSim(spec)
    sim.reset([[0.05, -0.02]], tilt=(0.01, -0.02))
    state = sim.get_state()[None]
    obs = Observer(spec, 1, "state", layout=sim.layout)(state, np.array([[3]]))
    assert obs.shape == (1, 7) and obs.dtype == np.float32
    np.testing.assert_allclose(obs[0, :2], [0.05, -0.02], atol=1e-6)
    np.testing.assert_allclose(obs[0, 4:6], [0.01, -0.02], atol=1e-7)
    assert obs[0, 6] == 3
    pixels = Observer(spec, 1, "pixels", layout=sim.layout)(state, np.array([[3]]))
    assert pixels.shape == (1, 1, 84, 84)
    renderer = Observer(spec, 1, "pixels").raster
    col, row = renderer.world_to_pixel(np.array([0.05, -0.02]))
    assert pixels[0, 0, int(round(row)), int(round(col))] > 200  # the marble is bright there
