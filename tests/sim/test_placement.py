"""Marble placement (bimgame.sim.placement): random starts keep their draws, never loop for ever and
keep marbles apart; given positions are checked against walls, rim and each other exactly."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bimgame.sim.maze import Gate, MazeSpec, Wall
from bimgame.sim.placement import (
    MAX_START_DRAWS,
    check_marble_xy,
    check_n_marbles,
    finite_array,
    max_start_marbles,
    sample_start,
    start_radius,
    start_separation,
)

SPEC = MazeSpec.merl()


def reference_sample_start(spec: MazeSpec, n_marbles: int, rng: np.random.Generator) -> np.ndarray:
    """The original sampler (one marble at a time, redrawn while too close): it loops for ever once
    it jams, so it is only called here for starts that do not."""
    radius = spec.channel_centre_radius(spec.outermost_channel)
    min_separation = 2 * (2 * spec.marble_radius) / radius
    angles: list[float] = []
    while len(angles) < n_marbles:
        candidate = float(rng.uniform(-math.pi, math.pi))
        if all(abs((candidate - a + math.pi) % (2 * math.pi) - math.pi) > min_separation for a in angles):
            angles.append(candidate)
    angles_arr = np.array(angles)
    return np.stack([radius * np.cos(angles_arr), radius * np.sin(angles_arr)], axis=-1)


def min_angular_gap(xy: np.ndarray) -> float:
    angle = np.arctan2(xy[:, 1], xy[:, 0])
    gap = np.abs((angle[:, None] - angle[None] + np.pi) % (2 * np.pi) - np.pi)
    gap[np.arange(len(xy)), np.arange(len(xy))] = np.inf
    return float(gap.min())


class ConstantRng:
    """A generator that always draws the same number: the original sampler never gets past the
    second marble with it."""

    def uniform(self, low, high, size=None):
        return low if size is None else np.full(size, float(low))

    def permutation(self, n):
        return np.arange(n)


def test_how_many_marbles_fit():
    # MERL: the centre circle of the outermost channel (89.25 mm) holds 22 marbles 25.4 mm apart.
    assert start_radius(SPEC) == pytest.approx(0.08925)
    assert max_start_marbles(SPEC) == 22 == math.ceil(2 * math.pi / start_separation(SPEC)) - 1
    assert max_start_marbles(SPEC.replace(marble_radius=0.005)) == 28
    assert max_start_marbles(MazeSpec(walls=(), rim_radius=0.05)) == 0
    with pytest.raises(ValueError, match="random starts need a maze with at least one wall"):
        check_n_marbles(MazeSpec(walls=(), rim_radius=0.05), 1)
    assert check_n_marbles(SPEC, np.int64(22)) == 22
    with pytest.raises(ValueError, match="n_marbles=23 is too many: at most 22"):
        check_n_marbles(SPEC, 23)
    with pytest.raises(ValueError, match="n_marbles=23 is too many"):
        sample_start(SPEC, 23, np.random.default_rng(0))


@pytest.mark.parametrize("n", [1, 2, 5, 10, 14])
def test_starts_that_do_not_jam_make_the_original_draws(n):
    for seed in range(25):
        a, b = np.random.default_rng(seed), np.random.default_rng(seed)
        np.testing.assert_array_equal(sample_start(SPEC, n, a), reference_sample_start(SPEC, n, b))
        assert a.bit_generator.state == b.bit_generator.state  # and leave the generator alike


@pytest.mark.parametrize("n", [15, 16, 18, 20, 22])
def test_jamming_starts_are_placed_at_once_and_stay_apart(n):
    separation = start_separation(SPEC)
    for seed in range(20):
        xy = sample_start(SPEC, n, np.random.default_rng(seed))
        assert xy.shape == (n, 2)
        np.testing.assert_allclose(np.hypot(xy[:, 0], xy[:, 1]), start_radius(SPEC), rtol=1e-12)
        assert min_angular_gap(xy) > separation * (1 - 1e-9)
        check_marble_xy(SPEC, xy)
    # Deterministic.
    np.testing.assert_array_equal(sample_start(SPEC, n, np.random.default_rng(3)),
                                  sample_start(SPEC, n, np.random.default_rng(3)))


def test_the_loop_is_bounded_even_if_draws_never_fit():
    xy = sample_start(SPEC, 3, ConstantRng())  # every draw is -π: the 2nd marble never fits
    assert min_angular_gap(xy) >= start_separation(SPEC) * (1 - 1e-9)
    assert MAX_START_DRAWS <= 100_000


def test_spaced_starts_cover_the_circle_uniformly():
    """Placed at once, arrangements are uniform: each marble's angle is uniform on the circle."""
    angles = np.concatenate([np.arctan2(*sample_start(SPEC, 22, np.random.default_rng(s))[:, ::-1].T)
                             for s in range(200)])
    counts, _ = np.histogram(angles, bins=8, range=(-math.pi, math.pi))
    assert counts.min() > 0.8 * len(angles) / 8


# ------------------------------------------------------------------ check_marble_xy
def _brute_force_clearance(spec: MazeSpec, x: float, y: float) -> float:
    """Distance from (x, y) to the walls' solid parts, by sampling them densely (0.05 mm, 0.05°)."""
    best = math.inf
    for wall in spec.walls:
        radii = np.linspace(wall.inner_radius, wall.outer_radius, 8)
        angles = np.radians(np.arange(-180.0, 180.0, 0.05))
        angles = angles[~wall.in_gate(angles)]
        px = radii[:, None] * np.cos(angles)[None]
        py = radii[:, None] * np.sin(angles)[None]
        best = min(best, float(np.min(np.hypot(px - x, py - y))))
    return best


def test_wall_check_agrees_with_a_brute_force_distance():
    rng = np.random.default_rng(0)
    rm = SPEC.marble_radius
    limit = SPEC.rim_radius - rm
    checked = refused = 0
    for _ in range(400):
        r, a = rng.uniform(0, limit), rng.uniform(-math.pi, math.pi)
        x, y = r * math.cos(a), r * math.sin(a)
        clearance = _brute_force_clearance(SPEC, x, y)
        if abs(clearance - rm) < 0.2e-3:
            continue  # too close to call at the brute force's resolution
        checked += 1
        if clearance < rm:
            refused += 1
            with pytest.raises(ValueError, match=r"overlaps walls\[\d\]"):
                check_marble_xy(SPEC, np.array([[x, y]]))
        else:
            check_marble_xy(SPEC, np.array([[x, y]]))
    assert checked > 300 and 50 < refused < checked - 50


def test_gates_are_open_for_a_marble_that_fits():
    # A gate just wider than the marble at its inner face: a marble centred in it fits at the wall's
    # inner face, one off-centre does not.
    walls = (Wall(0.03, 0.035, (Gate.deg(0.0, 30.0),)),)
    spec = MazeSpec(walls=walls, rim_radius=0.06)
    check_marble_xy(spec, np.array([[0.03, 0.0]]))
    with pytest.raises(ValueError, match=r"overlaps walls\[0\] \(solid from 30\.00 to 35\.00 mm .*gates at 0\.0°"):
        check_marble_xy(spec, np.array([[0.03 * math.cos(0.1), 0.03 * math.sin(0.1)]]))


def test_rim_and_marble_overlaps_are_refused_and_touching_is_allowed():
    rm = SPEC.marble_radius
    edge = SPEC.rim_radius - rm
    check_marble_xy(SPEC, np.array([[0.0, edge]]))
    with pytest.raises(ValueError, match=r"marble_xy\[0\] .* overlaps the rim or lies off the board"):
        check_marble_xy(SPEC, np.array([[0.0, edge + 1e-6]]))
    check_marble_xy(SPEC, np.array([[-rm, 0.0], [rm, 0.0]]))
    with pytest.raises(ValueError, match=r"marbles 0 and 1 overlap: marble_xy\[0\] and marble_xy\[1\] are 12\.70 mm"):
        check_marble_xy(SPEC, np.array([[-rm + 1e-6, 0.0], [rm, 0.0]]))


def test_finite_array_says_what_is_wrong():
    np.testing.assert_array_equal(finite_array("v", [[1, 2]], (1, 2)), [[1.0, 2.0]])
    with pytest.raises(ValueError, match=r"v is not finite at \(0, 1\), \(1, 0\)"):
        finite_array("v", [[0, np.inf], [np.nan, 0]], (2, 2))
    with pytest.raises(ValueError, match=r"v must have shape \(2, 2\) \(why\), got shape \(3,\)"):
        finite_array("v", [1, 2, 3], (2, 2), " (why)")
    with pytest.raises(ValueError, match=r"v must be numbers of shape \(2,\)"):
        finite_array("v", [[1], [2, 3]], (2,))
    with pytest.raises(ValueError, match=r"v must be numbers"):
        finite_array("v", "abc", (2,))
