"""The stage schedule of a backward start curriculum: how far from the goal episodes may start, and
when that distance grows.

Backplay (Resnick et al., 2018) and Salimans & Chen (2018) start episodes a short way before the goal
and move the starts back once the policy succeeds from there. Stage k lets a start lie up to ``D_k``
back (``D_0 = first_back``, ``D_{k+1} = D_k · growth``, rounded up for whole steps); once the last
``window`` episodes started in the current stage succeeded at a rate of at least ``threshold``, the
next stage begins. After the stage whose ``D_k`` reaches ``longest`` comes the final one, where every
start is the task's own (:attr:`BackwardStages.finished`).

The maze's demonstration curriculum counts ``D_k`` in steps of an expert episode
(:class:`~bimgame.learn.starts.DemoStartCurriculum`), the labyrinth's in metres of the printed path
(:class:`~bimgame.learn.path_starts.PathStartCurriculum`); both keep this one schedule, and
:class:`StagedStarts` is what such a curriculum does besides choosing its starts: the share of true
starts, the tags, ``record`` and the common part of ``status``. Every start curriculum checks its
settings and tags with :func:`check_int`, :func:`check_real` and :func:`check_tag`.
"""

from __future__ import annotations

import collections
import math
from typing import Any

import numpy as np

from bimgame.util.settings import is_integer, is_real

__all__ = ["TRUE_START", "check_int", "check_real", "check_tag", "BackwardStages", "StagedStarts"]

#: The tag of an episode started from the task's own start distribution (a sampler returned None).
TRUE_START = -1


def check_int(owner: str, name: str, value: Any, minimum: int) -> int:
    """``value`` as an int if it is an integer >= ``minimum``, else ``ValueError`` naming ``owner.name``."""
    if not (is_integer(value) and value >= minimum):
        raise ValueError(f"{owner}.{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def check_real(
    owner: str, name: str, value: Any, low: float, high: float, *, open_low: bool = False, allowed: str = ""
) -> float:
    """``value`` as a float if it is a finite number in [low, high] (or (low, high] with ``open_low``),
    else ``ValueError`` naming ``owner.name`` and ``allowed`` (default: the interval)."""
    inside = is_real(value) and math.isfinite(value) and (value > low if open_low else value >= low) and value <= high
    if not inside:
        bracket = "(" if open_low else "["
        shown = allowed or f"a number in {bracket}{low:g}, {high:g}]"
        raise ValueError(f"{owner}.{name} must be {shown}, got {value!r}")
    return float(value)


def check_tag(owner: str, tag: Any) -> int:
    """A start tag given to ``owner.record`` as an int, else ``ValueError``."""
    if not is_integer(tag):
        raise ValueError(
            f"{owner}.record: tag must be an integer (a start tag, {TRUE_START} for a true start), got {tag!r}"
        )
    return int(tag)


class BackwardStages:
    """Stages ``D_0 < D_1 < …`` up to ``longest`` and the success window that moves them on.

    Args:
        owner: the curriculum's name, for error messages.
        first_back: ``D_0`` (> 0); None: ``longest`` at once, one stage holding every start.
        growth: factor from one stage's ``D_k`` to the next (> 1).
        longest: the farthest a start can lie back; the stage reaching it is the last before the
            final one.
        threshold: success rate over ``window`` episodes of the current stage that ends it, in (0, 1].
        window: episodes the rate is taken over (>= 1).
        whole: round each ``D_k`` up to a whole number (steps).
    """

    def __init__(
        self,
        owner: str,
        first_back: float | None,
        growth: float,
        longest: float,
        *,
        threshold: float,
        window: int,
        whole: bool = False,
    ):
        if first_back is None:
            first_back = longest
        if not (math.isfinite(first_back) and first_back > 0 and math.isfinite(longest) and longest > 0):
            raise ValueError(f"{owner}: first_back and the longest distance must be finite and > 0")
        self.owner, self.growth, self.longest = owner, float(growth), float(longest)
        self.threshold, self.window = float(threshold), int(window)
        self.backs: list[float] = [first_back]
        while self.backs[-1] < longest:
            grown = self.backs[-1] * growth
            self.backs.append(math.ceil(grown) if whole else grown)
        self.stage = 0
        self._results: collections.deque[bool] = collections.deque(maxlen=self.window)

    @property
    def finished(self) -> bool:
        """Whether the final stage is reached: every start is a true start."""
        return self.stage >= len(self.backs)

    @property
    def back(self) -> float:
        """How far back the current stage's starts may lie (``longest`` once finished)."""
        return self.longest if self.finished else min(self.backs[self.stage], self.longest)

    @property
    def window_success(self) -> float:
        """Success rate of the current stage's episodes so far (0 before any)."""
        return sum(self._results) / len(self._results) if self._results else 0.0

    def record(self, stage: int, success: bool) -> None:
        """Count a finished episode started in ``stage``: only the current stage's move it on."""
        if self.finished or stage != self.stage:
            return
        self._results.append(bool(success))
        if len(self._results) == self.window and sum(self._results) >= self.threshold * self.window:
            self.stage += 1
            self._results.clear()


class StagedStarts:
    """A start curriculum of :class:`BackwardStages`: a subclass sets ``stages`` and ``true_share``
    and chooses the start of each stage; this class draws the true starts, tags episodes by stage,
    records their outcomes and reports the status every staged curriculum has."""

    stages: BackwardStages
    true_share: float

    @property
    def finished(self) -> bool:
        """Whether the final stage is reached: every start is a true start."""
        return self.stages.finished

    @property
    def stage(self) -> int:
        """The current stage's index (``len(stages.backs)`` once finished)."""
        return self.stages.stage

    def true_start(self, rng: np.random.Generator) -> bool:
        """Whether the next episode starts from the task's own starts (once finished, always; else
        with probability ``true_share``, one draw from ``rng``)."""
        return self.finished or rng.random() < self.true_share

    def record(self, tag: int, success: bool) -> None:
        """Count a finished episode (tag: the stage it started in): only the current stage's move the
        curriculum on; :data:`TRUE_START` episodes are not counted."""
        self.stages.record(check_tag(type(self).__name__, tag), success)

    def stage_status(self) -> dict[str, float]:
        """The stage, the share of true starts and the success rate of the current stage's window."""
        return {
            "curriculum_stage": float(self.stage),
            "true_start_share": 1.0 if self.finished else self.true_share,
            "curriculum_window_success": self.stages.window_success,
        }
