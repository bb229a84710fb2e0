"""Geodesic distances for a batch whose rows each show their own maze on one shared board.

:meth:`MazeSpec.geodesic_distance <bimgame.sim.maze.MazeSpec.geodesic_distance>` is vectorised over
the points of one maze. A vector env whose envs show different mazes (:mod:`bimgame.sim.maze_sets`)
would call it once per env and step; mazes on one board share every radius, and differ only in their
gates, so :class:`MazeRows` keeps each row's gate tables in padded arrays and computes every row in
one pass, the same computation as the per-maze one (a test compares them). A :class:`MazeRows`
measures to the centre, a task's goal channel, or both in one pass (``to_channels``: the per-maze
computation's ``to_channel`` each).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from bimgame.sim.geodesic import annulus_path_length, gate_distances, wrap_angle
from bimgame.sim.maze import MazeSpec

__all__ = ["MazeRows"]


def _target_gates(spec: MazeSpec, to_channel: int) -> list[tuple[list[float], np.ndarray]]:
    """Per wall of ``spec``, its gates' angles and distances to ``to_channel``: the part of the maze's
    geodesic tables to that target that :class:`MazeRows` uses, computed as they are (once per maze
    and target, kept with its other tables: a set's mazes come back)."""
    cache = spec._tables
    key = "centre_gates" if to_channel == 0 else f"gates_to_channel_{to_channel}"
    if key not in cache:
        portals = spec._gate_portals()
        distances = gate_distances(portals, to_channel)
        cache[key] = [(p["angles"], d) for p, d in zip(portals, distances, strict=True)]
    return cache[key]


class MazeRows:
    """Per-row gate tables of ``rows`` mazes on ``base``'s board, each with at most ``max_gates``
    gates per wall, for :meth:`geodesic_distances` to each of ``to_channels`` (0: the centre; ``j``:
    through wall ``j`` into channel ``j``, the goal of an STG task). The targets share everything but
    their gates' distances, so one pass serves them all."""

    def __init__(self, base: MazeSpec, rows: int, max_gates: int, to_channels: Sequence[int] = (0,)):
        if not base.walls:
            raise ValueError("MazeRows needs a board with walls")
        if not to_channels:
            raise ValueError("MazeRows needs at least one target channel")
        self.base = base
        tables = [base._geodesic_tables(c) for c in to_channels]  # checks each, naming the allowed ones
        self.to_channels = tuple(int(c) for c in to_channels)
        self._target_end = [t["target_end"] for t in tables]
        self._bounds = tables[0]["bounds"]  # the channels' radii: the same for every target
        self._band_start = tables[0]["band_start"]
        self._obstacle = tables[0]["obstacle"]
        self._mids = tables[0]["mids"]
        walls = len(base.walls)
        self._gate_angle = np.zeros((rows, walls + 1, max_gates))
        self._gate_dist = np.full((len(self.to_channels), rows, walls + 1, max_gates), np.inf)
        self._gate_half_width = np.full((rows, walls, max_gates), -1.0)  # -1: no gate (never inside)
        self._row_index = np.arange(rows)[:, None]

    def set_row(self, row: int, spec: MazeSpec) -> None:
        """Row ``row`` shows ``spec`` (a maze on the board, with at most ``max_gates`` gates a wall)."""
        gates = max((len(wall.gates) for wall in spec.walls), default=1)
        if gates > self._gate_angle.shape[2]:
            raise ValueError(f"a maze with {gates} gates on a wall, more than MazeRows' {self._gate_angle.shape[2]}")
        self._gate_angle[row] = 0.0
        self._gate_dist[:, row] = np.inf
        self._gate_half_width[row] = -1.0
        for target, to_channel in enumerate(self.to_channels):
            tables = spec._tables["geodesic"].get(to_channel)  # the spec's tables to the target, if built
            if tables is not None:
                self._gate_angle[row, :, :gates] = tables["gate_angle"]
                self._gate_dist[target, row, :, :gates] = tables["gate_dist"]
            else:  # only what the rows use of them: its gates' angles and distances to the target (kept)
                for k, (angles, distances) in enumerate(_target_gates(spec, to_channel)):
                    self._gate_angle[row, k + 1, : len(distances)] = angles
                    self._gate_dist[target, row, k + 1, : len(distances)] = distances
        for k, wall in enumerate(spec.walls):
            self._gate_half_width[row, k, : len(wall.gates)] = [gate.width / 2 for gate in wall.gates]

    def geodesic_distance(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Distances (m) to the first target: :meth:`geodesic_distances`' first array."""
        return self.geodesic_distances(x, y)[0]

    def geodesic_distances(self, x: np.ndarray, y: np.ndarray) -> list[np.ndarray]:
        """Distances (m) to each target of points ``x``, ``y`` of shape (rows, n), row ``b`` in its
        maze: the computation of ``MazeSpec.geodesic_distance(x, y, to_channel)`` on every row at once,
        for every ``to_channel``; the paths to the gates of each point's channel are measured once."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        rows = self._row_index
        r = np.hypot(x, y)
        theta = np.arctan2(y, x)
        walls = len(self.base.walls)
        channel = np.searchsorted(self._bounds, r, side="right")
        # Within a wall's band, outside its gates and beyond its mid radius: still outside (see
        # MazeSpec.geodesic_distance).
        in_band = r > self._band_start[channel]
        wall = np.minimum(channel, walls - 1)
        half_width = self._gate_half_width[rows, wall]  # (rows, n, gates)
        angle = self._gate_angle[rows, np.minimum(channel, walls - 1) + 1]
        in_gate = np.any(np.abs(wrap_angle(theta[..., None] - angle)) <= half_width, axis=-1)
        into_wall = in_band & (channel < walls) & ~in_gate
        from_outside = into_wall & (r >= self._mids[wall])
        channel = np.where(from_outside, channel + 1, channel)
        obstacle = self._obstacle[channel]
        band_start = self._band_start[channel]
        r_eff = np.minimum(r, band_start)
        lengths = annulus_path_length(
            r_eff[..., None],
            theta[..., None],
            obstacle[..., None],
            self._gate_angle[rows, channel],
            obstacle[..., None],
        )
        distances = []
        for target, to_channel in enumerate(self.to_channels):
            best = np.min(lengths + self._gate_dist[target, rows, channel], axis=-1) + (r - r_eff)
            arrived = r if to_channel == 0 else np.maximum(r - self._target_end[target], 0.0)
            distances.append(np.where(channel <= to_channel, arrived, best))
        return distances
