"""The geodesic distance's geometry: shortest paths around a disc and the per-target tables of
gate-to-goal distances, from plain radii and angles (a :class:`~bimgame.sim.maze.MazeSpec` builds
them once per target and caches them).

A wall is described here by its *portal*: its gates' centre angles and the radii where the marble's
centre enters a gate from outside (``outer_radius``) and leaves it inside (``inner_radius``).
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

__all__ = ["wrap_angle", "wrap_angle_one", "annulus_path_length", "gate_distances", "geodesic_tables"]

_TWO_PI = 2 * math.pi
#: Arrays of at least this many elements take :func:`wrap_angle`'s shift instead of the remainder.
_FAST_WRAP_SIZE = 64


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Wrap angles to [-pi, pi): ``(angle + pi) % 2pi - pi``.

    Large float64 arrays whose ``y = angle + pi`` all lie in ``[-2pi, 4pi)`` (differences of two
    wrapped angles, the common case) skip the remainder (``fmod``, ~5 ns an element) for a shift by
    one period, which gives the same bits: ``fmod`` is exact, ``y - 2pi`` is exact for ``y`` in
    ``[2pi, 4pi)`` (Sterbenz), on ``(-2pi, 0)`` the remainder is ``y + 2pi`` rounded, as here, and a
    zero's sign is lost in the final ``- pi`` (a test compares the two on edge cases)."""
    y = np.asarray(angle) + np.pi
    if y.dtype == np.float64 and y.size >= _FAST_WRAP_SIZE and y.min() >= -_TWO_PI and y.max() < 2 * _TWO_PI:
        shifted = y - np.where(y >= _TWO_PI, _TWO_PI, 0.0)
        shifted += np.where(y < 0, _TWO_PI, 0.0)
        shifted -= np.pi
        return shifted
    return y % (2 * np.pi) - np.pi


def wrap_angle_one(angle: float) -> float:
    """:func:`wrap_angle` of one float, in plain Python (~15x faster than numpy on a scalar): the same
    IEEE operations — Python's float ``%`` is numpy's ``remainder`` — so the same bits (a test checks)."""
    return (float(angle) + math.pi) % _TWO_PI - math.pi


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
    lengths = _portal_pair_lengths(portals)
    distances: list[np.ndarray] = []
    for k, portal in enumerate(portals):
        through = portal["outer_radius"] - portal["inner_radius"]
        count = len(portal["angles"])
        if k < to_channel:
            distances.append(np.full(count, np.inf))
            continue
        if k == to_channel:
            rest = portal["inner_radius"] if k == 0 else 0.0
            distances.append(np.full(count, through + rest))
            continue
        inner = np.full(lengths.shape[2], np.inf)  # padded gates: never the best
        inner[: len(distances[k - 1])] = distances[k - 1]
        distances.append(through + np.min(lengths[k - 1, :count] + inner, axis=1))
    return distances


def _portal_pair_lengths(portals: list[dict[str, Any]]) -> np.ndarray:
    """``annulus_path_length`` from each gate of wall ``k`` (its inner portal) to each gate of wall
    ``k - 1`` (its outer portal, on the obstacle circle), for every ``k >= 1`` at once: (walls - 1,
    gates, gates), gates padded (their lengths unused). The radii's terms are computed per wall by
    :func:`_pair_terms` as :func:`annulus_path_length` computes them from scalar radii, and combined
    with the angles by its elementwise operations in its order: the same bits as a call per pair."""
    if len(portals) < 2:
        return np.zeros((0, 1, 1))
    most = max(len(p["angles"]) for p in portals)
    angles = np.zeros((len(portals), most))
    for k, portal in enumerate(portals):
        angles[k, : len(portal["angles"])] = portal["angles"]
    radii = tuple((p["inner_radius"], p["outer_radius"]) for p in portals)
    sums, products, tangents, obstacle, alpha1, alpha2 = _pair_terms(radii)
    dtheta = np.abs(wrap_angle(angles[1:, :, None] - angles[:-1, None, :]))
    straight = np.sqrt(np.maximum(sums - products * np.cos(dtheta), 0.0))
    wrapped = tangents + obstacle * (dtheta - alpha1 - alpha2)
    return np.where(dtheta <= alpha1 + alpha2, straight, wrapped)


@functools.lru_cache(maxsize=64)
def _pair_terms(radii: tuple[tuple[float, float], ...]) -> tuple[np.ndarray, ...]:
    """Per wall ``k >= 1`` (portal radii ``(inner, outer)`` per wall), shaped (walls - 1, 1, 1): the
    terms of :func:`annulus_path_length` from radius ``inner_k`` to ``outer_{k-1}`` around a disc of
    ``outer_{k-1}`` that do not depend on the angles — ``r1² + r2²``, ``2 r1 r2``, the two tangents'
    sum, the obstacle radius and the tangent angles — each by its expression there, on numpy scalars
    (cached: they depend on the board only)."""
    terms = []
    for (inner, _), (_, outer) in zip(radii[1:], radii[:-1], strict=True):
        a = np.asarray(outer, dtype=float)
        r1 = np.maximum(np.asarray(inner, dtype=float), a)
        r2 = np.maximum(np.asarray(outer, dtype=float), a)
        alpha1 = np.arccos(np.minimum(a / r1, 1.0))
        alpha2 = np.arccos(np.minimum(a / r2, 1.0))
        tangents = np.sqrt(np.maximum(r1**2 - a**2, 0.0)) + np.sqrt(np.maximum(r2**2 - a**2, 0.0))
        terms.append((r1**2 + r2**2, 2 * r1 * r2, tangents, a, alpha1, alpha2))
    columns = tuple(np.array(column, dtype=float).reshape(-1, 1, 1) for column in zip(*terms, strict=True))
    for column in columns:
        column.flags.writeable = False
    return columns


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
