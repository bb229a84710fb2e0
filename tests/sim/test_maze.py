"""Tests of the maze geometry (bimgame.sim.maze): MERL's numbers, validation, channels, geodesic distance.

All lengths in metres, angles in radians unless a name says ``_deg``/``_mm``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bimgame.sim.maze import Friction, Gate, MazeSpec, MazeSpecError, Wall, annulus_path_length

MM = 1e-3

# Public facts of MERL's circular maze, the paper's.
MERL_WALL_SPANS_MM = [(16.0, 21.2), (36.0, 41.3), (56.2, 61.4), (76.2, 81.7)]
MERL_RIM_MM = 96.8
MERL_CHANNEL_CENTRES_MM = [27.86, 48.17, 68.48, 88.79]  # channels 1..4
MERL_GATES_DEG = [
    ([180.0], 50.0),
    ([45.0, 135.0, 225.0, 315.0], 21.4),
    ([0.0, 90.0, 180.0, 270.0], 14.6),
    ([45.0, 135.0, 225.0, 315.0], 11.1),
]


@pytest.fixture(scope="module")
def merl() -> MazeSpec:
    return MazeSpec.merl()


def _deg_mod(angle: float) -> float:
    return math.degrees(angle) % 360.0


def _polar(r, theta_deg):
    t = np.radians(theta_deg)
    return np.asarray(r) * np.cos(t), np.asarray(r) * np.sin(t)


# --------------------------------------------------------------------------------------- MERL spec
def test_merl_validates_and_matches_design(merl: MazeSpec):
    merl.validate()  # must not raise
    assert merl.n_channels == 5 and merl.outermost_channel == 4
    assert len(merl.walls) == 4
    for wall, (inner, outer) in zip(merl.walls, MERL_WALL_SPANS_MM):
        assert wall.inner_radius == pytest.approx(inner * MM, abs=1e-9)
        assert wall.outer_radius == pytest.approx(outer * MM, abs=1e-9)
        assert 4.5 * MM <= wall.thickness <= 5.6 * MM  # "≈ 5 mm thick"
    assert merl.rim_radius == pytest.approx(MERL_RIM_MM * MM, abs=1e-9)
    for wall, (angles, width) in zip(merl.walls, MERL_GATES_DEG):
        got = sorted((_deg_mod(g.angle), math.degrees(g.width)) for g in wall.gates)
        assert len(got) == len(angles)
        for (a, w), a_ref in zip(got, sorted(angles)):
            assert a == pytest.approx(a_ref, abs=1e-9)
            assert w == pytest.approx(width, abs=1e-9)
    # Wall-3 gates are "≈ 15 mm arcs" at the wall's mid radius.
    w3 = merl.walls[3]
    assert w3.gates[0].width * w3.mid_radius == pytest.approx(15 * MM, abs=0.5 * MM)
    assert merl.marble_radius == pytest.approx(6.35 * MM, abs=1e-12)
    assert merl.marble_mass == pytest.approx(8.4e-3, abs=1e-12)
    assert merl.wall_height == pytest.approx(20 * MM)
    assert merl.max_tilt == pytest.approx(math.radians(5.0))
    assert merl.tilt_step == pytest.approx(math.radians(1.0))
    f = merl.friction
    assert (f.slide, f.spin, f.roll, f.static) == pytest.approx((0.5, 1e-5, 1e-6, 1e-6))
    low = Friction.low()
    assert (low.slide, low.spin, low.roll) == pytest.approx((0.001, 1e-6, 1e-7))


def test_design_channel_centres_fit_their_channels(merl: MazeSpec):
    """MERL's channel-centre radii lie in channels 1..4 with room for the marble on both sides,
    and the spec's own centre radii are the channel midpoints (within 0.75 mm of MERL's)."""
    for k, centre_mm in enumerate(MERL_CHANNEL_CENTRES_MM, start=1):
        low, high = merl.channel_bounds(k)
        c = centre_mm * MM
        assert low + merl.marble_radius < c < high - merl.marble_radius
        assert merl.channel_centre_radius(k) == pytest.approx(0.5 * (low + high))
        assert abs(merl.channel_centre_radius(k) - c) < 0.75 * MM
    assert merl.channel_bounds(0) == (0.0, merl.walls[0].inner_radius)
    assert merl.channel_bounds(4) == (merl.walls[3].outer_radius, merl.rim_radius)
    with pytest.raises(MazeSpecError, match="channel must be in 0..4"):
        merl.channel_bounds(5)


def test_gates_are_tight_but_passable(merl: MazeSpec):
    """At a wall's inner face each gate is only 0.7–2 mm wider than the marble."""
    d = 2 * merl.marble_radius
    for wall in merl.walls[1:]:
        for gate in wall.gates:
            chord = 2 * wall.inner_radius * math.sin(gate.width / 2)
            assert 0.5 * MM < chord - d < 2.2 * MM


def test_solid_arcs_and_in_gate(merl: MazeSpec):
    w3 = merl.walls[3]
    arcs = w3.solid_arcs()
    assert len(arcs) == 4
    half = w3.gates[0].width / 2
    total_solid = sum(b - a for a, b in arcs)
    assert total_solid == pytest.approx(2 * math.pi - 4 * w3.gates[0].width)
    for a, b in arcs:
        assert -math.pi <= a < math.pi and b > a
        mid = 0.5 * (a + b)
        assert not w3.in_gate(mid) and w3.in_gate(a - 0.5 * half) and w3.in_gate(b + 0.5 * half)
    angles = np.radians([45.0, 45.0 + 5.5, 45.0 + 5.6, 90.0, -45.0, 135.0 + 360.0])
    assert w3.in_gate(angles).tolist() == [True, True, False, False, True, True]
    # Wall 0's single gate straddles the ±pi seam.
    assert merl.walls[0].in_gate(np.radians([180.0, -179.0, 156.0, 154.0, 0.0])).tolist() == [
        True, True, True, False, False]
    assert Wall(0.02, 0.025, ()).solid_arcs() == [(-math.pi, math.pi)]


# --------------------------------------------------------------------------------------- validation
def _wall(inner_mm, outer_mm, *gates_deg):
    return Wall(inner_mm * MM, outer_mm * MM, tuple(Gate.deg(a, w) for a, w in gates_deg))


def test_validation_gate_narrower_than_marble():
    # At 36 mm, a 12.7 mm marble needs > 20.3° of gate.
    with pytest.raises(MazeSpecError, match=r"walls\[1\]\.gates\[0\] is 20\.00° wide.*diameter"):
        MazeSpec(walls=(_wall(16, 21, (180, 60)), _wall(36, 41, (0, 20.0))), rim_radius=0.06)
    MazeSpec(walls=(_wall(16, 21, (180, 60)), _wall(36, 41, (0, 20.5))), rim_radius=0.06)


def test_validation_overlapping_walls():
    with pytest.raises(MazeSpecError, match=r"walls\[1\].*overlaps walls\[0\]"):
        MazeSpec(walls=(_wall(16, 40, (0, 60)), _wall(36, 41, (0, 40))), rim_radius=0.08)


@pytest.mark.parametrize("inner2_mm, match", [
    (33.0, r"channel 1 is 12\.00 mm wide, narrower than the marble.*walls\[1\]\.inner_radius"),
    (33.8, r"channel 1 is 12\.80 mm wide"),  # just wider than 12.7 mm: must pass
])
def test_validation_channel_narrower_than_marble(inner2_mm, match):
    walls = (_wall(16, 21, (180, 60)), _wall(inner2_mm, inner2_mm + 5, (0, 40)))
    if inner2_mm < 33.7:
        with pytest.raises(MazeSpecError, match=match):
            MazeSpec(walls=walls, rim_radius=0.08)
    else:
        MazeSpec(walls=walls, rim_radius=0.08)


def test_validation_centre_and_outermost_channel_too_narrow():
    with pytest.raises(MazeSpecError, match="the centre region is"):
        MazeSpec(walls=(_wall(12, 16, (0, 90)),), rim_radius=0.08)
    with pytest.raises(MazeSpecError, match="outermost channel.*rim_radius must exceed"):
        MazeSpec(walls=(_wall(16, 21, (0, 90)),), rim_radius=0.033)


@pytest.mark.parametrize("field", ["marble_radius", "rim_radius", "marble_mass", "wall_height",
                                   "tilt_step", "max_tilt"])
@pytest.mark.parametrize("value", [0.0, -1e-3, float("nan"), float("inf")])
def test_validation_non_positive_scalars(merl: MazeSpec, field, value):
    with pytest.raises(MazeSpecError, match=rf"^{field} must be a positive finite number"):
        merl.replace(**{field: value})


def test_validation_tilt_step_exceeds_max_tilt(merl: MazeSpec):
    with pytest.raises(MazeSpecError, match=r"tilt_step .* must not exceed max_tilt"):
        merl.replace(tilt_step=math.radians(6), max_tilt=math.radians(5))
    merl.replace(tilt_step=math.radians(5), max_tilt=math.radians(5))  # equal is fine


def test_validation_overlapping_gates():
    # At 36 mm a 30° gate is wide enough (> 20.3°); two of them 20° apart overlap.
    with pytest.raises(MazeSpecError, match=r"walls\[0\]: gates at 10\.0° and 30\.0° overlap"):
        MazeSpec(walls=(_wall(36, 41, (10, 30), (30, 30)),), rim_radius=0.06)
    # Across the ±180° seam too.
    with pytest.raises(MazeSpecError, match=r"walls\[0\]: gates at .* overlap"):
        MazeSpec(walls=(_wall(36, 41, (170, 30), (-170, 30)),), rim_radius=0.06)
    MazeSpec(walls=(_wall(36, 41, (10, 30), (45, 30)),), rim_radius=0.06)  # 5° apart: ok


def test_validation_wall_without_gates():
    with pytest.raises(MazeSpecError, match=r"walls\[1\] has no gate"):
        MazeSpec(walls=(_wall(16, 21, (0, 60)), _wall(36, 41)), rim_radius=0.06)


@pytest.mark.parametrize("field", ["slide", "spin", "roll", "static"])
def test_validation_negative_friction(merl: MazeSpec, field):
    with pytest.raises(MazeSpecError, match=rf"friction\.{field} must be a non-negative"):
        merl.replace(friction=Friction(**{field: -1e-6}))
    merl.replace(friction=Friction(**{field: 0.0}))  # zero is allowed


def test_validation_error_is_value_error_and_bad_types(merl: MazeSpec):
    assert issubclass(MazeSpecError, ValueError)
    with pytest.raises(MazeSpecError, match="friction must be a Friction"):
        merl.replace(friction=(0.5, 1e-5, 1e-6, 1e-6))
    with pytest.raises(MazeSpecError, match=r"walls\[0\] must be a Wall"):
        MazeSpec(walls=((0.016, 0.021, ()),), rim_radius=0.05)
    with pytest.raises(MazeSpecError, match="wall_height"):
        merl.replace(wall_height=10e-3)  # lower than the marble's diameter


# --------------------------------------------------------------------------------------- channels
def test_channel_of_at_channel_centres(merl: MazeSpec):
    radii = [0.0] + [c * MM for c in MERL_CHANNEL_CENTRES_MM]
    for theta in np.linspace(-180, 180, 13):
        x, y = _polar(radii, theta)
        assert merl.channel_of(x, y).tolist() == [0, 1, 2, 3, 4]
    # Own centre radii too, scalar input.
    for k in range(5):
        assert int(merl.channel_of(merl.channel_centre_radius(k), 0.0)) == k
    # Boundaries are the walls' mid radii.
    for k, wall in enumerate(merl.walls):
        assert int(merl.channel_of(wall.mid_radius - 1e-6, 0.0)) == k
        assert int(merl.channel_of(wall.mid_radius + 1e-6, 0.0)) == k + 1


def test_update_channel_hysteresis(merl: MazeSpec):
    w3 = merl.walls[3]
    inside_low = w3.inner_radius + 0.2 * w3.thickness   # below the mid radius
    inside_high = w3.inner_radius + 0.8 * w3.thickness  # above the mid radius
    x = np.array([inside_low, inside_high, w3.inner_radius - 0.1 * MM, w3.outer_radius + 0.1 * MM])
    y = np.zeros_like(x)
    # Coming from outside (channel 4): kept inside the wall's thickness, changed past the inner face.
    assert merl.update_channel(np.full(4, 4), x, y).tolist() == [4, 4, 3, 4]
    # Coming from inside (channel 3): kept inside the thickness, changed past the outer face.
    assert merl.update_channel(np.full(4, 3), x, y).tolist() == [3, 3, 3, 4]
    # channel_of itself splits at the mid radius.
    assert merl.channel_of(x, y).tolist() == [3, 4, 3, 4]
    # Wall 0 and the centre: from channel 1, the centre counts only below wall 0's inner face.
    w0 = merl.walls[0]
    r = np.array([w0.inner_radius + 0.1 * MM, w0.inner_radius - 0.1 * MM])
    assert merl.update_channel(np.array([1, 1]), r, 0 * r).tolist() == [1, 0]
    # ... and from the centre, channel 1 only beyond wall 0's outer face.
    assert merl.update_channel(np.array([0, 0]), r + w0.thickness, 0 * r).tolist() == [1, 0]
    # A sequence of positions through a gate: only one transition, at the far face.
    radii = np.linspace(88 * MM, 70 * MM, 200)
    ch, history = np.int64(4), []
    for rr in radii:
        ch = merl.update_channel(ch, *_polar(rr, 45.0))
        history.append(int(ch))
    changes = np.flatnonzero(np.diff(history))
    assert len(changes) == 1 and radii[changes[0] + 1] < w3.inner_radius <= radii[changes[0]]


# --------------------------------------------------------------------------------------- geodesic
def test_geodesic_zero_at_origin_and_radial_in_centre(merl: MazeSpec):
    assert float(merl.geodesic_distance(0.0, 0.0)) == 0.0
    rng = np.random.default_rng(0)
    r = rng.uniform(0, merl.walls[0].mid_radius * 0.999, 500)
    th = rng.uniform(-np.pi, np.pi, 500)
    x, y = r * np.cos(th), r * np.sin(th)
    np.testing.assert_allclose(merl.geodesic_distance(x, y), r, rtol=0, atol=1e-15)


def test_geodesic_gate_angle_closer_than_between_gates(merl: MazeSpec):
    r4 = merl.channel_centre_radius(4)
    at_gate = float(merl.geodesic_distance(*_polar(r4, 45.0)))
    between = float(merl.geodesic_distance(*_polar(r4, 90.0)))
    assert at_gate < between
    # Between two gates 90° apart the detour is the arc to the gate: at least 40° of arc.
    assert between - at_gate > math.radians(40) * (merl.walls[3].outer_radius + merl.marble_radius)
    # From a gate's outer portal the rest is radial through the wall plus the inner channels.
    d3 = merl.gate_distances()[3]
    assert np.all(d3 > merl.walls[3].outer_radius + merl.marble_radius)


def test_geodesic_at_least_straight_line_distance(merl: MazeSpec):
    rng = np.random.default_rng(1)
    n = 5000
    r = np.sqrt(rng.uniform(0, merl.rim_radius ** 2, n))
    th = rng.uniform(-np.pi, np.pi, n)
    x, y = r * np.cos(th), r * np.sin(th)
    d = merl.geodesic_distance(x, y)
    assert d.shape == (n,)
    assert np.all(np.isfinite(d))
    assert np.all(d >= r - 1e-12)
    # In the outer channels the detour through gates makes it strictly longer (for points the
    # marble's centre can occupy: not inside a wall's solid part).
    outer = (merl.channel_of(x, y) >= 2) & _free_space(merl, r, th)
    assert np.all(d[outer] > r[outer] + 5 * MM)


def _free_space(spec: MazeSpec, r: np.ndarray, th: np.ndarray) -> np.ndarray:
    """Where the marble's centre can be: not within a marble radius of a wall's solid part."""
    free = r <= spec.rim_radius - spec.marble_radius
    for wall in spec.walls:
        band = (r > wall.inner_radius - spec.marble_radius) & (r < wall.outer_radius + spec.marble_radius)
        free &= ~band | wall.in_gate(th)
    return free


def test_geodesic_mirror_symmetry(merl: MazeSpec):
    """Every gate of MERL's maze is symmetric under y -> -y (wall 0's single gate at 180° too), so
    the distance is; x -> -x is *not* a symmetry (wall 0's gate would move to 0°)."""
    rng = np.random.default_rng(2)
    n = 2000
    r = np.sqrt(rng.uniform(0, merl.rim_radius ** 2, n))
    th = rng.uniform(-np.pi, np.pi, n)
    x, y = r * np.cos(th), r * np.sin(th)
    np.testing.assert_allclose(merl.geodesic_distance(x, -y), merl.geodesic_distance(x, y),
                               rtol=0, atol=1e-12)
    # Not symmetric under x -> -x: at channel 1's centre, 0° is farther from the 180° gate.
    r1 = merl.channel_centre_radius(1)
    assert float(merl.geodesic_distance(r1, 0.0)) > float(merl.geodesic_distance(-r1, 0.0)) + 30 * MM


def test_geodesic_four_fold_symmetry_of_outer_walls():
    """With wall 0 given 4-fold gates too, the whole maze is symmetric under 90° rotations."""
    base = MazeSpec.merl()
    w0 = base.walls[0]
    spec = base.replace(walls=(Wall(w0.inner_radius, w0.outer_radius,
                                    tuple(Gate.deg(a, 50.0) for a in (0, 90, 180, 270))),)
                        + base.walls[1:])
    rng = np.random.default_rng(3)
    r = np.sqrt(rng.uniform(0, spec.rim_radius ** 2, 1000))
    th = rng.uniform(-np.pi, np.pi, 1000)
    d = spec.geodesic_distance(r * np.cos(th), r * np.sin(th))
    for q in (1, 2, 3):
        rot = th + q * np.pi / 2
        np.testing.assert_allclose(spec.geodesic_distance(r * np.cos(rot), r * np.sin(rot)), d,
                                   rtol=0, atol=1e-12)


def _gate_path(spec: MazeSpec, step: float = 0.25 * MM) -> tuple[np.ndarray, np.ndarray]:
    """Points along MERL's shortest route from channel 4 (at 30°) to the centre, following the
    channel-centre arcs and crossing each wall radially at a gate: 30°→45° in channel 4, through
    wall 3 at 45°, 45°→90° in channel 3, through wall 2 at 90°, 90°→135° in channel 2, through
    wall 1 at 135°, 135°→180° in channel 1, through wall 0 at 180° to the centre (the gates that
    lead towards wall 0's only gate, at 180°)."""
    rc = [spec.channel_centre_radius(k) for k in range(5)]
    legs = [("arc", 4, 30.0, 45.0), ("radial", 45.0, rc[4], rc[3]), ("arc", 3, 45.0, 90.0),
            ("radial", 90.0, rc[3], rc[2]), ("arc", 2, 90.0, 135.0), ("radial", 135.0, rc[2], rc[1]),
            ("arc", 1, 135.0, 180.0), ("radial", 180.0, rc[1], 0.0)]
    xs, ys = [], []
    for leg in legs:
        if leg[0] == "arc":
            _, k, a0, a1 = leg
            n = max(2, int(abs(math.radians(a1 - a0)) * rc[k] / step))
            t = np.linspace(a0, a1, n, endpoint=False)
            x, y = _polar(np.full(n, rc[k]), t)
        else:
            _, a, r0, r1 = leg
            n = max(2, int(abs(r1 - r0) / step))
            x, y = _polar(np.linspace(r0, r1, n, endpoint=False), np.full(n, a))
        xs.append(x)
        ys.append(y)
    xs.append(np.array([0.0]))
    ys.append(np.array([0.0]))
    return np.concatenate(xs), np.concatenate(ys)


def test_geodesic_non_increasing_along_gate_path(merl: MazeSpec):
    x, y = _gate_path(merl)
    d = merl.geodesic_distance(x, y)
    assert d[-1] == 0.0
    assert np.all(np.diff(d) <= 1e-12)
    # And it falls the whole way overall: the start is > 19 cm from the goal.
    assert d[0] > 0.19


def test_geodesic_strictly_decreasing_along_gate_path(merl: MazeSpec):
    x, y = _gate_path(merl)
    d = merl.geodesic_distance(x, y)
    assert np.all(np.diff(d) < 0)


def test_geodesic_is_lipschitz_along_gate_path(merl: MazeSpec):
    x, y = _gate_path(merl, step=0.1 * MM)
    d = merl.geodesic_distance(x, y)
    seg = np.hypot(np.diff(x), np.diff(y))
    assert np.all(np.abs(np.diff(d)) <= seg * (1 + 1e-9) + 1e-12)


def test_geodesic_is_lipschitz_within_channels(merl: MazeSpec):
    """Inside each channel, away from the walls' thickness, moving the point by a small step changes
    the distance by at most the step."""
    rng = np.random.default_rng(4)
    for k in range(1, 5):
        low, high = merl.channel_bounds(k)
        r = rng.uniform(low + merl.marble_radius, high - merl.marble_radius, 2000)
        th = rng.uniform(-np.pi, np.pi, 2000)
        x, y = r * np.cos(th), r * np.sin(th)
        dx, dy = rng.normal(size=(2, 2000)) * 0.05 * MM
        x2, y2 = x + dx, y + dy
        r2 = np.hypot(x2, y2)
        ok = (merl.channel_of(x2, y2) == k) & (r2 >= low + merl.marble_radius) & (r2 <= high - merl.marble_radius)
        d1 = merl.geodesic_distance(x[ok], y[ok])
        d2 = merl.geodesic_distance(x2[ok], y2[ok])
        assert np.all(np.abs(d2 - d1) <= np.hypot(dx, dy)[ok] * (1 + 1e-9) + 1e-12)


# --------------------------------------------------------------------------------------- annulus path
def _brute_force_path(p1, p2, a) -> float:
    """Shortest path from p1 to p2 outside the disc |p| < a, by brute force: the straight segment if
    it clears the disc, else the best polyline p1 -> c(phi1) -> arc -> c(phi2) -> p2 over a grid of
    touching angles (coarse, then refined around the best cell), keeping only segments that leave
    the circle outwards. No tangent formulas involved."""
    p1, p2 = np.asarray(p1, float), np.asarray(p2, float)
    d = p2 - p1
    t = np.clip(-p1 @ d / (d @ d), 0.0, 1.0) if d @ d > 0 else 0.0
    if np.linalg.norm(p1 + t * d) >= a:
        return float(np.linalg.norm(d))

    def best(phi1, phi2):
        c1 = a * np.stack([np.cos(phi1), np.sin(phi1)], axis=1)
        c2 = a * np.stack([np.cos(phi2), np.sin(phi2)], axis=1)
        # Segment c -> p stays outside the disc iff (p - c)·c >= 0 (p on the circle: only c = p).
        l1 = np.where(np.einsum("ij,ij->i", p1 - c1, c1) >= -1e-15, np.linalg.norm(p1 - c1, axis=1), np.inf)
        l2 = np.where(np.einsum("ij,ij->i", p2 - c2, c2) >= -1e-15, np.linalg.norm(p2 - c2, axis=1), np.inf)
        dphi = np.abs((phi1[:, None] - phi2[None, :] + np.pi) % (2 * np.pi) - np.pi)
        total = l1[:, None] + a * dphi + l2[None, :]
        i, j = np.unravel_index(np.argmin(total), total.shape)
        return total[i, j], phi1[i], phi2[j]

    extra = [math.atan2(p[1], p[0]) for p in (p1, p2)]  # a point on the circle touches there
    coarse = np.concatenate([np.linspace(-np.pi, np.pi, 1440, endpoint=False), extra])
    value, f1, f2 = best(coarse, coarse)
    h = 2 * np.pi / 1440
    fine1 = np.concatenate([np.linspace(f1 - 2 * h, f1 + 2 * h, 2001), [f1]])
    fine2 = np.concatenate([np.linspace(f2 - 2 * h, f2 + 2 * h, 2001), [f2]])
    return float(min(value, best(fine1, fine2)[0]))


@pytest.mark.parametrize("r1, th1_deg, r2, th2_deg, a", [
    (0.09, 90.0, 0.088, 45.0, 0.088),    # wraps: channel 4, 45° away from a gate portal
    (0.09, 180.0, 0.088, 0.0, 0.085),    # half way round
    (0.05, -30.0, 0.048, 100.0, 0.047),  # wraps the other way across 0
    (0.2, 10.0, 0.15, 170.0, 0.05),      # far points, wrap
    (0.07, 0.0, 0.07, 10.0, 0.068),      # nearly tangent, straight clears
    (0.0875, 170.0, 0.0875, -170.0, 0.08),  # across the ±180° seam
])
def test_annulus_path_length_matches_brute_force(r1, th1_deg, r2, th2_deg, a):
    t1, t2 = math.radians(th1_deg), math.radians(th2_deg)
    p1 = (r1 * math.cos(t1), r1 * math.sin(t1))
    p2 = (r2 * math.cos(t2), r2 * math.sin(t2))
    exact = float(annulus_path_length(r1, t1, r2, t2, a))
    brute = _brute_force_path(p1, p2, a)
    assert exact == pytest.approx(brute, rel=1e-6, abs=1e-9)
    assert exact >= math.dist(p1, p2) - 1e-15


def test_annulus_path_length_straight_when_clear():
    rng = np.random.default_rng(5)
    a = 0.03
    r1 = rng.uniform(a, 0.1, 300)
    th1 = rng.uniform(-np.pi, np.pi, 300)
    r2, th2 = 0.06, 0.4
    p2 = np.array([r2 * math.cos(th2), r2 * math.sin(th2)])
    p1 = np.stack([r1 * np.cos(th1), r1 * np.sin(th1)], axis=1)
    d = p2 - p1
    t = np.clip(-np.einsum("ij,ij->i", p1, d) / np.einsum("ij,ij->i", d, d), 0, 1)
    clearance = np.linalg.norm(p1 + t[:, None] * d, axis=1)
    got = annulus_path_length(r1, th1, r2, th2, a)
    straight = np.linalg.norm(d, axis=1)
    clear = clearance >= a
    assert clear.sum() > 50 and (~clear).sum() > 20
    np.testing.assert_allclose(got[clear], straight[clear], rtol=1e-12, atol=1e-15)
    assert np.all(got[~clear] > straight[~clear])
    # Each blocked case agrees with the brute force too (spot check a few).
    for i in np.flatnonzero(~clear)[:5]:
        assert got[i] == pytest.approx(_brute_force_path(p1[i], p2, a), rel=1e-6)
    # Same point: zero.
    assert float(annulus_path_length(0.05, 1.0, 0.05, 1.0, 0.04)) == pytest.approx(0.0, abs=1e-12)


# --------------------------------------------------------------------------------------- geodesic to a wall
def test_geodesic_to_a_wall_is_zero_past_it_and_cheapest_through_the_nearest_gate(merl: MazeSpec):
    r4 = merl.channel_centre_radius(4)
    # STG1's goal (channel 3): from 30° the nearest wall-3 gate is at 45°, not the centre's route.
    d = float(merl.geodesic_distance(*_polar(r4, 30.0), to_channel=3))
    through = merl.walls[3].thickness + 2 * merl.marble_radius
    arc = math.radians(15.0) * (merl.walls[3].outer_radius + merl.marble_radius)
    assert through < d < through + arc + 2 * MM
    # Already in channel 3 or deeper: nothing left to do.
    assert float(merl.geodesic_distance(*_polar(merl.channel_centre_radius(2), 10.0), to_channel=3)) == 0.0
    # Every target is no farther than the centre, and farther targets cost more.
    rng = np.random.default_rng(5)
    r = np.sqrt(rng.uniform(0, merl.rim_radius ** 2, 2000))
    th = rng.uniform(-np.pi, np.pi, 2000)
    x, y = r * np.cos(th), r * np.sin(th)
    distances = [merl.geodesic_distance(x, y, to_channel=j) for j in (3, 2, 1, 0)]
    for nearer, farther in zip(distances, distances[1:]):
        assert np.all(nearer <= farther + 1e-12)
    for j in (0, 1, 2, 3):
        scalar = np.array([merl.geodesic_distance_one(a, b, to_channel=j) for a, b in zip(x[:300], y[:300])])
        np.testing.assert_allclose(scalar, merl.geodesic_distance(x[:300], y[:300], to_channel=j), atol=1e-12)
    with pytest.raises(MazeSpecError, match="to_channel must be an integer in 0..3"):
        merl.geodesic_distance(0.0, 0.0, to_channel=4)


def test_geodesic_does_not_reward_sinking_into_a_wall(merl: MazeSpec):
    """Soft contacts let a marble that hits a wall sink into it by up to v/150 s; pressed into the
    solid part of a wall from outside it is still outside, so a planner gains nothing by it."""
    face = merl.walls[3].outer_radius + merl.marble_radius  # marble centre touching wall 3
    at_face = float(merl.geodesic_distance(*_polar(face, 90.0)))  # 90°: no gate in wall 3
    for depth in (0.5 * MM, 1 * MM, 3 * MM):
        assert float(merl.geodesic_distance(*_polar(face - depth, 90.0))) == pytest.approx(at_face, abs=1e-12)
        assert merl.geodesic_distance_one(*_polar(face - depth, 90.0)) == pytest.approx(at_face, abs=1e-12)
    # ... while in a gate the same radial move is real progress.
    gate_face = float(merl.geodesic_distance(*_polar(face, 45.0)))
    assert float(merl.geodesic_distance(*_polar(face - 3 * MM, 45.0))) == pytest.approx(gate_face - 3 * MM, abs=1e-9)
