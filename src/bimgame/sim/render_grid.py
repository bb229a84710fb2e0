"""The board-frame pixel grid of :mod:`bimgame.sim.render`: pixel coordinates, antialiased coverage.

One responsibility: the geometry of a ``size`` × ``size`` image of the board and the fraction of
each pixel that the background's regions and a marble cover. :class:`PixelGrid` maps board points
to pixels and holds, for one image size, the window of pixels a marble can touch and the marble
coverage table grayscale frames blend with; :func:`background_coverage` supersamples the fractions
of floor, goal region and wall of every pixel; :func:`blend_gray` composites a marble into batched
grayscale frames. This is pure geometry, the same for observations and video frames at any size;
the grey levels and colours drawn with it are :class:`~bimgame.sim.render.MazeRenderer`'s.

Pixel grid. For an image of ``size`` × ``size`` pixels the grid covers the square
``[-E, E]²`` of board coordinates (metres), ``E = spec.rim_radius + spec.rim_thickness`` (the rim's
outer edge touches the image border), so one pixel is ``2 E / size`` metres wide
(:attr:`PixelGrid.metres_per_pixel`). The image is "north up": row 0 is the top (+y), column 0
the left (-x). Continuous pixel coordinates ``(col, row)`` put the *centre* of pixel ``[i, j]``
(row ``i``, column ``j``) at ``(j, i)``; hence board point ``(x, y)`` maps to::

    col = (x + E) / metres_per_pixel - 0.5
    row = (E - y) / metres_per_pixel - 0.5

and the pixel ``[i, j]`` covers ``col`` in ``[j - 0.5, j + 0.5]`` and ``row`` in ``[i - 0.5, i + 0.5]``.

Antialiasing. Background pixels hold the area-weighted mean of ``SUPERSAMPLE`` × ``SUPERSAMPLE``
sub-samples. A marble of radius ``R`` pixels covers pixel ``[i, j]`` with
``a = clip(R + 0.5 - d, 0, 1)``, ``d`` the distance from the marble's centre to the pixel's centre
(in pixels), and the pixel becomes ``value * (1 - a) + MARBLE * a`` (rounded, ``MARBLE`` the
marble's grey level), so sub-pixel marble motion changes the image smoothly.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from bimgame.sim.maze import MazeSpec
from bimgame.sim.render_rings import FLOOR_LABEL, GOAL_LABEL, WALL_LABEL

__all__ = ["PixelGrid", "background_coverage", "blend_gray", "SUPERSAMPLE", "LUT_STEPS"]

SUPERSAMPLE: int = 4
"""Background antialiasing: sub-samples per pixel along each axis."""
#: Sub-pixel steps per pixel of the marble coverage table used for grayscale observations.
LUT_STEPS: int = 32

# Region labels of the background raster.
_FLOOR, _GOAL, _WALL = FLOOR_LABEL, GOAL_LABEL, WALL_LABEL


def _distance(dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """``sqrt(dx² + dy²)`` into ``dx`` (``dy`` is overwritten).

    Only correctly rounded IEEE operations (no ``hypot``, whose SIMD and scalar loops need not
    agree to the last bit), so a pixel gets the same value whatever the array's shape: the batched
    and single-frame paths give bit-identical images.
    """
    np.multiply(dx, dx, out=dx)
    np.multiply(dy, dy, out=dy)
    np.add(dx, dy, out=dx)
    return np.sqrt(dx, out=dx)


@dataclasses.dataclass(frozen=True)
class PixelGrid:
    """Pixel geometry of one image size and the marble window at that size."""

    size: int
    extent: float  # E: the image spans [-E, E]² metres
    metres_per_pixel: float
    radius_px: float  # marble radius in pixels
    half_window: int  # K: window offsets lie in [-K, K]²
    dflat: np.ndarray  # (P,) flat offsets di * size + dj (int64)
    di_int: np.ndarray  # (P,) row offsets (int64)
    dj_int: np.ndarray  # (P,) column offsets (int64)
    square_di: np.ndarray  # ((2K+1)²,) row offsets of the square window, row-major (float64)
    square_dj: np.ndarray  # ((2K+1)²,) column offsets of the square window (float64)
    disc_in_square: np.ndarray  # (P,) positions of the disc's pixels within the square window
    _cache: dict = dataclasses.field(default_factory=dict)  # coverage_lut(), built on first use

    @classmethod
    def build(cls, spec: MazeSpec, size: int, extent: float) -> PixelGrid:
        mpp = 2.0 * extent / size
        radius_px = spec.marble_radius / mpp
        # The marble's centre lies within 0.5 px (per axis) of the pixel it is rounded to, and a
        # pixel is touched only if its centre is within radius + 0.5 of the marble's centre; keep
        # just the offsets that can satisfy both (a disc, not the whole square).
        reach = radius_px + 0.5 + math.sqrt(0.5)
        k = math.ceil(reach)
        ii, jj = np.mgrid[-k : k + 1, -k : k + 1]
        keep = ii * ii + jj * jj < reach * reach
        di = ii[keep].astype(np.int64)
        dj = jj[keep].astype(np.int64)
        return cls(
            size=size,
            extent=extent,
            metres_per_pixel=mpp,
            radius_px=radius_px,
            half_window=k,
            dflat=di * size + dj,
            di_int=di,
            dj_int=dj,
            square_di=ii.ravel().astype(np.float64),
            square_dj=jj.ravel().astype(np.float64),
            disc_in_square=np.flatnonzero(keep.ravel()),
        )

    def coverage_lut(self) -> np.ndarray:
        """``1 - coverage`` of the square window's pixels for the marble's centre at each of
        (Q+1)² sub-pixel offsets (Q = LUT_STEPS per pixel), built on first use.

        Grayscale observations look the marble up here instead of computing distances: one
        indexing operation instead of about ten numpy calls per marble, which is most of the cost
        of an 84×84 frame. The centre is quantised to 1/Q px (1/32 px = 0.07 mm at 84 px), far
        below the one-pixel accuracy the observation needs; single and batched frames use the
        same table, so they stay bit-identical.
        """
        lut = self._cache.get("lut")
        if lut is None:
            q = LUT_STEPS
            offsets = np.arange(q + 1) / q - 0.5  # (i0 - row) or (j0 - col), quantised
            dy = self.square_di[None, None, :] + offsets[:, None, None]
            dx = self.square_dj[None, None, :] + offsets[None, :, None]
            d = np.broadcast_to(dx, (q + 1, q + 1, dx.shape[-1])).copy()
            _distance(d, np.broadcast_to(dy, d.shape).copy())
            lut = self._cache["lut"] = self.uncovered(d)
        return lut

    def lut_square(self, col: float, row: float) -> tuple[slice, slice, np.ndarray] | None:
        """:meth:`square` with ``uncovered=True``, from :meth:`coverage_lut`."""
        if not (math.isfinite(col) and math.isfinite(row)):
            return None
        j0 = round(col)
        i0 = round(row)
        half = LUT_STEPS // 2
        k = self.half_window
        u = self.coverage_lut()[round((i0 - row) * LUT_STEPS) + half, round((j0 - col) * LUT_STEPS) + half].reshape(
            2 * k + 1, 2 * k + 1
        )
        return self._clipped(i0, j0, u)

    def _clipped(self, i0: int, j0: int, values: np.ndarray) -> tuple[slice, slice, np.ndarray] | None:
        """The image slices a square window centred on pixel ``(i0, j0)`` covers, clipped to the
        image, and the matching part of ``values`` ((2K+1, 2K+1)); None if entirely outside."""
        k = self.half_window
        r0, c0 = i0 - k, j0 - k
        r1, c1 = i0 + k + 1, j0 + k + 1
        if r0 >= 0 and c0 >= 0 and r1 <= self.size and c1 <= self.size:
            return slice(r0, r1), slice(c0, c1), values
        rr0, cc0 = max(r0, 0), max(c0, 0)
        rr1, cc1 = min(r1, self.size), min(c1, self.size)
        if rr0 >= rr1 or cc0 >= cc1:
            return None
        return slice(rr0, rr1), slice(cc0, cc1), values[rr0 - r0 : rr1 - r0, cc0 - c0 : cc1 - c0]

    def lut_disc(self, col: np.ndarray, row: np.ndarray, j0: np.ndarray, i0: np.ndarray) -> np.ndarray:
        """``1 - coverage`` of the disc window's pixels (M, P) for marbles at ``col``, ``row``
        (rounded to ``j0``, ``i0``), from :meth:`coverage_lut`: the batched twin of
        :meth:`lut_square`."""
        half = LUT_STEPS // 2
        fi = np.rint((np.nan_to_num(i0 - row)) * LUT_STEPS).astype(np.int64) + half
        fj = np.rint((np.nan_to_num(j0 - col)) * LUT_STEPS).astype(np.int64) + half
        np.clip(fi, 0, LUT_STEPS, out=fi)
        np.clip(fj, 0, LUT_STEPS, out=fj)
        disc = self._cache.get("disc")
        if disc is None:
            disc = self._cache["disc"] = np.ascontiguousarray(self.coverage_lut()[:, :, self.disc_in_square])
        return disc[fi, fj]

    def to_pixel(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64)
        out = np.empty(xy.shape, dtype=np.float64)
        inv = 1.0 / self.metres_per_pixel
        np.multiply(xy[..., 0] + self.extent, inv, out=out[..., 0])
        np.multiply(self.extent - xy[..., 1], inv, out=out[..., 1])
        out -= 0.5
        return out

    def uncovered(self, d: np.ndarray) -> np.ndarray:
        """Turn distances ``d`` (px, any shape) into ``1 - a``, in place: ``clip(d - R + 0.5, 0, 1)``."""
        np.subtract(d, self.radius_px - 0.5, out=d)
        np.minimum(d, 1.0, out=d)
        np.maximum(d, 0.0, out=d)
        return d

    def square(self, col: float, row: float) -> tuple[slice, slice, np.ndarray] | None:
        """The square window of one marble centred at pixel coordinates ``(col, row)`` (floats),
        for colour frames.

        Returns ``(rows, cols, d)``: the slices of the image the window covers (clipped to the
        image) and the distances (px) of those pixels' centres from the marble's centre, shape
        ``(len(rows), len(cols))``; None if the marble is not finite or entirely outside.
        """
        if not (math.isfinite(col) and math.isfinite(row)):
            return None
        j0 = round(col)
        i0 = round(row)
        k = self.half_window
        d = np.add(self.square_dj, j0 - col)
        dy = np.add(self.square_di, i0 - row)
        _distance(d, dy)
        d = d.reshape(2 * k + 1, 2 * k + 1)
        return self._clipped(i0, j0, d)

    def window(self, j0: np.ndarray, i0: np.ndarray, inside: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """The disc windows of marbles centred on pixels ``(i0, j0)`` (shape (M,), rounded pixel
        coordinates); ``inside``: whether every window lies inside the image.

        Returns ``(flat, valid)``: flat pixel indices within one image (M, P), and None (if
        ``inside``) or the (M, P) mask of pixels inside the image (other entries hold clipped,
        meaningless indices). Their coverage comes from :meth:`lut_disc`.
        """
        if inside:
            base = i0.astype(np.int64) * self.size + j0.astype(np.int64)
            return base[:, None] + self.dflat, None
        # Near or beyond the image border: clip the window. Far-away (or non-finite) centres are
        # clamped first so the integer arithmetic cannot overflow.
        k = self.half_window
        lo, hi = -self.size - 2 * k, 2 * self.size + 2 * k
        j0 = np.clip(np.nan_to_num(j0, nan=lo), lo, hi).astype(np.int64)
        i0 = np.clip(np.nan_to_num(i0, nan=lo), lo, hi).astype(np.int64)
        jj = j0[:, None] + self.dj_int
        ii = i0[:, None] + self.di_int
        valid = (jj >= 0) & (jj < self.size) & (ii >= 0) & (ii < self.size)
        np.clip(jj, 0, self.size - 1, out=jj)
        np.clip(ii, 0, self.size - 1, out=ii)
        return ii * self.size + jj, valid


def background_coverage(spec: MazeSpec, size: int, extent: float, supersample: int = SUPERSAMPLE) -> np.ndarray:
    """Fraction of each pixel covered by floor, goal region and wall: (3, size, size) float64.

    "Wall" is the ring walls outside their gates, the rim and everything beyond the rim; the goal
    region is the floor inside wall 0 (the whole floor if there are no walls).
    """
    s = supersample
    mpp = 2.0 * extent / size
    sub = (np.arange(size * s) + 0.5) / s  # sub-sample positions in pixel-edge units
    xs = -extent + sub * mpp
    goal_radius = spec.walls[0].inner_radius if spec.walls else spec.rim_radius
    fractions = np.empty((3, size, size), dtype=np.float64)
    rows_per_chunk = max(1, 2**20 // (size * s * s))
    for r0 in range(0, size, rows_per_chunk):
        r1 = min(size, r0 + rows_per_chunk)
        ys = extent - sub[r0 * s : r1 * s] * mpp
        x, y = np.meshgrid(xs, ys)
        r = np.hypot(x, y)
        labels = np.full(r.shape, _FLOOR, dtype=np.int8)
        labels[r < goal_radius] = _GOAL
        labels[r >= spec.rim_radius] = _WALL
        for wall in spec.walls:
            ring = np.nonzero((r >= wall.inner_radius) & (r <= wall.outer_radius))
            theta = np.arctan2(y[ring], x[ring])
            labels[ring] = np.where(wall.in_gate(theta), _FLOOR, _WALL).astype(np.int8)
        blocks = labels.reshape(r1 - r0, s, size, s)
        for label in (_FLOOR, _GOAL, _WALL):
            fractions[label, r0:r1] = (blocks == label).mean(axis=(1, 3))
    return fractions


def blend_gray(flat_out: np.ndarray, flat: np.ndarray, uncovered: np.ndarray, marble: int) -> None:
    """``flat_out[flat] = round(v * (1 - a) + marble * a)`` with ``v = flat_out[flat]`` and
    ``uncovered = 1 - a``, computed as ``(v - marble) * (1 - a) + marble + 0.5`` truncated
    (``marble``: the marble's grey level)."""
    value = np.subtract(flat_out[flat], float(marble))
    value *= uncovered
    value += marble + 0.5
    flat_out[flat] = value
