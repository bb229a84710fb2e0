"""Where a policy's labyrinth episodes ended: the board with the spot on the path each episode
reached, and the progress reached along the path, from a
:func:`~bimgame.experiments.labyrinth_protocol.summarise_labyrinth` summary (what
``bimgame score --task LABYRINTH-… --figure`` draws).

Why a picture: a success rate of 0% on the hard layout hides whether a policy loses the marble
everywhere or at one narrow passage; the board shows the passage, the histogram how many episodes
end there. An episode's spot is the path's point at its progress reached
(:meth:`~bimgame.sim.labyrinth.WaypointPath.point_at`): where the marble last made progress before
it fell into a hole or left the path (two markers), stopped at the time limit or reached the goal —
not the hole it fell into, which the summary does not hold. Episodes that end within :data:`CLUSTER_M` of path of
each other, the same way, share one marker whose size (capped) and label count them.
"""

from __future__ import annotations

import textwrap
from collections import Counter
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.sim.labyrinth_render import background, sheet_grid
from bimgame.util.images import save_png, subplots

__all__ = ["CLUSTER_M", "END_STYLES", "end_clusters", "plot_episode_ends"]

#: Episodes that end this close along the path (m), the same way, share a marker.
CLUSTER_M = 0.01
#: How each way of ending is drawn: (label, colour, marker).
END_STYLES: dict[str, tuple[str, str, str]] = {
    "hole": ("fell into a hole", "crimson", "X"),
    "off_path": ("left the path", "purple", "P"),
    "fall": ("fell (hole or off the path)", "crimson", "X"),  # summaries that did not tell the two apart
    "time": ("time limit", "darkorange", "o"),
    "goal": ("goal", "forestgreen", "*"),
}
#: Resolution of the board picture (m per pixel).
_PIXEL = 0.5e-3


def _summary_fields(summary: Mapping[str, Any]) -> tuple[LabyrinthSpec, np.ndarray, list[str]]:
    """The board, progress fractions and endings of ``summary``; ``ValueError`` naming what is missing."""
    missing = [key for key in ("layout", "progress_fractions", "ended") if key not in summary]
    if missing:
        raise ValueError(
            f"not a labyrinth score summary: it lacks {', '.join(missing)} (write one with bimgame score "
            "--task LABYRINTH-EASY|MEDIUM|HARD --out FILE)"
        )
    fractions = np.asarray(summary["progress_fractions"], dtype=np.float64)
    ended = [str(e) for e in summary["ended"]]
    if len(ended) != len(fractions) or not set(ended) <= set(END_STYLES):
        raise ValueError(
            f"summary's ended must name one of {', '.join(END_STYLES)} per episode ({len(fractions)}), got {ended!r}"
        )
    return LabyrinthSpec.layout(str(summary["layout"])), fractions, ended


def end_clusters(summary: Mapping[str, Any]) -> list[tuple[str, float, int]]:
    """The summary's episode ends grouped: ``(ending, arc length (m), episodes)``, one per ending and
    :data:`CLUSTER_M` of path, at the mean arc length of its episodes; most episodes first."""
    return _clusters(*_summary_fields(summary))


def _clusters(spec: LabyrinthSpec, fractions: np.ndarray, ended: list[str]) -> list[tuple[str, float, int]]:
    """:func:`end_clusters` of the summary's checked fields."""
    arcs = fractions * spec.path.length
    groups: dict[tuple[str, int], list[float]] = {}
    for how, arc in zip(ended, arcs, strict=True):
        groups.setdefault((how, int(np.floor(arc / CLUSTER_M))), []).append(float(arc))
    clusters = [(how, float(np.mean(members)), len(members)) for (how, _), members in groups.items()]
    return sorted(clusters, key=lambda c: (-c[2], c[1]))


def _draw_board(ax: Any, spec: LabyrinthSpec, clusters: list[tuple[str, float, int]]) -> None:
    grid = sheet_grid(spec, pixel=_PIXEL, margin=0)
    extent = [1e3 * grid.left, 1e3 * (grid.left + grid.width * _PIXEL), 1e3 * (grid.top - grid.height * _PIXEL)]
    ax.imshow(background(spec, grid, colour=True), extent=[*extent, 1e3 * grid.top], interpolation="bilinear")
    path = spec.path
    for tenth in range(11):
        (x, y), _ = path.point_at(tenth / 10 * path.length)
        text = {0: "start", 10: "goal"}.get(tenth, f"{10 * tenth}%")
        ax.annotate(text, (1e3 * x, 1e3 * y), fontsize=6, color="navy", ha="center", va="center")
    for how, arc, count in clusters:
        _, colour, marker = END_STYLES[how]
        (x, y), _ = path.point_at(arc)
        size = min(40 + 15 * count, 200)  # capped: a large cluster must not hide the hole beside it
        ax.scatter(1e3 * x, 1e3 * y, s=size, c=colour, marker=marker, edgecolors="white", alpha=0.9, zorder=3)
        if count > 1:
            ax.annotate(str(count), (1e3 * x, 1e3 * y), xytext=(6, 6), textcoords="offset points", fontsize=8,
                        color=colour, fontweight="bold", zorder=4)  # fmt: skip
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")


def _draw_histogram(ax: Any, fractions: np.ndarray, ended: list[str]) -> None:
    bins = np.linspace(0.0, 100.0, 51)
    shown = [how for how in END_STYLES if how in ended]  # a legend of the endings that happened
    ax.hist(
        [100 * fractions[[e == how for e in ended]] for how in shown],
        bins=bins,
        stacked=True,
        color=[END_STYLES[how][1] for how in shown],
        label=[END_STYLES[how][0] for how in shown],
    )
    ax.locator_params(axis="y", integer=True)  # episode counts
    ax.set_xlim(0, 100)
    ax.set_xlabel("progress reached (% of the path)")
    ax.set_ylabel("episodes")
    ax.legend(fontsize=8, loc="upper right")


def _falls(counts: Counter[str]) -> str:
    """The falls of a summary's endings in words: holes and the path apart where it tells them apart."""
    if counts["fall"]:
        return f"{counts['fall'] + counts['hole'] + counts['off_path']} fell"
    return f"{counts['hole']} in a hole, {counts['off_path']} off the path"


def plot_episode_ends(summary: Mapping[str, Any], path: str | Path, *, title: str | None = None) -> Path:
    """Draw where ``summary``'s episodes ended (see the module notes) to PNG ``path``, atomically;
    returns the path. ``ValueError`` if ``summary`` is not a labyrinth score summary."""
    spec, fractions, ended = _summary_fields(summary)
    fig, (board, histogram) = subplots(1, 2, figsize=(12, 4.8), gridspec_kw={"width_ratios": [1.3, 1]})
    _draw_board(board, spec, _clusters(spec, fractions, ended))  # the summary read and checked once
    _draw_histogram(histogram, fractions, ended)
    counts = Counter(ended)
    default = (
        f"{summary.get('policy', 'policy')} on {summary.get('task', summary['layout'])}: {len(ended)} episodes, "
        f"{counts['goal']} at the goal, {_falls(counts)}, {counts['time']} at the time limit; "
        f"mean progress {100 * float(np.mean(fractions)):.0f}%"
    )
    fig.suptitle("\n".join(textwrap.wrap(title or default, 140)), fontsize=10)
    fig.tight_layout()
    return save_png(fig, path, dpi=130)
