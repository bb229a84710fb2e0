"""Top-down raster of the board in the board frame: the RL pixel observation and video frames.

Why a numpy raster rather than MuJoCo's OpenGL renderer? The pixel observation is a camera fixed
to the board looking straight down, so it is a 2-D picture: a static background (floor, goal
region, walls with their gates, rim) plus one disc per marble. The background is rasterised once,
from the exact geometry of the :class:`~bimgame.sim.maze.MazeSpec` (true circles and radial gate edges,
not the box pieces that approximate them in the physics model), antialiased by supersampling.
Each frame then only copies the background and blends a few dozen pixels around each marble, which
costs microseconds instead of the milliseconds of an OpenGL render plus read-back, vectorises over a
batch of environments, and needs no GL backend (EGL/OSMesa) on headless machines.

Pixel grid and antialiasing: :mod:`bimgame.sim.render_grid`. In short, the image spans the board
out to the rim's outer edge, "north up" (row 0 is +y, column 0 is -x), with pixel ``[i, j]``'s centre
at continuous pixel coordinates ``(col, row) = (j, i)``; the background is supersampled
(``SUPERSAMPLE`` × ``SUPERSAMPLE`` sub-samples per pixel) and marbles are blended by the fraction of
each pixel they cover, so sub-pixel marble motion changes the image smoothly.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence

import numpy as np

from bimgame.sim.maze import MazeSpec
from bimgame.sim.render_grid import SUPERSAMPLE, PixelGrid, background_coverage, blend_gray
from bimgame.sim.render_rings import RingSamples

__all__ = [
    "MazeRenderer",
    "FLOOR",
    "GOAL",
    "WALL",
    "MARBLE",
    "FLOOR_RGB",
    "GOAL_RGB",
    "WALL_RGB",
    "MARBLE_RGB",
    "MARBLE_EDGE_RGB",
    "MARBLE_OUTLINE_RGB",
    "TILT_GAUGE_RGB",
    "TILT_ARROW_RGB",
    "SUPERSAMPLE",
    "DEFAULT_RGB_SIZE",
]

# Grayscale levels of the observation (uint8). Dark floor, a slightly lighter goal region so the
# agent can see the target, mid-grey walls/rim (and everything outside the rim), white marbles:
# the marble contrasts with everything it can touch.
FLOOR: int = 30
GOAL: int = 70
WALL: int = 150
MARBLE: int = 255

# Colours of video frames (RGB uint8).
FLOOR_RGB: tuple[int, int, int] = (64, 84, 72)  # green-grey felt
GOAL_RGB: tuple[int, int, int] = (178, 128, 52)  # amber goal region
WALL_RGB: tuple[int, int, int] = (206, 206, 200)  # light grey walls, rim and frame
MARBLE_RGB: tuple[int, int, int] = (238, 241, 246)  # steel: bright centre ...
MARBLE_EDGE_RGB: tuple[int, int, int] = (128, 134, 146)  # ... shading to darker steel ...
MARBLE_OUTLINE_RGB: tuple[int, int, int] = (34, 37, 44)  # ... with a dark outline
TILT_GAUGE_RGB: tuple[int, int, int] = (70, 72, 78)  # tilt indicator ring and hub
TILT_ARROW_RGB: tuple[int, int, int] = (200, 40, 40)  # tilt indicator: downhill direction

DEFAULT_RGB_SIZE: int = 480

# Levels of the background's regions, in the order of its coverage's labels (floor, goal, wall).
_GRAY_LEVELS = np.array([FLOOR, GOAL, WALL], dtype=np.float64)
_RGB_LEVELS = np.array([FLOOR_RGB, GOAL_RGB, WALL_RGB], dtype=np.float64)


class MazeRenderer:
    """Numpy raster of a :class:`~bimgame.sim.maze.MazeSpec` seen from above, in the board frame.

    ``gray`` draws (batches of) ``size`` × ``size`` uint8 observations; ``rgb`` draws colour video
    frames at any size (default :data:`DEFAULT_RGB_SIZE`). See :mod:`bimgame.sim.render_grid` for the
    pixel convention. Backgrounds are rasterised once (the grayscale one in ``__init__``, each RGB size
    on first use) and cached.
    """

    def __init__(self, spec: MazeSpec, size: int = 84):
        if not isinstance(spec, MazeSpec):
            raise TypeError(f"spec must be a MazeSpec, got {type(spec).__name__}")
        if not (isinstance(size, (int, np.integer)) and size >= 1):
            raise ValueError(f"size must be a positive integer, got {size!r}")
        self.spec = spec
        self.size = int(size)
        self.extent = float(spec.rim_radius + spec.rim_thickness)
        self._grid = PixelGrid.build(spec, self.size, self.extent)
        self._set_background(background_coverage(spec, self.size, self.extent))
        self._grids: dict[int, PixelGrid] = {self.size: self._grid}
        self._rgb_backgrounds: dict[int, np.ndarray] = {}
        self._rings: RingSamples | None = None

    def _set_background(self, fractions: np.ndarray) -> None:
        self._fractions = fractions  # the coverage for_maze starts from (any maze's on the board)
        gray = np.rint(np.tensordot(_GRAY_LEVELS, fractions, axes=1))
        self._background = np.clip(gray, 0, 255).astype(np.uint8)
        self._background.flags.writeable = False

    def for_maze(self, spec: MazeSpec) -> MazeRenderer:
        """A renderer of ``spec``, a maze on this renderer's board (same radii and marble, other
        gates), at the same size: its background is redrawn only where the walls' rings are, the
        same pixels as ``MazeRenderer(spec, size)`` (a test compares them) at about a hundredth of the cost
        (:class:`~bimgame.sim.render_rings.RingSamples`)."""
        if [(w.inner_radius, w.outer_radius) for w in spec.walls] != [
            (w.inner_radius, w.outer_radius) for w in self.spec.walls
        ] or (spec.rim_radius, spec.rim_thickness, spec.marble_radius) != (
            self.spec.rim_radius,
            self.spec.rim_thickness,
            self.spec.marble_radius,
        ):
            raise ValueError("for_maze draws mazes of the same board: the same walls' radii, rim and marble")
        if self._rings is None:
            self._rings = RingSamples.build(self.spec, self.size, self.extent, SUPERSAMPLE)
        other = copy.copy(self)  # its _fractions stay this board's: for_maze redraws every ring pixel
        other.spec = spec
        other._rgb_backgrounds = {}
        # Only the ring pixels change. Their fractions are multiples of 1/s², so the grey levels'
        # weighted sums are exact whatever the order: the pixels of _set_background on the whole image.
        background = self._background.copy()
        levels = _GRAY_LEVELS @ self._rings.ring_fractions(spec)
        background.reshape(-1)[self._rings.pixels] = np.clip(np.rint(levels), 0, 255).astype(np.uint8)
        background.flags.writeable = False
        other._background = background
        return other

    # ------------------------------------------------------------------ geometry
    @property
    def metres_per_pixel(self) -> float:
        """Width (m) of one pixel of the grayscale observation: ``2 * extent / size``."""
        return self._grid.metres_per_pixel

    @property
    def marble_radius_px(self) -> float:
        """Marble radius in observation pixels."""
        return self._grid.radius_px

    @property
    def background(self) -> np.ndarray:
        """The static grayscale background, (size, size) uint8 (read-only)."""
        return self._background

    def world_to_pixel(self, xy: np.ndarray, size: int | None = None) -> np.ndarray:
        """Continuous pixel coordinates ``(col, row)`` of board points ``xy`` (m), shape (..., 2).

        Pixel ``[i, j]``'s centre is at ``(col, row) = (j, i)``; row 0 is +y (top), column 0 is -x
        (left). ``size`` selects the image size (default: the observation size).
        """
        xy = np.asarray(xy, dtype=np.float64)
        if xy.ndim == 0 or xy.shape[-1] != 2:
            raise ValueError(f"xy must have shape (..., 2), got {xy.shape}")
        return self._grid_for(size).to_pixel(xy)

    def pixel_to_world(self, colrow: np.ndarray, size: int | None = None) -> np.ndarray:
        """Inverse of :meth:`world_to_pixel`: board points (m) of pixel coordinates (..., 2)."""
        colrow = np.asarray(colrow, dtype=np.float64)
        if colrow.ndim == 0 or colrow.shape[-1] != 2:
            raise ValueError(f"colrow must have shape (..., 2), got {colrow.shape}")
        grid = self._grid_for(size)
        mpp = grid.metres_per_pixel
        x = (colrow[..., 0] + 0.5) * mpp - grid.extent
        y = grid.extent - (colrow[..., 1] + 0.5) * mpp
        return np.stack([x, y], axis=-1)

    def _grid_for(self, size: int | None) -> PixelGrid:
        """Pixel geometry at ``size`` (None: the observation size), built once per size."""
        if size is None:
            return self._grid
        if not (isinstance(size, (int, np.integer)) and size >= 1):
            raise ValueError(f"size must be a positive integer, got {size!r}")
        grid = self._grids.get(int(size))
        if grid is None:
            grid = self._grids[int(size)] = PixelGrid.build(self.spec, int(size), self.extent)
        return grid

    # ------------------------------------------------------------------ grayscale observations
    def gray(
        self, marble_xy: np.ndarray, out: np.ndarray | None = None, backgrounds: np.ndarray | None = None
    ) -> np.ndarray:
        """Grayscale frame(s) with marbles at board positions ``marble_xy`` (m).

        Args:
            marble_xy: (n_marbles, 2) for one frame or (B, n_marbles, 2) for a batch.
            out: optional C-contiguous uint8 array of the result's shape to draw into.
            backgrounds: optional (B, size, size) uint8, each frame's own background (the
                :attr:`background` of another maze on the same board); default :attr:`background`.

        Returns:
            (size, size) or (B, size, size) uint8 (``out`` if given). Marbles are composited in
            order (a later marble is drawn over an earlier one); parts outside the image are
            clipped and non-finite positions draw nothing.
        """
        xy = np.asarray(marble_xy)
        if xy.ndim not in (2, 3) or xy.shape[-1] != 2:
            raise ValueError(f"marble_xy must have shape (n_marbles, 2) or (B, n_marbles, 2), got {xy.shape}")
        single = xy.ndim == 2
        if single:
            xy = xy[None]
        batch, n_marbles = xy.shape[0], xy.shape[1]
        s = self.size
        shape = (s, s) if single else (batch, s, s)
        if out is None:
            out = np.empty(shape, dtype=np.uint8)
        elif (
            not isinstance(out, np.ndarray) or out.shape != shape or out.dtype != np.uint8 or not out.flags.c_contiguous
        ):
            raise ValueError(
                f"out must be a C-contiguous uint8 array of shape {shape}, got "
                f"{getattr(out, 'dtype', type(out).__name__)} {getattr(out, 'shape', '')}"
            )
        if backgrounds is None:
            np.copyto(out, self._background)
        elif backgrounds.shape == (batch, s, s):
            np.copyto(out, backgrounds[0] if single else backgrounds)
        else:
            raise ValueError(f"backgrounds must have shape {(batch, s, s)} (one per frame), got {backgrounds.shape}")
        if n_marbles == 0 or batch == 0:
            return out
        grid = self._grid
        if batch == 1:
            # One frame: scalar set-up per marble and a square window blended through a view
            # (fewer numpy calls on tiny arrays, no fancy indexing).
            image = out if single else out[0]
            extent, inv = grid.extent, 1.0 / grid.metres_per_pixel
            for x, y in xy[0].tolist():
                window = grid.lut_square((x + extent) * inv - 0.5, (extent - y) * inv - 0.5)
                if window is not None:
                    rows, cols, uncovered = window
                    view = image[rows, cols]
                    value = view.astype(np.float64)
                    value -= MARBLE
                    value *= uncovered
                    value += MARBLE + 0.5
                    np.copyto(view, value, casting="unsafe")
            return out
        pix = grid.to_pixel(xy)  # (B, n, 2)
        centre = np.rint(pix)
        k = grid.half_window
        inside = bool(centre.min() >= k and centre.max() <= s - 1 - k)  # False for NaN
        flat_out = out.reshape(-1)
        frame_base = (np.arange(batch, dtype=np.int64) * (s * s))[:, None]
        for m in range(n_marbles):
            flat, valid = grid.window(centre[:, m, 0], centre[:, m, 1], inside)
            u = grid.lut_disc(pix[:, m, 0], pix[:, m, 1], centre[:, m, 0], centre[:, m, 1])
            flat += frame_base
            if valid is not None:
                flat = flat[valid]
                u = u[valid]
            blend_gray(flat_out, flat, u, MARBLE)
        return out

    # ------------------------------------------------------------------ colour video frames
    def background_rgb(self, size: int | None = None) -> np.ndarray:
        """The static RGB background (size, size, 3) uint8 at ``size`` (default
        :data:`DEFAULT_RGB_SIZE`), rasterised on first use and cached; read-only."""
        grid = self._grid_for(DEFAULT_RGB_SIZE if size is None else size)
        background = self._rgb_backgrounds.get(grid.size)
        if background is None:
            fractions = background_coverage(self.spec, grid.size, self.extent)
            rgb = np.rint(np.einsum("kc,kij->ijc", _RGB_LEVELS, fractions))
            background = np.clip(rgb, 0, 255).astype(np.uint8)
            background.flags.writeable = False
            self._rgb_backgrounds[grid.size] = background
        return background

    def rgb(
        self, marble_xy: np.ndarray, size: int | None = None, tilt: Sequence[float] | np.ndarray | None = None
    ) -> np.ndarray:
        """A colour frame (size, size, 3) uint8 with marbles at ``marble_xy`` (n_marbles, 2) (m).

        ``size`` defaults to :data:`DEFAULT_RGB_SIZE`; each size's background is rasterised once.

        Marbles are steel discs shaded from a bright centre to a darker edge with a dark outline
        (radially symmetric, so the drawn marble's centroid is its position). If ``tilt`` — the
        board's tilt (rad) about x and y — is given, a gauge in the bottom-right corner shows the
        downhill direction in the board frame, its arrow's length proportional to the tilt
        magnitude (full length at ``spec.max_tilt``).
        """
        xy = np.asarray(marble_xy, dtype=np.float64)
        if xy.ndim != 2 or xy.shape[-1] != 2:
            raise ValueError(f"marble_xy must have shape (n_marbles, 2), got {xy.shape}")
        grid = self._grid_for(DEFAULT_RGB_SIZE if size is None else size)
        img = self.background_rgb(grid.size).copy()
        if tilt is not None:
            self._draw_tilt_gauge(img, tilt)
        pix = grid.to_pixel(xy)
        radius = grid.radius_px
        outline = max(1.0, 0.12 * radius)
        body_in = np.array(MARBLE_RGB, dtype=np.float64)
        body_out = np.array(MARBLE_EDGE_RGB, dtype=np.float64)
        edge = np.array(MARBLE_OUTLINE_RGB, dtype=np.float64)
        for x, y in pix.tolist():
            window = grid.square(x, y)
            if window is None:
                continue
            rows, cols, d = window
            d = d[..., None]
            # Steel: bright centre shading to a darker edge, then a dark outline ring.
            colour = body_in + (body_out - body_in) * np.minimum(d / max(radius, 1e-9), 1.0) ** 2
            colour += (edge - colour) * np.clip(d - (radius - outline) + 0.5, 0.0, 1.0)
            coverage = 1.0 - grid.uncovered(d)
            view = img[rows, cols]
            current = view.astype(np.float64)
            view[...] = np.rint(current + (colour - current) * coverage)
        return img

    def _draw_tilt_gauge(self, img: np.ndarray, tilt: Sequence[float] | np.ndarray) -> None:
        """Draw the tilt indicator into the bottom-right corner of ``img`` (in place).

        Downhill direction in the board frame: gravity (0, 0, -1) expressed in the board frame of
        a board rotated by ``Rx(tilt_x) @ Ry(tilt_y)`` has in-plane part
        ``(cos(tilt_x) sin(tilt_y), -sin(tilt_x))``.
        """
        t = np.asarray(tilt, dtype=np.float64).reshape(-1)
        if t.shape != (2,):
            raise ValueError(f"tilt must be (tilt_x, tilt_y) in radians, got shape {np.shape(tilt)}")
        size = img.shape[0]
        rho = 0.065 * size  # gauge radius (px); fits in the corner outside the rim
        centre = size - 1 - (rho + 0.02 * size)
        gx = math.cos(t[0]) * math.sin(t[1])
        gy = -math.sin(t[0])
        slope = math.hypot(gx, gy)  # sin of the tilt angle from horizontal
        if not math.isfinite(slope):
            slope = 0.0  # unknown tilt: the gauge without an arrow
        length = rho * min(1.0, math.asin(min(1.0, slope)) / self.spec.max_tilt)
        if slope > 0:
            ex, ey = centre + length * gx / slope, centre - length * gy / slope
        else:
            ex, ey = centre, centre
        lo = max(0, math.floor(centre - rho - 3))
        hi = min(size, math.ceil(centre + rho + 4))
        jj, ii = np.meshgrid(np.arange(lo, hi, dtype=np.float64), np.arange(lo, hi, dtype=np.float64))
        patch = img[lo:hi, lo:hi].astype(np.float64)
        width = max(1.0, 0.012 * size)

        def paint(coverage: np.ndarray, colour: tuple[int, int, int]) -> None:
            np.clip(coverage, 0.0, 1.0, out=coverage)
            patch[...] += (np.asarray(colour, dtype=np.float64) - patch) * coverage[..., None]

        r = np.hypot(jj - centre, ii - centre)
        paint(width / 2 + 0.5 - np.abs(r - rho), TILT_GAUGE_RGB)  # ring
        paint(1.5 * width + 0.5 - r, TILT_GAUGE_RGB)  # hub
        # Arrow: segment from the hub to (ex, ey) and a disc at its tip.
        vx, vy = ex - centre, ey - centre
        seg2 = vx * vx + vy * vy
        if seg2 > 0:
            s = np.clip(((jj - centre) * vx + (ii - centre) * vy) / seg2, 0.0, 1.0)
            dist = np.hypot(jj - (centre + s * vx), ii - (centre + s * vy))
            paint(width / 2 + 0.5 - dist, TILT_ARROW_RGB)
            paint(1.5 * width + 0.5 - np.hypot(jj - ex, ii - ey), TILT_ARROW_RGB)
        img[lo:hi, lo:hi] = np.rint(patch)
