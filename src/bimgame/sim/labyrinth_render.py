"""Top-down raster of a labyrinth (:class:`~bimgame.sim.labyrinth.LabyrinthSpec`): the pixel
observations of the labyrinth env and its video frames, drawn with numpy from the marble's position.

Why numpy, as for the circular maze (:mod:`bimgame.sim.render`): a camera fixed to the board and
looking straight down sees a static picture (floor, the printed path, holes, walls, rim) plus one
disc, the marble. The static part is rasterised once per board and pixel grid (:func:`background`,
cached), each frame copies it and blends the few pixels around the marble: microseconds, no OpenGL.

Pixel grid (:class:`RasterGrid`). "North up" as :mod:`bimgame.sim.render`: row 0 is the top (+y),
column 0 the left (-x); continuous pixel coordinates ``(col, row)`` put the centre of pixel
``[i, j]`` at ``(j, i)``, so board point ``(x, y)`` is at
``col = (x - left) / pixel - 0.5``, ``row = (top - y) / pixel - 0.5``. Two grids are used:

- :func:`board_grid`: a ``size`` × ``size`` square showing the whole board with its rim, centred;
  the board is wider (x) than tall, so bands above and below show the outside;
- :func:`sheet_grid`: the board at a fixed scale (1 mm per pixel by default) with a margin of
  outside around the rim, from which :meth:`LabyrinthRaster.crop` cuts CyberRunner's 64 × 64
  window centred on the marble (``cyberrunner_state_estimation/core/measurements.py``: the sub-image
  samples the board at ``1e-3 * mgrid[-32:32, -32:32]`` m around the ball, north up).

Layers, from the bottom: outside (beyond the rim), floor (the playable area), the path (a line
``path_width`` wide through the waypoints, as printed on the real board), holes (discs of
``hole_radius``), walls and rim, then the marble. Rectangles (floor, walls, rim) are antialiased by
their exact pixel coverage, discs and path lines by ``SUPERSAMPLE`` × ``SUPERSAMPLE`` sub-samples;
the marble by ``clip(R + 0.5 - d, 0, 1)`` as the circular maze's, looked up for its position
quantised to 1/:data:`LUT_STEPS` of a pixel. Gray levels (:data:`GRAY`) make
the marble the only pure white and holes the only black, walls light, the floor mid-gray.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence

import numpy as np

from bimgame.sim.labyrinth import LabyrinthSpec

__all__ = [
    "GRAY",
    "RGB",
    "SUPERSAMPLE",
    "LUT_STEPS",
    "RasterGrid",
    "LabyrinthRaster",
    "board_grid",
    "sheet_grid",
    "background",
]

#: Sub-samples per axis for the antialiasing of discs (holes) and path lines.
SUPERSAMPLE = 4
#: The marble's sub-pixel position is quantised to 1/LUT_STEPS of a pixel (its coverage is looked up).
LUT_STEPS = 32
#: Gray level of each layer (uint8): the marble is the only 255, a hole's centre the only 0.
GRAY: dict[str, tuple[int, ...]] = {
    "outside": (60,),
    "floor": (150,),
    "path": (110,),
    "hole": (0,),
    "wall": (215,),
    "marble": (255,),
}
#: Colours of :meth:`LabyrinthRaster.rgb` (video frames): a wooden board, a blue marble (CyberRunner
#: played with blue marbles, ``docs/01_hardware_setup.md``).
RGB: dict[str, tuple[int, ...]] = {
    "outside": (45, 45, 45),
    "floor": (222, 190, 140),
    "path": (70, 60, 50),
    "hole": (10, 10, 10),
    "wall": (150, 100, 55),
    "marble": (40, 90, 230),
}
_LAYERS = ("floor", "path", "hole", "wall")


@dataclasses.dataclass(frozen=True)
class RasterGrid:
    """A pixel grid over the board frame: ``width`` × ``height`` pixels of ``pixel`` metres, the
    top-left corner of pixel ``[0, 0]`` at board point ``(left, top)`` (m)."""

    width: int
    height: int
    left: float
    top: float
    pixel: float

    def to_pixel(self, xy: np.ndarray) -> np.ndarray:
        """Continuous pixel coordinates ``(col, row)`` (..., 2) of board points ``xy`` (..., 2) (m)."""
        p = np.asarray(xy, dtype=np.float64)
        return np.stack([(p[..., 0] - self.left) / self.pixel - 0.5, (self.top - p[..., 1]) / self.pixel - 0.5], -1)

    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Pixel edges: x of the ``width + 1`` column borders (left to right), y of the ``height + 1``
        row borders (top to bottom), in metres."""
        return (
            self.left + np.arange(self.width + 1) * self.pixel,
            self.top - np.arange(self.height + 1) * self.pixel,
        )


def board_grid(spec: LabyrinthSpec, size: int) -> RasterGrid:
    """A ``size`` × ``size`` grid whose square just holds the board and its rim, centred."""
    extent = max(spec.board_size) / 2 + spec.rim_thickness
    return RasterGrid(int(size), int(size), -extent, extent, 2 * extent / size)


def sheet_grid(spec: LabyrinthSpec, pixel: float = 1e-3, margin: int = 33) -> RasterGrid:
    """The board and rim at ``pixel`` metres per pixel, with ``margin`` pixels of outside all round
    (enough for a crop of up to ``2 * margin - 2`` pixels centred anywhere on the board)."""
    hx, hy = spec.board_size[0] / 2 + spec.rim_thickness, spec.board_size[1] / 2 + spec.rim_thickness
    nx, ny = math.ceil(2 * hx / pixel - 1e-9), math.ceil(2 * hy / pixel - 1e-9)
    return RasterGrid(
        nx + 2 * margin, ny + 2 * margin, -nx * pixel / 2 - margin * pixel, ny * pixel / 2 + margin * pixel, pixel
    )


def _rect_coverage(grid: RasterGrid, rects: np.ndarray) -> np.ndarray:
    """Exact area fraction (height, width) of each pixel inside the union of axis-aligned rectangles
    ``(x_min, y_min, x_max, y_max)`` (overlaps count once where they do not share a pixel)."""
    xe, ye = grid.edges()
    out = np.zeros((grid.height, grid.width), dtype=np.float32)
    for x0, y0, x1, y1 in rects:
        ox = np.clip(np.minimum(xe[1:], x1) - np.maximum(xe[:-1], x0), 0.0, None) / grid.pixel
        oy = np.clip(np.minimum(ye[:-1], y1) - np.maximum(ye[1:], y0), 0.0, None) / grid.pixel
        cols, rows = np.nonzero(ox)[0], np.nonzero(oy)[0]
        if len(cols) and len(rows):
            block = (oy[rows, None] * ox[None, cols]).astype(np.float32)
            window = out[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]
            np.maximum(window, block, out=window)
    return out


def _window_samples(grid: RasterGrid, lo: np.ndarray, hi: np.ndarray):
    """Sub-sample points of the pixels overlapping the box ``lo``..``hi`` (board m): the row and
    column slices and the sample coordinates x, y (rows, cols, S, S), or None if outside the grid."""
    (c0, r1), (c1, r0) = grid.to_pixel(np.asarray(lo)), grid.to_pixel(np.asarray(hi))
    j0, j1 = max(0, math.floor(c0)), min(grid.width, math.ceil(c1) + 1)
    i0, i1 = max(0, math.floor(r0)), min(grid.height, math.ceil(r1) + 1)
    if j0 >= j1 or i0 >= i1:
        return None
    sub = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE
    x = grid.left + (np.arange(j0, j1)[:, None] + sub) * grid.pixel  # (cols, S)
    y = grid.top - (np.arange(i0, i1)[:, None] + sub) * grid.pixel  # (rows, S)
    xs = np.broadcast_to(x[None, :, None, :], (i1 - i0, j1 - j0, SUPERSAMPLE, SUPERSAMPLE))
    ys = np.broadcast_to(y[:, None, :, None], xs.shape)
    return slice(i0, i1), slice(j0, j1), xs, ys


def _disc_coverage(grid: RasterGrid, centres: np.ndarray, radius: float) -> np.ndarray:
    """Supersampled area fraction of each pixel inside any of the discs."""
    out = np.zeros((grid.height, grid.width), dtype=np.float32)
    for c in np.asarray(centres, dtype=np.float64).reshape(-1, 2):
        window = _window_samples(grid, c - radius, c + radius)
        if window is None:
            continue
        rows, cols, xs, ys = window
        inside = ((xs - c[0]) ** 2 + (ys - c[1]) ** 2 <= radius**2).mean(axis=(2, 3))
        np.maximum(out[rows, cols], inside, out=out[rows, cols])
    return out


def _line_coverage(grid: RasterGrid, points: np.ndarray, width: float) -> np.ndarray:
    """Supersampled area fraction of each pixel within ``width / 2`` of the polyline ``points``."""
    out = np.zeros((grid.height, grid.width), dtype=np.float32)
    half = width / 2
    for a, b in zip(points[:-1], points[1:], strict=True):
        window = _window_samples(grid, np.minimum(a, b) - half, np.maximum(a, b) + half)
        if window is None:
            continue
        rows, cols, xs, ys = window
        d = b - a
        t = np.clip(((xs - a[0]) * d[0] + (ys - a[1]) * d[1]) / float(d @ d), 0.0, 1.0)
        near = ((xs - a[0] - t * d[0]) ** 2 + (ys - a[1] - t * d[1]) ** 2 <= half**2).mean(axis=(2, 3))
        np.maximum(out[rows, cols], near, out=out[rows, cols])
    return out


@functools.lru_cache(maxsize=32)
def _layers(spec: LabyrinthSpec, grid: RasterGrid, path_width: float) -> dict[str, np.ndarray]:
    hx, hy = spec.board_size[0] / 2, spec.board_size[1] / 2
    t = spec.rim_thickness
    rim = np.array(
        [(-hx - t, -hy - t, -hx, hy + t), (hx, -hy - t, hx + t, hy + t), (-hx, -hy - t, hx, -hy), (-hx, hy, hx, hy + t)]
    )
    walls = np.concatenate([rim, np.asarray(spec.walls, dtype=np.float64).reshape(-1, 4)])
    path = np.asarray(spec.waypoints, dtype=np.float64)
    return {
        "floor": _rect_coverage(grid, np.array([(-hx, -hy, hx, hy)])),
        "path": _line_coverage(grid, path, path_width) if path_width > 0 else np.zeros((grid.height, grid.width)),
        "hole": _disc_coverage(grid, np.asarray(spec.holes).reshape(-1, 2), spec.hole_radius),
        "wall": _rect_coverage(grid, walls),
    }


@functools.lru_cache(maxsize=32)
def background(spec: LabyrinthSpec, grid: RasterGrid, path_width: float = 0.002, colour: bool = False) -> np.ndarray:
    """The static picture of ``spec`` on ``grid``: (height, width) uint8 gray levels (:data:`GRAY`)
    or, with ``colour``, (height, width, 3) (:data:`RGB`). Cached per board, grid and style (the
    arrays are read-only: copy before drawing on them)."""
    palette = RGB if colour else GRAY
    layers = _layers(spec, grid, float(path_width))
    image = np.broadcast_to(
        np.asarray(palette["outside"], np.float32), (grid.height, grid.width, len(palette["floor"]))
    )
    for name in _LAYERS:
        cover = layers[name][..., None]
        image = image * (1 - cover) + np.asarray(palette[name], np.float32) * cover
    out = np.rint(image).astype(np.uint8)
    out = out if colour else out[..., 0]
    out.setflags(write=False)
    return out


class LabyrinthRaster:
    """Frames of one board on one grid: :meth:`gray` and :meth:`rgb` draw the marble on the cached
    :func:`background`; :meth:`crop` cuts a window centred on the marble (CyberRunner's view).

    Args:
        spec: the board.
        grid: the pixel grid (:func:`board_grid`, :func:`sheet_grid`).
        path_width: width of the printed path line (m); 0 draws none.
    """

    def __init__(self, spec: LabyrinthSpec, grid: RasterGrid, *, path_width: float = 0.002):
        if not (isinstance(path_width, (int, float)) and math.isfinite(path_width) and path_width >= 0):
            raise ValueError(f"path_width must be a non-negative number of metres, got {path_width!r}")
        self.spec = spec
        self.grid = grid
        self.path_width = float(path_width)
        self.background = background(spec, grid, self.path_width)
        #: The marble's radius in pixels.
        self.marble_radius = spec.marble_radius / grid.pixel

    def _draw(self, image: np.ndarray, col: float, row: float, value: tuple[int, ...]) -> np.ndarray:
        """Blend the marble centred at pixel coordinates ``(col, row)`` into ``image`` (in place).
        Its coverage comes from :attr:`_lut`, the window around pixel ``(floor(col), floor(row))``
        for the centre's fraction of a pixel quantised to 1/``LUT_STEPS``."""
        if not (math.isfinite(col) and math.isfinite(row)):
            return image
        i0, j0 = math.floor(row), math.floor(col)
        k = self._lut_half
        coverage = self._lut[round((row - i0) * LUT_STEPS), round((col - j0) * LUT_STEPS)]
        a0, a1 = max(0, i0 - k), min(image.shape[0], i0 + k + 1)
        b0, b1 = max(0, j0 - k), min(image.shape[1], j0 + k + 1)
        if a0 >= a1 or b0 >= b1:
            return image
        a = coverage[a0 - i0 + k : a1 - i0 + k, b0 - j0 + k : b1 - j0 + k]
        window = image[a0:a1, b0:b1]
        if image.ndim == 3:
            a = a[..., None]
        window[...] = np.rint(window + (np.asarray(value, np.float64) - window) * a)
        return image

    @functools.cached_property
    def _lut_half(self) -> int:
        return math.ceil(self.marble_radius + 1.5)

    @functools.cached_property
    def _lut(self) -> np.ndarray:
        """Marble coverage ``clip(R + 0.5 - d, 0, 1)`` of the (2K+1)² window around pixel (i0, j0),
        for centre fractions 0, 1/LUT_STEPS, …, 1 of a pixel in row and column: (S+1, S+1, 2K+1, 2K+1)."""
        k, r = self._lut_half, self.marble_radius
        offsets = np.arange(-k, k + 1, dtype=np.float64)
        fractions = np.arange(LUT_STEPS + 1) / LUT_STEPS
        dy = offsets[None, :] - fractions[:, None]  # (S+1, 2K+1): pixel row minus centre row
        d = np.hypot(dy[:, None, :, None], dy[None, :, None, :])
        return np.clip(r + 0.5 - d, 0.0, 1.0)

    def _pixel(self, xy: np.ndarray | Sequence[float]) -> tuple[float, float]:
        """:meth:`RasterGrid.to_pixel` of one point, in plain floats (the per-frame path)."""
        g = self.grid
        return (float(xy[0]) - g.left) / g.pixel - 0.5, (g.top - float(xy[1])) / g.pixel - 0.5

    def gray(self, xy: np.ndarray) -> np.ndarray:
        """The whole grid (height, width) uint8 with the marble at board point ``xy`` (m)."""
        col, row = self._pixel(xy)
        return self._draw(self.background.copy(), col, row, GRAY["marble"])

    def rgb(self, xy: np.ndarray) -> np.ndarray:
        """The whole grid in colour (height, width, 3) uint8 with the marble at ``xy`` (m)."""
        col, row = self._pixel(xy)
        image = background(self.spec, self.grid, self.path_width, colour=True).copy()
        return self._draw(image, col, row, RGB["marble"])

    def crop(self, xy: np.ndarray, size: int = 64) -> np.ndarray:
        """A ``size`` × ``size`` uint8 window of the grid centred on the marble at ``xy`` (m): the
        marble's pixel (the nearest to its centre) is ``[size // 2, size // 2]`` and the marble is
        drawn at its exact sub-pixel position; beyond the grid the window shows the outside."""
        col, row = self._pixel(xy)
        if not (math.isfinite(col) and math.isfinite(row)):
            raise ValueError(f"xy must be finite board coordinates (m), got {xy!r}")
        i0, j0 = round(row) - size // 2, round(col) - size // 2
        bg = self.background
        if 0 <= i0 and 0 <= j0 and i0 + size <= bg.shape[0] and j0 + size <= bg.shape[1]:
            out = bg[i0 : i0 + size, j0 : j0 + size].copy()
        else:
            out = np.full((size, size), GRAY["outside"][0], dtype=np.uint8)
            a0, a1 = max(i0, 0), min(i0 + size, bg.shape[0])
            b0, b1 = max(j0, 0), min(j0 + size, bg.shape[1])
            if a0 < a1 and b0 < b1:
                out[a0 - i0 : a1 - i0, b0 - j0 : b1 - j0] = bg[a0:a1, b0:b1]
        return self._draw(out, col - j0, row - i0, GRAY["marble"])
