"""The scalar path-progress rule (bimgame.sim.labyrinth_tracker) against PathProgress, the rule's
definition, point by point on every layout: same segments, progress, flags."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.envs.labyrinth_env import path_points_ahead
from bimgame.sim.labyrinth import LabyrinthSpec, PathProgress
from bimgame.sim.labyrinth_layouts import LAYOUT_NAMES
from bimgame.sim.labyrinth_tracker import ScalarPathProgress


def wander(spec: LabyrinthSpec, rng: np.random.Generator, n: int) -> np.ndarray:
    """Points along the path with noise up to 12 mm across it, some rolling back, a few jumps."""
    path = spec.path
    s = np.cumsum(rng.normal(0.004, 0.006, n)).clip(0, path.length)
    k = np.clip(np.searchsorted(path.cumulative, s, side="right") - 1, 0, path.n_segments - 1)
    t = (s - path.cumulative[k]) / path.lengths[k]
    points = path.starts[k] + t[:, None] * path.vectors[k] + rng.uniform(-0.012, 0.012, (n, 2))
    jumps = rng.random(n) < 0.03
    points[jumps] = rng.uniform(-1, 1, (jumps.sum(), 2)) * np.array(spec.board_size) / 2
    return points


@pytest.mark.parametrize("layout", LAYOUT_NAMES)
def test_scalar_rule_equals_path_progress(layout):
    spec = LabyrinthSpec.layout(layout)
    reference, fast = PathProgress(spec), ScalarPathProgress(spec)
    points = wander(spec, np.random.default_rng(LAYOUT_NAMES.index(layout)), 600)
    assert reference.reset(points[0]) == fast.reset(points[0])
    offs = 0
    for p in points[1:]:
        a, b = reference.update(p), fast.update(p.tolist())
        assert (a.segment, a.off_path, a.over_hole, a.goal) == (b.segment, b.off_path, b.over_hole, b.goal)
        assert a.progress == pytest.approx(b.progress, abs=1e-12) and a.delta == pytest.approx(b.delta, abs=1e-12)
        offs += a.off_path
    assert 0 < offs < len(points) - 1  # both branches exercised
    assert reference.segment > 3  # and it got somewhere


def test_points_ahead_equal_the_vectorised_ones():
    spec = LabyrinthSpec.layout("hard")
    fast = ScalarPathProgress(spec)
    for progress in (0.0, 0.0123, 0.5, spec.path.length - 0.02, spec.path.length):
        expected = path_points_ahead(spec.path, progress)
        assert np.array(fast.points_ahead(progress, 5, 0.012)) == pytest.approx(expected, abs=1e-15)
