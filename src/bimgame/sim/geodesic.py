"""The geodesic distance's geometry: shortest paths around a disc and the per-target tables of
gate-to-goal distances, from plain radii and angles (a :class:`~bimgame.sim.maze.MazeSpec` builds
them once per target and caches them).

A wall is described here by its *portal*: its gates' centre angles and the radii where the marble's
centre enters a gate from outside (``outer_radius``) and leaves it inside (``inner_radius``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["wrap_angle", "annulus_path_length", "gate_distances", "geodesic_tables"]


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def annulus_path_length(
    r1: np.ndarray | float,
    theta1: np.ndarray | float,
    r2: np.ndarray | float,
    theta2: np.ndarray | float,
    obstacle_radius: np.ndarray | float,
) -> np.ndarray:
    """Shortest path length between points (polar ``(r1, theta1)`` and ``(r2, theta2)``) that must
    stay outside the disc of radius ``obstacle_radius`` centred at the origin.

    Points inside the disc are treated as lying on its boundary. If the straight segment clears the
    disc the answer is its length; otherwise the path runs along the two tangents and the arc
    between them. All arguments broadcast against each other.
    """
    a = np.asarray(obstacle_radius, dtype=float)
    r1 = np.maximum(np.asarray(r1, dtype=float), a)
    r2 = np.maximum(np.asarray(r2, dtype=float), a)
    dtheta = np.abs(wrap_angle(np.asarray(theta1, dtype=float) - theta2))
    alpha1 = np.arccos(np.minimum(a / r1, 1.0))
    alpha2 = np.arccos(np.minimum(a / r2, 1.0))
    straight = np.sqrt(np.maximum(r1**2 + r2**2 - 2 * r1 * r2 * np.cos(dtheta), 0.0))
    wrapped = (
        np.sqrt(np.maximum(r1**2 - a**2, 0.0)) + np.sqrt(np.maximum(r2**2 - a**2, 0.0)) + a * (dtheta - alpha1 - alpha2)
    )
    return np.where(dtheta <= alpha1 + alpha2, straight, wrapped)


def gate_distances(portals: list[dict[str, Any]], to_channel: int) -> list[np.ndarray]:
    """Dynamic programming from the target wall outwards: a gate of the target wall costs its
    radial crossing (plus, for the centre, the way to the centre point); a gate of an outer
    wall costs its crossing plus the best path to a gate of the next wall in."""
    distances: list[np.ndarray] = []
    for k, portal in enumerate(portals):
        through = portal["outer_radius"] - portal["inner_radius"]
        if k < to_channel:
            distances.append(np.full(len(portal["angles"]), np.inf))
            continue
        if k == to_channel:
            rest = portal["inner_radius"] if k == 0 else 0.0
            distances.append(np.full(len(portal["angles"]), through + rest))
            continue
        inner = portals[k - 1]
        per_gate = []
        for angle in portal["angles"]:
            best = min(
                float(
                    annulus_path_length(
                        portal["inner_radius"], angle, inner["outer_radius"], inner_angle, inner["outer_radius"]
                    )
                )
                + d
                for inner_angle, d in zip(inner["angles"], distances[k - 1], strict=True)
            )
            per_gate.append(through + best)
        distances.append(np.array(per_gate))
    return distances


def geodesic_tables(portals: list[dict[str, Any]], mids: list[float], to_channel: int) -> dict[str, Any]:
    """The tables of the geodesic distance to ``to_channel``, from the walls' portals (innermost
    first) and mid radii."""
    distances = gate_distances(portals, to_channel)
    gate_lists = [
        (p["outer_radius"], [(float(a), float(d)) for a, d in zip(p["angles"], ds, strict=True)])
        for p, ds in zip(portals, distances, strict=True)
    ]
    # A marble whose centre is within a wall's band (inside a gate) belongs, for the geodesic
    # distance, to the inner channel: it moves radially to the gate's inner end first.
    bounds = [p["outer_radius"] for p in portals]
    channels = [
        (a, portals[k + 1]["inner_radius"] if k + 1 < len(portals) else math.inf, gates)
        for k, (a, gates) in enumerate(gate_lists)
    ]
    max_gates = max((len(p["angles"]) for p in portals), default=1)
    gate_angle = np.zeros((len(portals) + 1, max_gates))
    gate_dist = np.full((len(portals) + 1, max_gates), np.inf)
    for k, (_, gates) in enumerate(gate_lists):
        for j, (angle, dist) in enumerate(gates):
            gate_angle[k + 1, j], gate_dist[k + 1, j] = angle, dist
    # Points already past the target wall: 0, or the radial rest of the way through its gate.
    target_end = 0.0 if to_channel == 0 else portals[to_channel]["inner_radius"]
    return {
        "to_channel": to_channel,
        "target_end": target_end,
        "obstacle": np.array([1.0] + [c[0] for c in channels]),
        "band_start": np.array([np.inf] + [c[1] for c in channels]),
        "band_start_list": [math.inf] + [c[1] for c in channels],
        "mids": np.array(mids or [0.0]),
        "gate_angle": gate_angle,
        "gate_dist": gate_dist,
        "channels": channels,
        "bounds": np.array(bounds),
        "bounds_list": bounds,
        "portals": portals,
        "gate_distances": distances,
    }
