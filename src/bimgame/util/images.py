"""Image files, written atomically: matplotlib figures as PNG, RGB frames as animated GIF.

Figures are made with :func:`subplots`, matplotlib's object-oriented ``Figure`` rather than pyplot:
no GUI backend is chosen or changed, so drawing works with no display (servers, CI, spawned workers)
and importing bimgame never switches the backend of a user's notebook.

matplotlib is imported when a figure is first made, not with this module: the learners' spawned
worker processes import the run-logging modules that use this one but never draw, and matplotlib
was about a second of each worker's start (1.7 s on a loaded machine)."""

from __future__ import annotations

import io
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image

from bimgame.util.files import atomic_write_bytes

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["subplots", "save_png", "write_gif"]


def subplots(nrows: int = 1, ncols: int = 1, **options: Any) -> tuple[Figure, Any]:
    """``(figure, axes)`` like ``pyplot.subplots`` (``figsize``, ``constrained_layout`` … go to the
    figure, ``sharex``, ``squeeze`` … to its axes), without pyplot."""
    from matplotlib.figure import Figure  # lazily: see the module docstring

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
