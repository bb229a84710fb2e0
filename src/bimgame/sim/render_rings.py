"""The background of another maze on a board, redrawn only where the board's ring walls are.

Mazes of one board (:mod:`bimgame.sim.maze_sets`) share every radius and differ in their gates, so
the antialiased background of :mod:`bimgame.sim.render` changes only in the pixels the ring walls
cross. :class:`RingSamples` keeps those pixels' sub-samples, sorted by angle per wall, and the counts
of each pixel's other sub-samples per label; a maze's background is then its gates' open sub-samples
counted per pixel. Each gate labels only the sub-samples within a hair of its angular sector
(:class:`GateSamples`, also what :func:`~bimgame.envs.mazes.maze_encoding` samples) with exactly
:meth:`~bimgame.sim.maze.Wall.in_gate`'s test, so the pixels are those of ``MazeRenderer(spec, size)``
(a test compares them) at a fraction of the cost.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from bimgame.sim.geodesic import wrap_angle, wrap_angle_one
from bimgame.sim.maze import MazeSpec, Wall

__all__ = ["GateSamples", "RingSamples", "open_samples", "FLOOR_LABEL", "GOAL_LABEL", "WALL_LABEL"]

# Region labels of the background raster (the label order of render_grid's background_coverage).
FLOOR_LABEL, GOAL_LABEL, WALL_LABEL = 0, 1, 2
#: Sub-samples within this angle (rad) of a gate's sector are tested exactly; farther ones cannot pass
#: the test (its rounding errors are ~1e-15 rad for gates at angles within :data:`_NEAR_ANGLE`).
_MARGIN = 1e-9
#: Gates farther than this from [-pi, pi) (rad), or as wide as the circle, are tested on every sample.
_NEAR_ANGLE = 4 * math.pi
#: :class:`GateSamples` keys wall ``k``'s angles (in [-pi, pi]) by ``angle + k * _KEY_PERIOD``.
_KEY_PERIOD = 8.0


@dataclasses.dataclass(frozen=True)
class GateSamples:
    """Sample angles of several walls, each wall's ascending in [-pi, pi], for :meth:`open_mask`:
    wall ``k``'s keyed by ``angle + k * _KEY_PERIOD`` in one ascending array, so that one bisection
    finds every gate's candidates."""

    angles: np.ndarray  # (n,) every wall's samples, wall 0's first, each wall's ascending
    keys: np.ndarray  # (n,) angles + k * _KEY_PERIOD: ascending
    starts: np.ndarray  # (walls + 1,) where each wall's samples start, then n

    @classmethod
    def of(cls, per_wall: list[np.ndarray]) -> GateSamples:
        """The samples of each wall (ascending angles in [-pi, pi]), wall 0's first."""
        angles = np.concatenate(per_wall) if per_wall else np.zeros(0)
        keys = np.concatenate([a + k * _KEY_PERIOD for k, a in enumerate(per_wall)]) if per_wall else np.zeros(0)
        starts = np.cumsum([0] + [len(a) for a in per_wall])
        for array in (angles, keys, starts):
            array.flags.writeable = False
        return cls(angles, keys, starts)

    def open_mask(self, walls: tuple[Wall, ...]) -> np.ndarray:
        """Whether each sample is inside one of its wall's gates: ``walls[k].in_gate`` on wall ``k``'s
        samples, bit for bit, the comparison made only near each gate.

        Each gate's candidates are the samples within ``_MARGIN`` of its sector (its centre wrapped
        to [-pi, pi), the sector's parts beyond ±pi moved by a period), found by bisection; only they
        take :meth:`~bimgame.sim.maze.Wall.in_gate`'s comparison, on the gate's angle and half width.
        A wall with a gate far outside [-pi, pi) or as wide as a half circle tests every sample."""
        opened = np.zeros(len(self.angles), dtype=bool)
        bounds: list[tuple[float, float]] = []
        owners: list[int] = []
        centres: list[float] = []
        half_widths: list[float] = []
        for k, wall in enumerate(walls):
            gates = [(gate.angle, gate.width / 2) for gate in wall.gates]
            if not all(abs(c) <= _NEAR_ANGLE and 0 <= h < math.pi - 1e-6 for c, h in gates):
                segment = slice(int(self.starts[k]), int(self.starts[k + 1]))
                opened[segment] = wall.in_gate(self.angles[segment])  # unusual gates: every sample
                continue
            offset = k * _KEY_PERIOD
            for c, h in gates:
                centre = wrap_angle_one(c)
                lo, hi = centre - h - _MARGIN, centre + h + _MARGIN
                bounds.append((offset + max(lo, -math.pi), offset + min(hi, math.pi)))
                if lo < -math.pi:  # the sector's part past -pi, a period on
                    bounds.append((offset + lo + 2 * math.pi, offset + math.pi))
                if hi > math.pi:
                    bounds.append((offset - math.pi, offset + hi - 2 * math.pi))
                owners += [len(centres)] * (len(bounds) - len(owners))
                centres.append(c)
                half_widths.append(h)
        if not bounds:
            return opened
        edges = np.array(bounds)
        first = np.searchsorted(self.keys, edges[:, 0], side="left")
        sizes = np.maximum(np.searchsorted(self.keys, edges[:, 1], side="right") - first, 0)
        total = int(sizes.sum())
        if total:
            gate = np.repeat(np.array(owners), sizes)
            candidates = np.arange(total) - np.repeat(np.cumsum(sizes) - sizes - first, sizes)
            centre = np.array(centres, dtype=float)[gate]
            half_width = np.array(half_widths, dtype=float)[gate]
            inside = np.abs(wrap_angle(self.angles[candidates] - centre)) <= half_width
            opened[candidates[inside]] = True  # a sample on two touching gates' edges: once
        return opened


def open_samples(wall: Wall, theta_sorted: np.ndarray) -> np.ndarray:
    """Indices into ``theta_sorted`` (ascending angles in [-pi, pi]) of the samples inside one of
    ``wall``'s gates: ``wall.in_gate(theta_sorted)``'s true entries (:meth:`GateSamples.open_mask`)."""
    return np.flatnonzero(GateSamples.of([theta_sorted]).open_mask((wall,)))


@dataclasses.dataclass(frozen=True)
class RingSamples:
    """The background sub-samples of the pixels a board's ring walls cross, so that the background
    of another maze on the same board (other gates, same radii) is drawn by labelling only those."""

    pixels: np.ndarray  # (P,) flat indices of the pixels that hold a sub-sample inside a wall's ring
    counts: np.ndarray  # (3, P) per label, each pixel's sub-samples outside the rings with that label
    ring_counts: np.ndarray  # (P,) each pixel's sub-samples inside a ring
    rings: GateSamples  # every wall's ring sub-samples' angles, ascending per wall
    rows: np.ndarray  # the row in ``pixels`` of each of those sub-samples
    samples_per_pixel: int

    @classmethod
    def build(cls, spec: MazeSpec, size: int, extent: float, supersample: int) -> RingSamples:
        """The ring sub-samples of ``spec``'s board at ``size`` pixels, at the positions
        :func:`~bimgame.sim.render_grid.background_coverage` samples (``extent``: half the image's
        width in metres)."""
        s = supersample
        mpp = 2.0 * extent / size
        sub = (np.arange(size * s) + 0.5) / s  # the sub-sample positions of background_coverage
        x, y = np.meshgrid(-extent + sub * mpp, extent - sub * mpp)
        # Pixel-major: row p holds pixel p's s² sub-samples in background_coverage's order.
        x = x.reshape(size, s, size, s).transpose(0, 2, 1, 3).reshape(size * size, s * s)
        y = y.reshape(size, s, size, s).transpose(0, 2, 1, 3).reshape(size * size, s * s)
        r = np.hypot(x, y)
        in_rings = [(r >= wall.inner_radius) & (r <= wall.outer_radius) for wall in spec.walls]
        any_ring = np.logical_or.reduce(in_rings)
        pixels = np.flatnonzero(np.any(any_ring, axis=1))
        labels = np.full((len(pixels), s * s), FLOOR_LABEL, dtype=np.int8)
        rp = r[pixels]
        labels[rp < (spec.walls[0].inner_radius if spec.walls else spec.rim_radius)] = GOAL_LABEL
        labels[rp >= spec.rim_radius] = WALL_LABEL
        outside = ~any_ring[pixels]
        counts = np.stack([((labels == label) & outside).sum(axis=1) for label in (0, 1, 2)])
        theta = np.arctan2(y[pixels], x[pixels])
        angles, rows = [], []
        for ring in in_rings:
            ring_rows, columns = np.nonzero(ring[pixels])
            order = np.argsort(theta[ring_rows, columns], kind="stable")
            angles.append(theta[ring_rows, columns][order])
            rows.append(ring_rows[order])
        ring_rows = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
        return cls(pixels, counts, (~outside).sum(axis=1), GateSamples.of(angles), ring_rows, s * s)

    def ring_fractions(self, spec: MazeSpec) -> np.ndarray:
        """Each ring pixel's (:attr:`pixels`) fraction of floor, goal and wall sub-samples in ``spec``,
        (3, P): its gates' open samples are floor, the rest of its ring wall; counts over
        ``samples_per_pixel``, as background_coverage's mean of the labels gives them (multiples of
        1/s², exact)."""
        open_counts = np.bincount(self.rows[self.rings.open_mask(spec.walls)], minlength=len(self.pixels))
        counts = self.counts.copy()
        counts[FLOOR_LABEL] += open_counts
        counts[WALL_LABEL] += self.ring_counts - open_counts
        return counts / self.samples_per_pixel

    def fractions(self, spec: MazeSpec, base: np.ndarray) -> np.ndarray:
        """:func:`~bimgame.sim.render_grid.background_coverage` of ``spec`` from ``base``, the
        coverage of any maze on the board."""
        fractions = base.copy()
        fractions.reshape(3, -1)[:, self.pixels] = self.ring_fractions(spec)
        return fractions
