"""Geodesic distances for a batch whose rows each show their own maze on one shared board.

:meth:`MazeSpec.geodesic_distance <bimgame.sim.maze.MazeSpec.geodesic_distance>` is vectorised over
the points of one maze. A vector env whose envs show different mazes (:mod:`bimgame.sim.maze_sets`)
would call it once per env and step; mazes on one board share every radius, and differ only in their
gates, so :class:`MazeRows` keeps each row's gate tables in padded arrays and computes every row in
one pass, the same computation as the per-maze one (a test compares them). A :class:`MazeRows`
measures to one target, the centre or a task's goal channel (``to_channel``), as the per-maze
computation's ``to_channel``.
"""

from __future__ import annotations

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
    gates per wall, for :meth:`geodesic_distance` to ``to_channel`` (0: the centre; ``j``: through
    wall ``j`` into channel ``j``, the goal of an STG task)."""

    def __init__(self, base: MazeSpec, rows: int, max_gates: int, to_channel: int = 0):
        if not base.walls:
            raise ValueError("MazeRows needs a board with walls")
        self.base = base
        tables = base._geodesic_tables(to_channel)  # checks to_channel, naming the allowed ones
        self.to_channel = int(to_channel)
        self._target_end = tables["target_end"]
        self._bounds = tables["bounds"]
        self._band_start = tables["band_start"]
        self._obstacle = tables["obstacle"]
        self._mids = tables["mids"]
        walls = len(base.walls)
        self._gate_angle = np.zeros((rows, walls + 1, max_gates))
        self._gate_dist = np.full((rows, walls + 1, max_gates), np.inf)
        self._gate_half_width = np.full((rows, walls, max_gates), -1.0)  # -1: no gate (never inside)
        self._row_index = np.arange(rows)[:, None]

    def set_row(self, row: int, spec: MazeSpec) -> None:
        """Row ``row`` shows ``spec`` (a maze on the board, with at most ``max_gates`` gates a wall)."""
        gates = max((len(wall.gates) for wall in spec.walls), default=1)
        if gates > self._gate_angle.shape[2]:
            raise ValueError(f"a maze with {gates} gates on a wall, more than MazeRows' {self._gate_angle.shape[2]}")
        self._gate_angle[row] = 0.0
        self._gate_dist[row] = np.inf
        self._gate_half_width[row] = -1.0
        tables = spec._tables["geodesic"].get(self.to_channel)  # the spec's tables to the target, if built
        if tables is not None:
            self._gate_angle[row, :, :gates] = tables["gate_angle"]
            self._gate_dist[row, :, :gates] = tables["gate_dist"]
        else:  # only what the rows use of them: its gates' angles and distances to the target (kept)
            for k, (angles, distances) in enumerate(_target_gates(spec, self.to_channel)):
                self._gate_angle[row, k + 1, : len(distances)] = angles
                self._gate_dist[row, k + 1, : len(distances)] = distances
        for k, wall in enumerate(spec.walls):
            self._gate_half_width[row, k, : len(wall.gates)] = [gate.width / 2 for gate in wall.gates]

    def geodesic_distance(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Distances (m) to the target of points ``x``, ``y`` of shape (rows, n), row ``b`` in its
        maze: the computation of ``MazeSpec.geodesic_distance(x, y, to_channel)`` on every row at once."""
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
        best = np.min(lengths + self._gate_dist[rows, channel], axis=-1) + (r - r_eff)
        arrived = r if self.to_channel == 0 else np.maximum(r - self._target_end, 0.0)
        return np.where(channel <= self.to_channel, arrived, best)
