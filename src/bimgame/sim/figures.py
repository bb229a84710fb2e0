"""A labelled drawing of a maze (walls, gates, channels, geodesic distance) as a PNG.

Drawn and written with :mod:`bimgame.util.images` (no pyplot)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.patches import Circle, Wedge

from bimgame.sim.maze import MazeSpec
from bimgame.util.images import save_png, subplots

__all__ = ["draw_maze", "draw_maze_grid"]


def draw_maze(spec: MazeSpec, path: str | Path, *, geodesic: bool = True, dpi: int = 150) -> Path:
    """Draw ``spec`` to a PNG at ``path``: walls and rim in grey, gates labelled with their angle
    and width, channels numbered, and (optionally) the geodesic distance to the centre as a
    colour map over the floor. Written atomically; returns the path."""
    extent = spec.rim_radius + spec.rim_thickness
    fig, ax = subplots(figsize=(7, 7))
    if geodesic:
        image = ax.imshow(
            _geodesic_image(spec),
            extent=(-extent * 1e3, extent * 1e3, -extent * 1e3, extent * 1e3),
            origin="lower",
            cmap="viridis",
            alpha=0.85,
        )
        fig.colorbar(image, ax=ax, shrink=0.75, label="geodesic distance to the centre (mm)")
    _draw_walls(ax, spec)
    for wall in spec.walls:
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


def _geodesic_image(spec: MazeSpec, n: int = 400) -> np.ndarray:
    """The geodesic distance to the centre (mm) on an n × n grid over the board (NaN off the floor)."""
    extent = spec.rim_radius + spec.rim_thickness
    xs = np.linspace(-extent, extent, n)
    gx, gy = np.meshgrid(xs, xs)
    dist = spec.geodesic_distance(gx, gy) * 1e3
    dist[np.hypot(gx, gy) > spec.rim_radius] = np.nan
    return dist


def _draw_walls(ax, spec: MazeSpec) -> None:
    """The solid parts of the walls and the rim, in grey."""
    grey = "0.45"
    extent = spec.rim_radius + spec.rim_thickness
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
    ax.add_patch(Wedge((0, 0), extent * 1e3, 0, 360, width=spec.rim_thickness * 1e3, color=grey))


def draw_maze_grid(
    specs: list[MazeSpec], titles: list[str], path: str | Path, *, columns: int = 4, dpi: int = 110
) -> Path:
    """Several mazes side by side (walls over the geodesic distance, one colour scale for all), each
    titled; written atomically to ``path``. For pictures of random mazes (:mod:`bimgame.sim.maze_sets`)."""
    if not specs or len(specs) != len(titles):
        raise ValueError(
            f"draw_maze_grid needs as many titles as mazes (at least one), got {len(specs)} and {len(titles)}"
        )
    rows = math.ceil(len(specs) / columns)
    cols = min(columns, len(specs))
    fig, axes = subplots(rows, cols, figsize=(2.6 * cols, 2.7 * rows), squeeze=False, layout="constrained")
    images = [_geodesic_image(spec, 200) for spec in specs]
    top = float(np.nanmax([np.nanmax(image) for image in images]))
    for index, ax in enumerate(axes.flat):
        ax.set_axis_off()
        if index >= len(specs):
            continue
        spec = specs[index]
        extent = (spec.rim_radius + spec.rim_thickness) * 1e3
        ax.imshow(
            images[index], extent=(-extent, extent, -extent, extent), origin="lower", cmap="viridis", vmin=0, vmax=top
        )
        _draw_walls(ax, spec)
        ax.set_xlim(-extent - 1, extent + 1)
        ax.set_ylim(-extent - 1, extent + 1)
        ax.set_aspect("equal")
        ax.set_title(titles[index], fontsize=8)
    return save_png(fig, path, dpi=dpi)
