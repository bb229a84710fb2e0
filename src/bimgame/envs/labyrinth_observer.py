"""What the labyrinth env shows of the marble: its observation in each mode, from the marble's kinematics.

:class:`~bimgame.envs.labyrinth_env.LabyrinthEnv` steps the physics and keeps the episode; this module
turns a moment of it — the marble's board-frame position and velocity, the board's tilt and the
marble's progress along the path — into the observation of the env's ``obs_mode``: the state vector
(with the holes and walls around the marble when ``surroundings``), top-down pixels, or CyberRunner's
observation (a crop centred on the marble, the tilt, the path ahead), the last two with the marble's
``motion`` when asked. One place for it, so that a step, a reset and a recorded physics state
re-read in another mode (:meth:`~bimgame.envs.labyrinth_env.LabyrinthEnv.observe_state`) give the
same observation.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from bimgame.envs.labyrinth_cyberrunner import (
    CROP_PIXEL,
    PATH_AHEAD,
    PATH_SPACING,
    cyberrunner_observation,
    cyberrunner_space,
    flatten_cyberrunner,
    marble_motion,
)
from bimgame.envs.labyrinth_pixels import pixel_observation, pixel_space
from bimgame.envs.labyrinth_surroundings import NO_HOLE, RAY_RANGE, SURROUNDING_HOLES, WALL_RAYS, Surroundings
from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.sim.labyrinth_render import LabyrinthRaster, board_grid, sheet_grid
from bimgame.sim.labyrinth_tracker import ScalarPathProgress

__all__ = ["LabyrinthObserver"]


class LabyrinthObserver:
    """The observations of ``obs_mode`` on ``board`` (the env's arguments of the same names; their
    checks are the env's). ``tracker`` gives the path points ahead of a progress."""

    def __init__(
        self,
        board: LabyrinthSpec,
        tracker: ScalarPathProgress,
        *,
        obs_mode: str,
        obs_size: int,
        path_width: float,
        surroundings: bool,
        motion: bool,
        control_hz: int,
    ):
        self.board, self.tracker = board, tracker
        self.obs_mode, self.obs_size, self.motion, self.control_hz = obs_mode, obs_size, motion, control_hz
        self.surroundings = Surroundings(board) if surroundings else None
        #: The drawn board of pixels (the whole board) and CyberRunner's observation (a sheet at 1 mm per pixel).
        self.raster: LabyrinthRaster | None = None
        if obs_mode == "pixels":
            self.raster = LabyrinthRaster(board, board_grid(board, obs_size), path_width=path_width)
        elif obs_mode in ("cyberrunner", "cyberrunner_flat"):
            self.raster = LabyrinthRaster(board, sheet_grid(board, CROP_PIXEL), path_width=path_width)

    def space(self) -> spaces.Space:
        """The observation space of the mode."""
        hx, hy = self.board.board_size[0] / 2, self.board.board_size[1] / 2
        if self.obs_mode == "pixels":
            return pixel_space(self.obs_size, self.motion)
        if self.obs_mode in ("cyberrunner", "cyberrunner_flat"):
            return cyberrunner_space(self.obs_mode == "cyberrunner_flat", self.motion)
        tilt = self.board.max_tilt + 0.01
        span = np.tile([2 * hx, 2 * hy], PATH_AHEAD)
        low = np.concatenate([[-hx, -hy, -np.inf, -np.inf, -tilt, -tilt, 0.0], -span]).astype(np.float32)
        high = np.concatenate([[hx, hy, np.inf, np.inf, tilt, tilt, 1.0], span]).astype(np.float32)
        if self.surroundings is not None:  # hole offsets (a missing hole's is NO_HOLE), then distances
            far = max(2 * hx, 2 * hy, *NO_HOLE)
            low = np.concatenate([low, np.full(2 * SURROUNDING_HOLES, -far), np.zeros(WALL_RAYS)], dtype=np.float32)
            high = np.concatenate([high, np.full(2 * SURROUNDING_HOLES, far), np.full(WALL_RAYS, RAY_RANGE)])
        return spaces.Box(low, high.astype(np.float32), dtype=np.float32)

    def observe(self, kinematics: tuple[float, ...], tilt: np.ndarray, progress: float, previous_xy: np.ndarray) -> Any:
        """The observation of the marble's board-frame ``kinematics`` (x, y, vx, vy), the board's
        ``tilt`` (rad) and the marble's path ``progress`` (m); ``previous_xy`` its position at the
        previous observation (the ``motion``)."""
        x, y = kinematics[:2]
        if self.obs_mode == "pixels":
            assert self.raster is not None
            return pixel_observation(self.raster, np.array([[x, y]]), previous_xy[None] if self.motion else None)[0]
        if self.obs_mode == "state":
            head = self.state_values(kinematics, tilt, progress)
            return head if self.surroundings is None else np.concatenate([head, self.surroundings.of(np.array([x, y]))])
        assert self.raster is not None
        xy = np.array([[x, y]])
        motion = marble_motion(xy, previous_xy[None], self.control_hz) if self.motion else None
        obs = cyberrunner_observation(
            self.raster,
            self.board.board_size,
            xy,
            np.asarray(tilt)[None],
            np.array([self.path_relative(x, y, progress)]),
            motion,
        )
        obs = {key: value[0] for key, value in obs.items()}
        return flatten_cyberrunner(obs) if self.obs_mode == "cyberrunner_flat" else obs

    def state_values(self, kinematics: tuple[float, ...], tilt: np.ndarray, progress: float) -> np.ndarray:
        """The 17 state values: x, y, vx, vy, the tilt, the progress as a fraction of the path, then
        the 5 path points ahead relative to the marble (:data:`PATH_SPACING` apart)."""
        x, y, vx, vy = kinematics
        relative = self.path_relative(x, y, progress)
        return np.array([x, y, vx, vy, tilt[0], tilt[1], progress / self.board.path.length, *relative], np.float32)

    def path_relative(self, x: float, y: float, progress: float) -> list[float]:
        """The 5 path points ahead of ``progress`` (m), :data:`PATH_SPACING` apart, relative to the
        marble at (``x``, ``y``), flattened."""
        ahead = self.tracker.points_ahead(progress, PATH_AHEAD, PATH_SPACING)
        return [v for px, py in ahead for v in (px - x, py - y)]
