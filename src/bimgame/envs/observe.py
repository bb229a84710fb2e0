"""Observations computed from physics states, batched: the same code serves the single env, the
batched vector env and anything that re-renders stored trajectories from their states."""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from bimgame.envs.gate_bearings import BEARING_VALUES, gate_bearings_size
from bimgame.envs.mazes import maze_encoding, maze_encoding_size, maze_raster
from bimgame.sim.layout import StateLayout
from bimgame.sim.maze import MazeSpec
from bimgame.sim.render import MazeRenderer

__all__ = ["OBS_MODES", "Observer"]

OBS_MODES = ("pixels", "state")


class Observer:
    """Maps physics states (B, state_size) and task channels (B, n) to observations.

    ``pixels``: (B, 1, size, size) uint8 from :class:`~bimgame.sim.render.MazeRenderer`.
    ``state``: (B, 4n + 2 + n) float32 — per marble x, y, vx, vy (board frame, m and m/s), then
    tilt about x and y (rad), then each marble's channel; with ``maze_encoding``, then the maze's
    :func:`~bimgame.envs.mazes.maze_encoding` (each row's, given to :meth:`from_kinematics`); with
    ``gate_bearings`` too, then the first marble's :mod:`~bimgame.envs.gate_bearings` (given to
    :meth:`from_kinematics`: they change every step).
    """

    def __init__(
        self,
        spec: MazeSpec,
        n_marbles: int,
        obs_mode: str,
        *,
        obs_size: int = 84,
        layout: StateLayout | None = None,
        maze_encoding: bool = False,
        board: MazeSpec | None = None,
        gate_bearings: bool = False,
    ):
        if obs_mode not in OBS_MODES:
            raise ValueError(f"unknown obs_mode {obs_mode!r}; allowed: {', '.join(OBS_MODES)}")
        if not (isinstance(obs_size, (int, np.integer)) and 16 <= obs_size <= 1024):
            raise ValueError(f"obs_size must be an integer in 16..1024, got {obs_size!r}")
        self.spec = spec
        self.n_marbles = n_marbles
        self.obs_mode = obs_mode
        self.obs_size = int(obs_size)
        self.layout = layout
        self.encoding_size = maze_encoding_size(spec) if maze_encoding and obs_mode == "state" else 0
        self.bearings_size = gate_bearings_size(spec) if gate_bearings and self.encoding_size else 0
        #: The board the mazes :meth:`set_maze` shows share (their rasters are drawn from its).
        self.board = board
        self._raster: MazeRenderer | None = None
        self.space: spaces.Box
        if obs_mode == "pixels":
            self.space = spaces.Box(0, 255, shape=(1, self.obs_size, self.obs_size), dtype=np.uint8)
        else:
            extent = spec.rim_radius + spec.rim_thickness
            n = n_marbles
            low = np.concatenate(
                [np.tile([-extent, -extent, -np.inf, -np.inf], n), [-spec.max_tilt - 0.01] * 2, np.zeros(n)]
            ).astype(np.float32)
            high = np.concatenate(
                [
                    np.tile([extent, extent, np.inf, np.inf], n),
                    [spec.max_tilt + 0.01] * 2,
                    np.full(n, spec.outermost_channel),
                ]
            ).astype(np.float32)
            low = np.concatenate([low, np.zeros(self.encoding_size, dtype=np.float32)])
            high = np.concatenate([high, np.ones(self.encoding_size, dtype=np.float32)])
            if self.bearings_size:  # sin, cos, half-width (bins) per wall
                walls = self.bearings_size // BEARING_VALUES
                low = np.concatenate([low, np.tile(np.array([-1, -1, 0], dtype=np.float32), walls)])
                high = np.concatenate([high, np.tile(np.array([1, 1, 16], dtype=np.float32), walls)])
            self.space = spaces.Box(low, high, dtype=np.float32)

    @property
    def raster(self) -> MazeRenderer:
        """The pixel renderer (built on first use: state observations never need it)."""
        if self._raster is None:
            self._raster = maze_raster(self.spec, self.obs_size, self.board)
        return self._raster

    def set_maze(self, spec: MazeSpec) -> None:
        """Observe ``spec`` from now on (a maze on the same board: its raster is drawn on first use)."""
        if spec is not self.spec:
            self.spec = spec
            self._raster = None

    def __call__(
        self,
        states: np.ndarray,
        channels: np.ndarray,
        layout: StateLayout | None = None,
    ) -> np.ndarray:
        layout = layout or self.layout
        if layout is None:
            raise ValueError("Observer needs the model's StateLayout (pass layout=)")
        positions, velocities = layout.board_frame(states)
        return self.from_kinematics(positions, velocities, states[:, layout.tilt], channels)

    def from_kinematics(
        self,
        positions: np.ndarray,
        velocities: np.ndarray,
        tilt: np.ndarray,
        channels: np.ndarray,
        *,
        encodings: np.ndarray | None = None,
        backgrounds: np.ndarray | None = None,
        bearings: np.ndarray | None = None,
    ) -> np.ndarray:
        """Observations from board-frame marble positions and velocities (B, n, 3), board tilt
        (B, 2) and channels (B, n), for callers that already decoded their states. When rows show
        different mazes: ``encodings`` (B, :attr:`encoding_size`), each row's
        :func:`~bimgame.envs.mazes.maze_encoding`, and ``backgrounds`` (B, size, size), each row's
        raster background; by default every row shows :attr:`spec`. ``bearings`` (B,
        :attr:`bearings_size`): each row's gate bearings, needed when the observations have them."""
        batch = positions.shape[0]
        if self.obs_mode == "pixels":
            return self.raster.gray(positions[..., :2], backgrounds=backgrounds)[:, None]
        per_marble = np.concatenate([positions[..., :2], velocities[..., :2]], axis=-1)
        n = self.n_marbles
        encoded = 5 * n + 2 + self.encoding_size
        out = np.empty((batch, encoded + self.bearings_size), dtype=np.float32)
        out[:, : 4 * n] = per_marble.reshape(batch, -1)
        out[:, 4 * n : 4 * n + 2] = tilt
        out[:, 4 * n + 2 : 5 * n + 2] = channels
        if self.encoding_size:
            out[:, 5 * n + 2 : encoded] = maze_encoding(self.spec) if encodings is None else encodings
        if self.bearings_size:
            if bearings is None:
                raise ValueError("these observations end with gate bearings: pass bearings=")
            out[:, encoded:] = bearings
        return out
