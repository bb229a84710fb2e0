"""Image files, written atomically: matplotlib figures as PNG, RGB frames as animated GIF.

Figures are made with :func:`subplots`, matplotlib's object-oriented ``Figure`` rather than pyplot:
no GUI backend is chosen or changed, so drawing works with no display (servers, CI, spawned workers)
and importing bimgame never switches the backend of a user's notebook."""

from __future__ import annotations

import io
import sys
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from PIL import Image

from bimgame.util.files import atomic_write_bytes

__all__ = ["subplots", "save_png", "write_gif"]


def subplots(nrows: int = 1, ncols: int = 1, **options: Any) -> tuple[Figure, Any]:
    """``(figure, axes)`` like ``pyplot.subplots`` (``figsize``, ``constrained_layout`` … go to the
    figure, ``sharex``, ``squeeze`` … to its axes), without pyplot."""
    figure_keys = {"figsize", "dpi", "constrained_layout", "layout", "facecolor"}
    figure = Figure(**{k: v for k, v in options.items() if k in figure_keys})
    axes = figure.subplots(nrows, ncols, **{k: v for k, v in options.items() if k not in figure_keys})
    return figure, axes


def save_png(fig: Any, path: str | Path, *, dpi: int, **savefig_options: Any) -> Path:
    """Write a matplotlib figure to ``path`` as a PNG, atomically; returns the path. A figure made
    with pyplot is closed too, so that pyplot does not keep it alive."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi, **savefig_options)
    pyplot = sys.modules.get("matplotlib.pyplot")
    if pyplot is not None:
        pyplot.close(fig)
    return atomic_write_bytes(path, buffer.getvalue())


def write_gif(frames: list[np.ndarray], path: str | Path, fps: int = 30, max_frames: int = 600) -> Path:
    """Write RGB frames as an animated GIF (atomically), keeping at most ``max_frames`` by
    skipping frames evenly."""
    if not frames:
        raise ValueError("no frames to write")
    stride = max(1, int(np.ceil(len(frames) / max_frames)))
    images = [Image.fromarray(frame) for frame in frames[::stride]]
    buffer = io.BytesIO()
    images[0].save(
        buffer, format="GIF", save_all=True, append_images=images[1:], duration=round(1000 * stride / fps), loop=0
    )
    return atomic_write_bytes(path, buffer.getvalue())
