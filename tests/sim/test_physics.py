"""Tests of the MuJoCo physics (bimgame.sim.MazeSim): rolling, static friction, walls and gates,
energy, determinism, tilt servo, two marbles and the board-frame kinematics.

SI units throughout. Where a check needs physics-step resolution (contacts last a few
milliseconds), the simulator is built with ``substeps=1`` and each action's tilt change is split
into equal parts over the substeps; that ramps the board exactly as one 5-substep action does.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bimgame.sim.maze import Friction, MazeSpec
from bimgame.sim.physics import CONTROL_HZ, PHYSICS_HZ, MazeSim

G = 9.81
DEG = math.pi / 180
MM = 1e-3


# --------------------------------------------------------------------------------------- helpers
def board_to_world(tilt) -> np.ndarray:
    """Rotation matrix Rx(a)·Ry(b): board-frame vectors to world-frame vectors."""
    a, b = tilt
    ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
    rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    return rx @ ry


def flat_spec(**kw) -> MazeSpec:
    return MazeSpec(walls=(), rim_radius=0.3, **kw)


def polar(r: float, angle_deg: float) -> np.ndarray:
    return np.array([r * math.cos(angle_deg * DEG), r * math.sin(angle_deg * DEG)])


def launch(sim: MazeSim, velocities_board, *, rolling: bool = False) -> None:
    """Give each marble a board-frame in-plane velocity (board at rest, as after reset). With
    ``rolling`` the angular velocity matches rolling without slip (ω = n × v / r; the body frame is
    the world frame right after reset, whose quaternion is the identity)."""
    state = sim.get_state()
    lay = sim.layout
    rot = board_to_world(state[lay.tilt])
    normal = rot[:, 2]
    for i, v in enumerate(np.atleast_2d(velocities_board)):
        vb = np.array([v[0], v[1], 0.0])
        vw = rot @ vb
        state[lay.marble_vel[i]] = vw
        if rolling:
            assert np.array_equal(state[lay.marble_quat[i]], [1.0, 0.0, 0.0, 0.0])
            state[lay.marble_angvel[i]] = np.cross(normal, vw) / sim.spec.marble_radius
    sim.set_state(state)


def board_xyz(sim: MazeSim) -> np.ndarray:
    """Board-frame marble positions (n_marbles, 3)."""
    return sim.marble_kinematics()[0]


def marble_energy(sim: MazeSim, state: np.ndarray, i: int = 0) -> float:
    """½ m v² + ½ I ω² + m g z of marble i (world frame; |ω| is frame independent)."""
    lay = sim.layout
    m, r = sim.spec.marble_mass, sim.spec.marble_radius
    v = state[lay.marble_vel[i]]
    w = state[lay.marble_angvel[i]]
    z = state[lay.marble_pos[i]][2]
    return 0.5 * m * v @ v + 0.5 * (0.4 * m * r * r) * w @ w + m * G * z


def rolling_acceleration(
    friction: Friction, tilt_y: float, settle: float = 0.2, duration: float = 0.5
) -> tuple[float, np.ndarray]:
    """Board-frame x acceleration of a marble released at rest on a wall-free board tilted by
    ``tilt_y`` about y: finite difference of the velocity over ``duration`` after ``settle``."""
    sim = MazeSim(flat_spec(friction=friction))
    sim.reset(np.array([[-0.2 * np.sign(tilt_y), 0.0]]), tilt=(0.0, tilt_y))
    for _ in range(round(settle * CONTROL_HZ)):
        sim.step(np.zeros(2))
    _, v0 = sim.marble_kinematics()
    t0 = sim.data.time
    for _ in range(round(duration * CONTROL_HZ)):
        sim.step(np.zeros(2))
    p1, v1 = sim.marble_kinematics()
    acc = (v1[0] - v0[0]) / (sim.data.time - t0)
    return float(acc[0]), acc


def static_theory(spec: MazeSpec, theta: float, f: float) -> float:
    """Rolling without slip with frictionloss f on the translational (N) and rotational (N·m)
    degrees of freedom: 1.4 m a = m g sinθ − f (1 + 1/r)."""
    m, r = spec.marble_mass, spec.marble_radius
    return (m * G * math.sin(theta) - f * (1 + 1 / r)) / (1.4 * m)


@pytest.fixture(scope="module")
def merl() -> MazeSpec:
    return MazeSpec.merl()


@pytest.fixture(scope="module")
def merl_fine(merl) -> MazeSim:
    """MERL's maze stepped one physics step at a time."""
    return MazeSim(merl, substeps=1)


def test_rates():
    sim = MazeSim(flat_spec())
    assert sim.model.opt.timestep == pytest.approx(1 / PHYSICS_HZ)
    assert sim.control_dt == pytest.approx(1 / CONTROL_HZ)
    assert sim.substeps == 5


# --------------------------------------------------------------------------------------- rolling
THETA = 5 * DEG
ROLL_THEORY = 5 / 7 * G * math.sin(THETA)  # 0.6107 m/s²
SLIDE_THEORY = G * math.sin(THETA)  # 0.8550 m/s²

CONDIM_BUG = (
    "sim/physics.py contact_condim(): MERL's friction (slide 0.5, spin 1e-5, roll 1e-6) has spin == mjMINMU, "
    "so condim=6 is chosen and MuJoCo raises the rolling friction 1e-6 to 1e-5 "
    "(d.contact.friction == [0.5, 0.5, 1e-5, 1e-5, 1e-5]): the marble rolls 2.2% slower than "
    "(5/7) g sinθ without static friction (0.5973 vs 0.6107 m/s²) and 2.3% slower than the static-"
    "friction theory with it (0.5838 vs 0.5972). condim=4 (torsional only) gives 0.6073 / 0.5938."
)


def test_rolling_direction_and_plane():
    """Rotating the board by +θ about +y maps (x, 0, 0) to (x cosθ, 0, −x sinθ): the +x edge goes
    down, so the marble must accelerate towards +x in the board frame (and −x for −θ)."""
    rot = board_to_world((0.0, THETA))
    np.testing.assert_allclose(rot @ [1, 0, 0], [math.cos(THETA), 0, -math.sin(THETA)], atol=1e-15)
    for sign in (+1, -1):
        ax, acc = rolling_acceleration(Friction(static=0.0), sign * THETA)
        assert sign * ax > 0.5 * ROLL_THEORY
        assert abs(acc[1]) < 1e-9 and abs(acc[2]) < 1e-3  # stays on the floor, no sideways drift


def test_rolling_without_static_friction_matches_five_sevenths():
    ax, _ = rolling_acceleration(Friction(static=0.0), THETA)
    assert ax == pytest.approx(ROLL_THEORY, rel=0.01)


def test_rolling_without_static_or_torsional_friction_matches_five_sevenths():
    """Below MuJoCo's friction floor the model uses condim=3: pure rolling, (5/7) g sinθ."""
    ax, _ = rolling_acceleration(Friction(spin=1e-6, roll=1e-7, static=0.0), THETA)
    assert ax == pytest.approx(ROLL_THEORY, rel=0.01)
    assert ax < ROLL_THEORY  # soft contacts can only lose, not gain


def test_rolling_with_default_friction_matches_static_friction_theory(merl):
    f = Friction()
    ax, _ = rolling_acceleration(f, THETA)
    assert ax == pytest.approx(static_theory(merl, THETA, f.static), rel=0.015)
    assert ax == pytest.approx(ROLL_THEORY, rel=0.03)


def test_rolling_with_default_friction_is_slowed_but_rolls(merl):
    """What holds even with the condim issue: slower than frictionless rolling, far from sliding,
    and within 5% of (5/7) g sinθ."""
    ax, _ = rolling_acceleration(Friction(), THETA)
    assert ax < static_theory(merl, THETA, 0.0)
    assert ax == pytest.approx(ROLL_THEORY, rel=0.05)


def test_low_friction_slides():
    ax, _ = rolling_acceleration(Friction.low(), THETA)
    assert abs(ax - SLIDE_THEORY) < abs(ax - ROLL_THEORY)
    assert ax == pytest.approx(SLIDE_THEORY, rel=0.03)


def _max_height_after_launch(speed: float, *, rolling: bool, physics_hz: float = PHYSICS_HZ) -> float:
    """Largest board-frame height above resting contact (m) of a marble launched on a flat
    wall-free board after settling, within 0.27 s (before it can reach the rim)."""
    sim = MazeSim(flat_spec(), physics_hz=physics_hz, substeps=1)
    sim.reset(np.array([[-0.25, 0.0]]))
    n = round(physics_hz / PHYSICS_HZ)
    for _ in range(20 * n):
        sim.step(np.zeros(2))
    rest = board_xyz(sim)[0, 2]
    state = sim.get_state()
    state[sim.layout.marble_vel[0]] = [speed, 0.0, 0.0]
    r = sim.spec.marble_radius
    w = np.array([0.0, speed / r, 0.0]) if rolling else np.zeros(3)
    # Angular velocity is in the body frame; at rest the marble has not turned, so body = world.
    np.testing.assert_allclose(state[sim.layout.marble_quat[0]], [1, 0, 0, 0], atol=1e-3)
    state[sim.layout.marble_angvel[0]] = w
    sim.set_state(state)
    z = []
    for _ in range(40 * n):
        sim.step(np.zeros(2))
        z.append(board_xyz(sim)[0, 2])
    return max(z) - rest


def test_rolling_marble_stays_on_floor():
    for speed in (0.3, 0.7, 1.0):
        assert _max_height_after_launch(speed, rolling=True) < 0.1 * MM  # measured ≤ 0.042 mm


@pytest.mark.xfail(
    strict=True,
    reason=(
        "sim/physics.py (150 Hz physics): a marble sliding without spin on the floor is thrown upwards by "
        "the contact solver while friction spins it up: it rises 0.33 / 0.89 / 3.4 mm above its resting "
        "height at 0.3 / 0.5 / 1 m/s (independent of impratio, cone type and noslip iterations); at "
        "600 Hz physics the hop is ~0.1 mm. Rolling marbles do not hop (<= 0.04 mm). Sliding happens "
        "after every wall impact."
    ),
)
def test_sliding_marble_stays_on_floor():
    assert _max_height_after_launch(0.5, rolling=False) < 0.2 * MM


# --------------------------------------------------------------------------------------- static friction
STATIC_F = 2e-5  # N and N·m: breakaway at ≈ 2.2° for MERL's marble


def _breakaway(spec: MazeSpec, f: float) -> float:
    return math.asin(f * (1 + 1 / spec.marble_radius) / (spec.marble_mass * G))


def _displacement_after(spec: MazeSpec, tilt_y: float, seconds: float = 1.0) -> float:
    sim = MazeSim(spec)
    sim.reset(np.zeros((1, 2)), tilt=(0.0, tilt_y))
    p0 = board_xyz(sim)[0, :2].copy()
    for _ in range(round(seconds * CONTROL_HZ)):
        sim.step(np.zeros(2))
    return float(np.linalg.norm(board_xyz(sim)[0, :2] - p0))


def test_breakaway_tilt_is_small():
    spec = flat_spec(friction=Friction(static=STATIC_F))
    assert 1 * DEG < _breakaway(spec, STATIC_F) < 2.5 * DEG


def test_static_friction_holds_below_breakaway():
    spec = flat_spec(friction=Friction(static=STATIC_F))
    assert _displacement_after(spec, 0.5 * _breakaway(spec, STATIC_F)) < 0.2 * MM


def test_static_friction_releases_above_breakaway():
    spec = flat_spec(friction=Friction(static=STATIC_F))
    theta = _breakaway(spec, STATIC_F)
    moved = _displacement_after(spec, 2 * theta)
    assert moved > 2 * MM
    # Sub-threshold motion (if any) is much slower than above threshold.
    assert _displacement_after(spec, 0.5 * theta) < 0.05 * moved


# --------------------------------------------------------------------------------------- walls and gates
def _angle_away_from_gates(spec: MazeSpec, channel: int) -> float:
    """Angle (deg) in ``channel`` farthest from the gates of both walls bounding it."""
    walls = [w for k, w in enumerate(spec.walls) if k in (channel - 1, channel)]
    candidates = np.arange(0.0, 360.0, 0.5)
    clearance = np.full(candidates.shape, np.inf)
    for wall in walls:
        for gate in wall.gates:
            d = np.abs((candidates * DEG - gate.angle + np.pi) % (2 * np.pi) - np.pi) - gate.width / 2
            clearance = np.minimum(clearance, d)
    best = candidates[np.argmax(clearance)]
    assert clearance.max() > 10 * DEG
    return float(best)


@pytest.mark.parametrize(
    "channel, direction", [(0, +1), (1, -1), (1, +1), (2, -1), (2, +1), (3, -1), (3, +1), (4, -1), (4, +1)]
)
def test_walls_stop_a_fast_marble(merl, merl_fine, channel, direction):
    """Fired at 1 m/s radially into a wall away from any gate, the marble is stopped and never
    changes channel in 0.5 s (checked at every physics step). The contacts are nearly perfectly
    inelastic (rebound ≈ 1–7% of the impact speed)."""
    sim = merl_fine
    angle = _angle_away_from_gates(merl, channel)
    r0 = merl.channel_centre_radius(channel)
    sim.reset(polar(r0, angle)[None], tilt=(0.0, 0.0))
    launch(sim, direction * polar(1.0, angle)[None])
    radii, zs = [], []
    for _ in range(round(0.5 * PHYSICS_HZ)):
        sim.step(np.zeros(2))
        p = board_xyz(sim)[0]
        assert int(merl.channel_of(p[0], p[1])) == channel
        zs.append(p[2])
        radii.append(math.hypot(p[0], p[1]))
    radii = np.array(radii)
    # It never gets near the top of the wall. (It does leave the floor: launched sliding at 1 m/s
    # it hops up to 3.7 mm, see test_sliding_marble_stays_on_floor; rolling into a wall at 1 m/s
    # it climbs up to 6.5 mm, which a real rolling ball also does.)
    zs = np.array(zs) - merl.marble_radius
    assert zs.min() > -1 * MM and zs.max() < merl.wall_height - 2 * merl.marble_radius
    # It did reach the wall, and the wall stopped it within the first physics step of contact:
    # without predictive contacts the deepest overlap is (distance travelled in one step) minus
    # the clearance left at the step before, so at most speed·dt (6.7 mm at 1 m/s and 150 Hz).
    low, high = merl.channel_bounds(channel)
    one_step = 1.0 * sim.model.opt.timestep  # distance travelled in one physics step at 1 m/s
    if direction > 0:
        face = high - merl.marble_radius
        overlap = radii.max() - face
    else:
        face = low + merl.marble_radius
        overlap = face - radii.min()
    assert -0.1 * MM < overlap < one_step + 0.2 * MM
    # ... and it comes back off the wall: the last 0.2 s are spent clear of it.
    tail = radii[-round(0.2 * PHYSICS_HZ) :]
    assert np.all(tail < face + 0.5 * MM) if direction > 0 else np.all(tail > face - 0.5 * MM)


def _run_fine(sim: MazeSim, actions: np.ndarray) -> np.ndarray:
    """Apply action-level tilt changes (n, 2) at physics-step resolution; board-frame marble
    positions (n * 5, n_marbles, 3) after each physics step."""
    out = []
    for a in actions:
        for _ in range(5):
            sim.step(a / 5)
            out.append(board_xyz(sim))
    return np.array(out)


def test_random_actions_cross_walls_only_in_gates(merl, merl_fine):
    """3000 random actions (±1°/0 per axis): every channel change happens inside a gate of the wall
    crossed; the marble stays on the board's floor and inside the rim."""
    sim = merl_fine
    rng = np.random.default_rng(0)
    r4 = merl.channel_centre_radius(4)
    sim.reset(polar(r4, rng.uniform(0, 360))[None])
    actions = rng.integers(-1, 2, size=(3000, 2)) * merl.tilt_step
    pos = _run_fine(sim, actions)[:, 0]
    r = np.hypot(pos[:, 0], pos[:, 1])
    assert r.max() < merl.rim_radius - merl.marble_radius + 1 * MM
    # Tight: on fast tilt reversals near the rim the floor's vertical acceleration (r·α ≈ g) makes
    # the marble hop ~0.5 mm and then land ~1 mm deep; this seed peaks at 0.97 mm (0.92–1.02 mm
    # over seeds 0–7).
    assert np.all(np.abs(pos[:, 2] - merl.marble_radius) < 1 * MM)
    ch = merl.channel_of(pos[:, 0], pos[:, 1])
    changes = np.flatnonzero(np.diff(ch))
    assert len(changes) >= 2, "seed chosen so the marble does cross walls"
    worst = -np.inf
    for i in changes:
        a, b = ch[i], ch[i + 1]
        assert abs(int(b) - int(a)) == 1
        wall = merl.walls[min(a, b)]
        # Point where the segment between the two physics steps crosses the wall's mid radius.
        t = (wall.mid_radius - r[i]) / (r[i + 1] - r[i])
        p = pos[i, :2] + t * (pos[i + 1, :2] - pos[i, :2])
        ang = math.atan2(p[1], p[0])
        margin = min(abs((ang - g.angle + math.pi) % (2 * math.pi) - math.pi) - g.width / 2 for g in wall.gates)
        worst = max(worst, margin)
        tol = math.asin(merl.marble_radius / wall.mid_radius)
        assert wall.in_gate(ang) or margin < tol
        # Physically the whole marble fits in the gate: its centre is well inside the sector.
        assert margin < 0, f"crossed wall at {math.degrees(ang):.2f}°, {math.degrees(margin):.2f}° outside"
    assert worst < -0.5 * math.asin(merl.marble_radius / merl.walls[-1].mid_radius)


@pytest.mark.parametrize("angle, passes", [(45.0, True), (90.0, False), (0.0, False)])
def test_gate_lets_marble_through(merl, merl_fine, angle, passes):
    sim = merl_fine
    sim.reset(polar(merl.channel_centre_radius(4), angle)[None])
    launch(sim, -polar(0.3, angle)[None])
    channels = []
    for _ in range(round(0.5 * PHYSICS_HZ)):
        sim.step(np.zeros(2))
        p = board_xyz(sim)[0]
        channels.append(int(merl.channel_of(p[0], p[1])))
    if passes:
        assert 3 in channels
        assert channels[-1] == 3  # and it stays through (0.3 m/s carries it across channel 3)
    else:
        assert set(channels) == {4}


# --------------------------------------------------------------------------------------- energy
def test_energy_never_grows_on_fixed_tilted_board(merl, merl_fine):
    sim = merl_fine
    rng = np.random.default_rng(11)
    tilt = (2 * DEG, 3 * DEG)
    for trial in range(3):
        sim.reset(polar(merl.channel_centre_radius(4), rng.uniform(0, 360))[None], tilt=tilt)
        speed = rng.uniform(0.25, 0.35)
        heading = rng.uniform(0, 2 * np.pi)
        launch(sim, [[speed * math.cos(heading), speed * math.sin(heading)]], rolling=trial > 0)
        e0 = marble_energy(sim, sim.get_state())
        ke0 = 0.5 * merl.marble_mass * speed**2
        energies = []
        for _ in range(round(5 * PHYSICS_HZ)):
            sim.step(np.zeros(2))
            energies.append(marble_energy(sim, sim.get_state()))
        energies = np.array(energies)
        # Slack: 0.1% of the initial kinetic energy (≈ 4e-7 J).
        assert energies.max() - e0 < 1e-3 * ke0
        assert energies[-1] < e0 - 0.05 * ke0
        np.testing.assert_allclose(sim.tilt, tilt, atol=0.05 * DEG)


# --------------------------------------------------------------------------------------- determinism
def _random_actions(rng, n, horizon, spec):
    return rng.integers(-1, 2, size=(n, horizon, 2)) * spec.tilt_step


def test_state_roundtrip_is_bit_identical(merl):
    sim = MazeSim(merl)
    rng = np.random.default_rng(3)
    sim.reset(polar(merl.channel_centre_radius(4), 30.0)[None])
    for a in _random_actions(rng, 1, 20, merl)[0]:
        sim.step(a)
    start = sim.get_state()
    actions = _random_actions(rng, 1, 40, merl)[0]
    runs = []
    for _ in range(2):
        sim.set_state(start)
        traj = []
        for a in actions:
            sim.step(a)
            traj.append(sim.get_state())
        runs.append(np.array(traj))
    assert np.array_equal(runs[0], runs[1])
    # Something actually happened: the marble moved and the board tilted.
    assert not np.array_equal(runs[0][0], runs[0][-1])
    # A second simulator of the same spec agrees too.
    other = MazeSim(merl)
    other.set_state(start)
    for a, s in zip(actions, runs[0]):
        other.step(a)
        assert np.array_equal(other.get_state(), s)


@pytest.mark.parametrize("nthread", [1, 2])
def test_rollout_equals_stepping(merl, nthread):
    sim = MazeSim(merl)
    rng = np.random.default_rng(100 + nthread)
    batch, horizon = 4, 25
    starts = []
    for _ in range(batch):
        sim.reset(
            polar(merl.channel_centre_radius(4), rng.uniform(0, 360))[None], tilt=rng.integers(-3, 4, size=2) * DEG
        )
        for a in _random_actions(rng, 1, 5, merl)[0]:
            sim.step(a)
        starts.append(sim.get_state())
    starts = np.array(starts)
    actions = _random_actions(rng, batch, horizon, merl)
    out = sim.rollout(starts, actions, nthread=nthread)
    assert out.shape == (batch, horizon, sim.state_size)
    for b in range(batch):
        sim.set_state(starts[b])
        for t in range(horizon):
            sim.step(actions[b, t])
            assert np.array_equal(sim.get_state(), out[b, t]), (b, t)
    # One shared start, several sequences.
    out_shared = sim.rollout(starts[0], actions, nthread=nthread)
    for b in range(batch):
        sim.set_state(starts[0])
        for t in range(horizon):
            sim.step(actions[b, t])
        assert np.array_equal(sim.get_state(), out_shared[b, -1])
    # One sequence, several starts; and the two thread counts agree.
    out_seq = sim.rollout(starts, actions[0], nthread=nthread)
    np.testing.assert_array_equal(out_seq[0], out[0])
    sim.close()


def test_rollout_threads_agree(merl):
    sim = MazeSim(merl)
    rng = np.random.default_rng(5)
    sim.reset(polar(merl.channel_centre_radius(4), 100.0)[None])
    actions = _random_actions(rng, 6, 15, merl)
    a = sim.rollout(sim.get_state(), actions, nthread=1)
    b = sim.rollout(sim.get_state(), actions, nthread=2)
    c = sim.rollout(sim.get_state(), actions, nthread=2)
    assert np.array_equal(a, b) and np.array_equal(b, c)
    sim.close()


@pytest.mark.parametrize(
    "states_shape, deltas_shape, match",
    [
        ((3, 10), (3, 5, 2), "states must have last dimension"),
        (("S",), (5, 3), r"tilt_deltas must have shape \(B, H, 2\)"),
        (("S",), (5,), r"tilt_deltas must have shape \(B, H, 2\)"),
        (("S",), (2, 3, 5, 2), r"tilt_deltas must have shape \(B, H, 2\)"),
        ((2, "S"), (3, 5, 2), "batch sizes"),
    ],
)
def test_rollout_rejects_bad_shapes(merl, states_shape, deltas_shape, match):
    sim = MazeSim(merl)
    size = sim.state_size
    states = np.zeros(tuple(size if d == "S" else d for d in states_shape))
    with pytest.raises(ValueError, match=match):
        sim.rollout(states, np.zeros(deltas_shape))


def test_set_state_rejects_bad_input(merl):
    sim = MazeSim(merl)
    with pytest.raises(ValueError, match="state must be a finite float vector"):
        sim.set_state(np.zeros(sim.state_size + 1))
    bad = sim.get_state()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="finite"):
        sim.set_state(bad)


# --------------------------------------------------------------------------------------- tilt
def test_tilt_follows_steps_and_clamps(merl):
    sim = MazeSim(merl)
    sim.reset(np.zeros((1, 2)))
    for k in range(1, 13):
        sim.step(np.array([merl.tilt_step, 0.0]))
        expected = min(k, 5) * DEG
        assert abs(sim.tilt[0] - expected) < 0.05 * DEG, (k, math.degrees(sim.tilt[0]))
        assert abs(sim.tilt[1]) < 0.05 * DEG
        assert sim.target_tilt[0] == pytest.approx(expected, abs=1e-12)
        assert sim.target_tilt[0] <= merl.max_tilt  # never beyond the clamp
    # No wind-up: one step back from the clamp returns to 4°.
    sim.step(np.array([-merl.tilt_step, 0.0]))
    assert sim.target_tilt[0] == pytest.approx(4 * DEG, abs=1e-12)
    sim.step(np.array([0.0, 0.0]))
    assert abs(sim.tilt[0] - 4 * DEG) < 0.05 * DEG
    # Both axes, negative side.
    for _ in range(7):
        sim.step(np.array([0.0, -merl.tilt_step]))
    assert sim.target_tilt[1] == pytest.approx(-merl.max_tilt, abs=1e-12)
    assert sim.target_tilt[1] >= -merl.max_tilt
    sim.step(np.zeros(2))
    assert abs(sim.tilt[1] + merl.max_tilt) < 0.05 * DEG


def test_rates_for_clamps_exactly(merl):
    sim = MazeSim(merl)
    target, rate = sim.rates_for(np.array([4.5 * DEG, -4.5 * DEG]), np.array([DEG, -DEG]))
    assert target[0] == merl.max_tilt and target[1] == -merl.max_tilt
    np.testing.assert_allclose(rate, np.array([0.5, -0.5]) * DEG / sim.control_dt, rtol=1e-12)


def test_reset_clamps_tilt(merl):
    sim = MazeSim(merl)
    sim.reset(np.zeros((1, 2)), tilt=(10 * DEG, -10 * DEG))
    np.testing.assert_array_equal(sim.tilt, [merl.max_tilt, -merl.max_tilt])
    np.testing.assert_array_equal(sim.target_tilt, [merl.max_tilt, -merl.max_tilt])


# --------------------------------------------------------------------------------------- two marbles
def _two_marble_collision(speed: float) -> tuple[MazeSpec, np.ndarray]:
    spec = flat_spec()
    sim = MazeSim(spec, n_marbles=2, substeps=1)
    sim.reset(np.array([[-0.015, 0.0005], [0.015, -0.0005]]))
    launch(sim, np.array([[speed, 0.0], [-speed, 0.0]]), rolling=True)
    return spec, _run_fine(sim, np.zeros((30, 2)))  # 1 s


def _check_two_marbles(spec: MazeSpec, pos: np.ndarray, max_overlap: float) -> None:
    dist = np.linalg.norm(pos[:, 0] - pos[:, 1], axis=1)
    r = spec.marble_radius
    assert dist.min() > 2 * r - max_overlap
    assert dist.min() < 2 * r + 0.1 * MM  # they did meet
    assert np.all(pos[:, 0, 0] < pos[:, 1, 0])  # never pass through each other
    assert np.all(np.abs(pos[..., 2] - r) < 1 * MM)
    assert np.all(np.hypot(pos[..., 0], pos[..., 1]) < spec.rim_radius - r + 1 * MM)
    # Momentum is shared symmetrically: the pair's midpoint barely moves.
    mid = 0.5 * (pos[:, 0, :2] + pos[:, 1, :2])
    assert np.abs(mid).max() < 1 * MM


def test_two_marbles_collide_and_stay_on_board():
    """Rolled slowly towards each other (0.03 m/s each): they touch without overlapping by more
    than 0.5 mm, never pass through each other, stay on the floor and on the board."""
    spec, pos = _two_marble_collision(0.03)
    _check_two_marbles(spec, pos, 0.5 * MM)


def test_two_marbles_fast_collision_is_bounded_by_one_step():
    """At 0.25 m/s each (0.5 m/s closing speed) the overlap is at most one physics step of travel
    (3.3 mm): the contact stops them at once and they never pass through each other."""
    spec, pos = _two_marble_collision(0.25)
    _check_two_marbles(spec, pos, 0.5 / PHYSICS_HZ + 0.2 * MM)


@pytest.mark.xfail(
    strict=True,
    reason=(
        "sim/physics.py: contacts are detected only after overlap, at 150 Hz: two marbles closing at 0.5 m/s "
        "overlap by up to 0.5 m/s / 150 Hz = 3.3 mm (measured 2.49 mm); walls likewise (2.8 mm at "
        "0.5 m/s, 4.2 mm at 0.7 m/s; a marble at >= 1.5 m/s tunnels through a wall)"
    ),
)
def test_two_marbles_fast_collision_overlap_below_half_mm():
    spec, pos = _two_marble_collision(0.25)
    _check_two_marbles(spec, pos, 0.5 * MM)


# --------------------------------------------------------------------------------------- board frame
def test_board_frame_reproduces_reset_positions(merl):
    sim = MazeSim(merl, n_marbles=2)
    xy = np.array([[0.05, -0.02], [-0.03, 0.07]])
    tilt = (3 * DEG, -4 * DEG)
    sim.reset(xy, tilt=tilt)
    state = sim.get_state()
    p, v = sim.layout.board_frame(state)
    np.testing.assert_allclose(p[:, :2], xy, atol=1e-15)
    np.testing.assert_allclose(p[:, 2], merl.marble_radius, atol=1e-15)
    np.testing.assert_allclose(v, 0.0, atol=1e-15)
    world = state[sim.layout.marble_pos]
    np.testing.assert_allclose(np.linalg.norm(p, axis=-1), np.linalg.norm(world, axis=-1), rtol=1e-14)
    np.testing.assert_allclose(world, (board_to_world(tilt) @ p.T).T, atol=1e-15)
    # The tilted marble is really tilted: its world height differs from the board height.
    assert np.all(np.abs(world[:, 2] - merl.marble_radius) > 1 * MM)


def test_board_frame_norm_and_velocity_while_tilting(merl):
    """While the board tilts, board-frame positions keep the world distance from the pivot, and the
    board-frame velocity is the time derivative of the board-frame position."""
    sim = MazeSim(merl, substeps=1)
    rng = np.random.default_rng(9)
    sim.reset(polar(merl.channel_centre_radius(3), 20.0)[None])
    launch(sim, [[0.1, 0.05]])
    actions = rng.integers(-1, 2, size=(40, 2)) * merl.tilt_step
    states = []
    for a in actions:
        for _ in range(5):
            sim.step(a / 5)
            states.append(sim.get_state())
    states = np.array(states)
    p, v = sim.layout.board_frame(states)  # vectorised over leading dims
    assert p.shape == (len(states), 1, 3) and v.shape == p.shape
    world = states[:, sim.layout.marble_pos[0]]
    np.testing.assert_allclose(np.linalg.norm(p[:, 0], axis=-1), np.linalg.norm(world, axis=-1), rtol=1e-13)
    # The integrator is semi-implicit (q_{n+1} = q_n + dt·v_{n+1}), so the backward difference of
    # the board-frame position matches the velocity at the later step up to O(dt·|ω|·|v|, dt·|ω|²|p|)
    # (< 1 mm/s here; dropping the ω×p term would be wrong by tens of mm/s).
    dt = sim.model.opt.timestep
    backward = (p[1:, 0] - p[:-1, 0]) / dt
    err = np.linalg.norm(backward - v[1:, 0], axis=-1)
    tilt_rates = np.abs(states[:, sim.layout.tilt_rate]).max()
    assert tilt_rates > 20 * DEG  # the board did move fast
    assert err.max() < 2 * MM
    # Independent formula: v_board = R(tilt)ᵀ (v − ω × p), ω = ȧ·x + ḃ·Rx(a)·y.
    for s_ in states[::7]:
        a, b = s_[sim.layout.tilt]
        da, db = s_[sim.layout.tilt_rate]
        rot = board_to_world((a, b))
        omega = np.array([da, 0.0, 0.0]) + db * board_to_world((a, 0.0))[:, 1]
        pw, vw = s_[sim.layout.marble_pos[0]], s_[sim.layout.marble_vel[0]]
        pb, vb = sim.layout.board_frame(s_)
        np.testing.assert_allclose(pb[0], rot.T @ pw, atol=1e-15)
        np.testing.assert_allclose(vb[0], rot.T @ (vw - np.cross(omega, pw)), atol=1e-14)
    # Matching one element against the single-state call.
    p1, v1 = sim.layout.board_frame(states[17])
    np.testing.assert_array_equal(p1, p[17])
    np.testing.assert_array_equal(v1, v[17])


# --------------------------------------------------------------------------------------- bad input
def test_reset_says_whether_positions_or_tilt_are_malformed_or_not_finite(merl):
    """These used to be reshaped silently ((2,) for one marble), fail inside numpy ("cannot
    reshape"), or blame the physics state ("state must be a finite float vector")."""
    sim = MazeSim(merl)
    with pytest.raises(ValueError, match=r"marble_xy must have shape \(1, 2\) .*got shape \(2,\)"):
        sim.reset(np.zeros(2))
    with pytest.raises(ValueError, match=r"marble_xy must have shape \(1, 2\) .*got shape \(2, 2\)"):
        sim.reset(np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"marble_xy is not finite at \(0, 0\)"):
        sim.reset([[np.nan, 0.0]])
    with pytest.raises(ValueError, match=r"tilt is not finite at \(0,\)"):
        sim.reset([[0.0, 0.0]], tilt=(np.nan, 0.0))
    with pytest.raises(ValueError, match=r"tilt must have shape \(2,\)"):
        sim.reset([[0.0, 0.0]], tilt=(0.01,))


def test_nan_tilt_changes_are_refused_instead_of_resetting_the_state(merl):
    """MuJoCo answers a NaN control with a warning and a reset of the whole state (the marble
    jumps to the origin); step() and rollout() refuse it instead."""
    sim = MazeSim(merl)
    sim.reset([[merl.channel_centre_radius(4), 0.0]])
    before = sim.get_state()
    with pytest.raises(ValueError, match="tilt_delta must be finite"):
        sim.step((np.nan, 0.0))
    np.testing.assert_array_equal(sim.get_state(), before)
    with pytest.raises(ValueError, match="states and tilt_deltas must be finite"):
        sim.rollout(before, np.array([[0.0, np.nan]]))
    bad = before.copy()
    bad[sim.layout.marble_vel[0][0]] = np.inf
    with pytest.raises(ValueError, match="states and tilt_deltas must be finite"):
        sim.rollout(bad, np.zeros((1, 2)))
    sim.step((np.inf, 0.0))  # an infinite change is only clamped at max_tilt
    np.testing.assert_allclose(sim.target_tilt, [merl.max_tilt, 0.0])


# ---------------------------------------------------------------- switching mazes without a rebuild
def _slotted_trajectory(sim, spec, seed=0, steps=300, model=None):
    from bimgame.envs.env import DISCRETE_TILTS
    from bimgame.sim.placement import sample_start

    sim.reset(sample_start(spec, 1, np.random.default_rng(seed)))
    actions = np.random.default_rng(seed + 1).integers(0, 5, steps)
    models = None if model is None else [model]
    return sim.rollout(sim.get_state(), DISCRETE_TILTS[actions] * spec.tilt_step, models=models)[0]


def test_set_walls_steps_exactly_as_a_model_built_for_the_maze():
    import copy

    from bimgame.sim.maze_sets import maze_number
    from bimgame.sim.mjcf import wall_slots

    slots = wall_slots(MazeSpec.merl(), 4)
    switched = MazeSim(MazeSpec.merl(), wall_slots=slots)
    copy_model = copy.copy(switched.model)
    for number in (0, 1, 2):
        maze = maze_number(number)
        built = MazeSim(maze, wall_slots=slots)
        switched.set_walls(maze)
        expected = _slotted_trajectory(built, maze, seed=number)
        np.testing.assert_array_equal(_slotted_trajectory(switched, maze, seed=number), expected)
        switched.set_walls(maze, copy_model)  # a model copy, as a vector env's envs have
        np.testing.assert_array_equal(_slotted_trajectory(switched, maze, seed=number, model=copy_model), expected)
    # And the marble meets the new walls: MERL's model would give another trajectory.
    merl = _slotted_trajectory(MazeSim(MazeSpec.merl()), maze, seed=2)
    assert not np.array_equal(merl, expected)


def test_set_walls_refuses_another_board_a_sim_without_slots_and_too_many_gates():
    from bimgame.sim.generate import GateRules, random_maze
    from bimgame.sim.mjcf import wall_boxes, wall_slots

    base = MazeSpec.merl()
    with pytest.raises(ValueError, match="built with wall_slots"):
        MazeSim(base).set_walls(base)
    sim = MazeSim(base, wall_slots=wall_slots(base, 4))
    with pytest.raises(ValueError, match="marble_mass"):
        sim.set_walls(base.replace(marble_mass=0.01))
    with pytest.raises(ValueError, match="radii"):
        sim.set_walls(base.replace(walls=base.walls[1:]))
    exact = MazeSim(base, wall_slots=tuple(len(boxes) for boxes in wall_boxes(base)))  # no spare slot
    many = random_maze(np.random.default_rng(0), rules=GateRules(min_gates=8, max_gates=8))
    with pytest.raises(ValueError, match=r"walls\[\d\] of the new maze needs \d+ pieces, more than the \d+ slots"):
        exact.set_walls(many)


def test_wall_slots_hold_every_random_maze():
    from bimgame.sim.generate import random_maze
    from bimgame.sim.mjcf import wall_boxes, wall_slots

    slots = wall_slots(MazeSpec.merl(), 4)
    most = [0] * len(slots)
    for seed in range(300):
        for k, boxes in enumerate(wall_boxes(random_maze(np.random.default_rng(seed)))):
            most[k] = max(most[k], len(boxes))
    assert all(m <= s for m, s in zip(most, slots))
    assert sum(slots) - sum(most) < 40  # and not wastefully many (parked pieces still cost a pair test)
