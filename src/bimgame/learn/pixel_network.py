"""The pixel network (``obs="pixels"``, the A3C paper's Conv-Conv-FC-LSTM) on either puzzle's frames:
its :class:`~bimgame.learn.nets.NetConfig` and the empty board a ``subtract_background`` network
subtracts from each frame.

Both puzzles' envs observe the whole board top-down, north up, as one :data:`PIXEL_SIZE` ×
:data:`PIXEL_SIZE` uint8 gray frame (their ``obs_size`` default; the learners' envs pass none): the
circular maze through :class:`~bimgame.sim.render.MazeRenderer`, CyberRunner's labyrinth through
:class:`~bimgame.sim.labyrinth_render.LabyrinthRaster` on :func:`~bimgame.sim.labyrinth_render.board_grid`
(the board, 276 × 231 mm, centred in the square; its marble ≈ 3.5 px wide). Each draws the marble on a
fixed picture of the empty board, so either puzzle's empty-board frame is exact (:func:`empty_board_frame`):
subtracted, only the marble remains. With the labyrinth's ``motion`` an observation is two such frames,
the previous one first (:mod:`bimgame.envs.labyrinth_pixels`): the network reads two channels and
subtracts the empty board from each.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bimgame.envs.labyrinth_env import PATH_WIDTH
from bimgame.envs.labyrinth_pixels import pixel_frames
from bimgame.envs.puzzles import PuzzleSpec
from bimgame.learn.nets import NetConfig, maze_background
from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.sim.labyrinth_render import LabyrinthRaster, board_grid

__all__ = ["PIXEL_SIZE", "empty_board_frame", "pixel_net_config"]

#: The side of a pixel observation, both puzzles' (the envs' ``obs_size`` default, the paper's 84).
PIXEL_SIZE = 84


def empty_board_frame(spec: PuzzleSpec, size: int = PIXEL_SIZE) -> np.ndarray:
    """The pixel observation of board ``spec`` without its marble, (1, size, size) uint8: the circular
    maze's (:func:`~bimgame.learn.nets.maze_background`) or the labyrinth's (its raster's static picture:
    floor, printed path, holes, walls, rim and the outside around them)."""
    if isinstance(spec, LabyrinthSpec):
        return np.array(LabyrinthRaster(spec, board_grid(spec, size), path_width=PATH_WIDTH).background[None])
    return maze_background(spec, size)


def pixel_net_config(network: Any, spec: PuzzleSpec, privileged: dict[str, Any]) -> tuple[NetConfig, np.ndarray | None]:
    """The conv network of ``network`` (a :class:`~bimgame.learn.common.NetworkSettings` with
    ``obs="pixels"``, its sizes filled in) on ``spec``'s frames — two per observation with the labyrinth's
    ``motion`` (:mod:`bimgame.envs.labyrinth_pixels`) — and the background it subtracts (its
    :func:`empty_board_frame`, one per frame; None without ``subtract_background``). ``privileged``:
    the auxiliary heads' and asymmetric critic's NetConfig settings ({} without either)."""
    frames = pixel_frames(bool(getattr(network, "motion", False)))
    net_config = NetConfig(
        encoder="conv",
        obs_shape=(frames, PIXEL_SIZE, PIXEL_SIZE),
        features=network.features,
        hidden=network.hidden,
        tilt_input=network.tilt_input,
        action_type=network.action_type,
        keypoints=network.keypoints,
        subtract_background=network.subtract_background,
        precision=network.precision,
        **privileged,
    )
    background = np.repeat(empty_board_frame(spec), frames, axis=0) if network.subtract_background else None
    return net_config, background
