"""The labyrinth's pixel observation, built for one board or a batch of boards.

The whole board top-down, north up, as uint8 gray frames of ``obs_size`` × ``obs_size`` drawn by a
:class:`~bimgame.sim.labyrinth_render.LabyrinthRaster` on
:func:`~bimgame.sim.labyrinth_render.board_grid`. The single env
(:class:`~bimgame.envs.labyrinth_env.LabyrinthEnv`) and the batched one
(:class:`~bimgame.envs.labyrinth_vector.LabyrinthVectorEnv`) both observe ``obs_mode="pixels"``
through :func:`pixel_observation`, so the two cannot drift apart.

**The marble's motion** (``motion=True``): one frame shows where the marble is, not where it is going,
and a marble ≈ 3.5 px wide moves a fraction of a pixel per step. With ``motion`` the observation is
two frames, the previous observation's and then this one's (a two-frame stack, the usual answer of
pixel-based RL, e.g. DQN's four frames): the pixel counterpart of CyberRunner's observation's
``"motion"`` part (:mod:`bimgame.envs.labyrinth_cyberrunner`). At an episode's first observation
both frames are the same (no motion). The previous frame is drawn again from the marble's previous
position rather than kept: the frame is a pure function of that position (the board is fixed in the
camera's view), so redrawing gives the same pixels and the dataset loader, which re-renders recorded
episodes from stored physics states, needs no frame memory.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from bimgame.sim.labyrinth_render import LabyrinthRaster

__all__ = ["pixel_frames", "pixel_space", "pixel_observation"]


def pixel_frames(motion: bool) -> int:
    """Frames (channels) of one pixel observation: 2 with the marble's ``motion``, else 1."""
    return 2 if motion else 1


def pixel_space(obs_size: int, motion: bool = False) -> spaces.Box:
    """One board's pixel observation space: ``Box(0, 255, (frames, obs_size, obs_size), uint8)``."""
    return spaces.Box(0, 255, shape=(pixel_frames(motion), obs_size, obs_size), dtype=np.uint8)


def pixel_observation(raster: LabyrinthRaster, xy: np.ndarray, previous_xy: np.ndarray | None = None) -> np.ndarray:
    """The pixel observations of N boards whose marbles are at ``xy`` (N, 2) m (board frame):
    (N, 1, S, S) uint8, or with ``previous_xy`` (N, 2) — the marbles' positions at the previous
    observation — (N, 2, S, S), the previous frame first. ``raster``: the board's raster on its pixel
    grid."""
    current = np.stack([raster.gray(p) for p in np.asarray(xy)])[:, None]
    if previous_xy is None:
        return current
    previous = np.stack([raster.gray(p) for p in np.asarray(previous_xy)])[:, None]
    return np.concatenate([previous, current], axis=1)
