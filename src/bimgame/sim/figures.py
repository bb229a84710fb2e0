"""A labelled drawing of a maze (walls, gates, channels, geodesic distance) as a PNG.

Drawn and written with :mod:`bimgame.util.images` (no pyplot)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.patches import Circle, Wedge

from bimgame.sim.maze import MazeSpec
from bimgame.util.images import save_png, subplots

__all__ = ["draw_maze"]


def draw_maze(spec: MazeSpec, path: str | Path, *, geodesic: bool = True, dpi: int = 150) -> Path:
    """Draw ``spec`` to a PNG at ``path``: walls and rim in grey, gates labelled with their angle
    and width, channels numbered, and (optionally) the geodesic distance to the centre as a
    colour map over the floor. Written atomically; returns the path."""
    extent = spec.rim_radius + spec.rim_thickness
    fig, ax = subplots(figsize=(7, 7))
    if geodesic:
        n = 400
        xs = np.linspace(-extent, extent, n)
        gx, gy = np.meshgrid(xs, xs)
        dist = spec.geodesic_distance(gx, gy) * 1e3
        dist[np.hypot(gx, gy) > spec.rim_radius] = np.nan
        image = ax.imshow(
            dist,
            extent=(-extent * 1e3, extent * 1e3, -extent * 1e3, extent * 1e3),
            origin="lower",
            cmap="viridis",
            alpha=0.85,
        )
        fig.colorbar(image, ax=ax, shrink=0.75, label="geodesic distance to the centre (mm)")
    grey = "0.45"
    for wall in spec.walls:
        for start, end in wall.solid_arcs():
            ax.add_patch(
                Wedge(
                    (0, 0),
                    wall.outer_radius * 1e3,
                    math.degrees(start),
                    math.degrees(end),
                    width=wall.thickness * 1e3,
                    color=grey,
                )
            )
        for gate in wall.gates:
            r = wall.outer_radius * 1e3 + 4
            ax.annotate(
                f"{math.degrees(gate.angle) % 360:.0f}°\n{math.degrees(gate.width):.1f}°",
                (r * math.cos(gate.angle), r * math.sin(gate.angle)),
                fontsize=6,
                ha="center",
                va="center",
                color="white",
            )
    ax.add_patch(Wedge((0, 0), extent * 1e3, 0, 360, width=spec.rim_thickness * 1e3, color=grey))
    for channel in range(spec.n_channels):
        radius = spec.channel_centre_radius(channel) * 1e3
        angle = math.radians(200)
        ax.text(
            radius * math.cos(angle),
            radius * math.sin(angle),
            str(channel),
            fontsize=9,
            ha="center",
            va="center",
            color="white",
            weight="bold",
        )
    start_radius = spec.channel_centre_radius(spec.outermost_channel) * 1e3
    ax.add_patch(Circle((start_radius, 0), spec.marble_radius * 1e3, color="#d0d4dc", ec="black", lw=0.5))
    ax.set_xlim(-extent * 1e3 - 2, extent * 1e3 + 2)
    ax.set_ylim(-extent * 1e3 - 2, extent * 1e3 + 2)
    ax.set_aspect("equal")
    ax.set_xlabel("board x (mm)")
    ax.set_ylabel("board y (mm)")
    ax.set_title(
        f"{len(spec.walls)}-wall circular maze; marble Ø {2 * spec.marble_radius * 1e3:.2f} mm "
        "(white numbers: channels)",
        fontsize=9,
    )
    return save_png(fig, path, dpi=dpi, bbox_inches="tight")
