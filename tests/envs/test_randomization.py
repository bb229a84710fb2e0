"""Domain randomisation: reproducible per-episode draws, the same in single and vector envs, physics
and actuation that really change, camera transforms that keep the marble in view, and every bad
range refused by name."""

from __future__ import annotations

import math
import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import bimgame  # noqa: F401  (registers the ids)
from bimgame.envs import Randomization
from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.randomization import EpisodeRandomizer, max_camera_shift, max_marble_radius_scale
from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.sim.maze import Friction, Gate, MazeSpec, Wall
from bimgame.sim.physics import MazeSim
from bimgame.sim.render import MazeRenderer

MERL = MazeSpec.merl()
PHYSICS = dict(sliding_friction=(0.7, 1.3), torsional_friction=(0.5, 2.0), rolling_friction=(5.0, 20.0),
               marble_mass=(0.8, 1.2), marble_radius=(0.95, 1.03), max_tilt=(0.8, 1.2), tilt_step=(0.8, 1.2),
               tilt_error=(0.0, 0.2), latency=(0, 2))
CAMERA = dict(brightness=(-20.0, 20.0), contrast=(0.8, 1.2), pixel_noise=(0.0, 5.0), blur=(0.0, 1.0),
              camera_shift=(-2.0, 2.0), camera_rotation=(-10.0, 10.0))
EVERYTHING = Randomization(**PHYSICS, **CAMERA)


def run(env, seed: int, actions, options=None):
    """Observations, rewards and infos of an episode from ``reset(seed)`` with ``actions``."""
    obs, info = env.reset(seed=seed, options=options)
    out = [(obs, 0.0, info)]
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        out.append((obs, reward, info))
        if terminated or truncated:
            break
    return out


ACTIONS = np.random.default_rng(0).integers(5, size=60).tolist()


# ------------------------------------------------------------------ reproducibility
@pytest.mark.parametrize("obs_mode", ["pixels", "state"])
def test_randomize_none_is_the_env_without_the_option(obs_mode):
    plain = run(BallInMazeEnv("STG1", obs_mode=obs_mode), 4, ACTIONS)
    none = run(BallInMazeEnv("STG1", obs_mode=obs_mode, randomize=None), 4, ACTIONS)
    assert len(plain) == len(none)
    for (a, ra, ia), (b, rb, ib) in zip(plain, none):
        assert np.array_equal(a, b) and ra == rb and "randomization" not in ib
    vector = BallInMazeVectorEnv(2, task="STG1", obs_mode=obs_mode, randomize=None)
    assert vector.randomizer is None and "randomization" not in vector.reset(seed=0)[1]


def test_same_seed_same_draws_and_episode_other_seed_other_draws():
    a = run(BallInMazeEnv("FULL", randomize=EVERYTHING), 7, ACTIONS)
    b = run(BallInMazeEnv("FULL", randomize=EVERYTHING), 7, ACTIONS)
    c = run(BallInMazeEnv("FULL", randomize=EVERYTHING), 8, ACTIONS)
    assert len(a) == len(b) == len(ACTIONS) + 1
    for (oa, ra, ia), (ob, rb, ib) in zip(a, b):
        assert np.array_equal(oa, ob) and ra == rb and ia["randomization"] == ib["randomization"]
        np.testing.assert_array_equal(ia["tilt"], ib["tilt"])
    drawn_a, drawn_c = a[0][2]["randomization"], c[0][2]["randomization"]
    assert drawn_a.keys() == drawn_c.keys()
    assert all(drawn_a[k] != drawn_c[k] for k in drawn_a if k != "latency")
    # The randomisation is drawn after the start: a seed's start does not depend on it.
    plain = BallInMazeEnv("FULL", obs_mode="state")
    randomized = BallInMazeEnv("FULL", obs_mode="state", randomize=Randomization(**PHYSICS))
    np.testing.assert_array_equal(plain.reset(seed=3)[0][:2], randomized.reset(seed=3)[0][:2])


def test_draws_lie_in_their_ranges_and_are_reported_each_episode():
    env = BallInMazeEnv("STG1", randomize=EVERYTHING)
    ranges = {**PHYSICS, **CAMERA, "camera_shift_x": CAMERA["camera_shift"], "camera_shift_y": CAMERA["camera_shift"]}
    seen = []
    for seed in range(40):
        _, info = env.reset(seed=seed)
        drawn = info["randomization"]
        assert set(drawn) == set(ranges) - {"camera_shift"}
        # The marble starts at rest on the floor: at the height of its drawn radius.
        height = env.sim.get_state()[env.sim.layout.marble_pos[0, 2]]
        assert height == pytest.approx(MERL.marble_radius * drawn["marble_radius"], rel=1e-12)
        for key, value in drawn.items():
            low, high = ranges[key]
            assert low <= value <= high, key
            assert type(value) is (int if key == "latency" else float)
        assert env.step(0)[4]["randomization"] == drawn  # the same all episode
        seen.append(drawn)
    assert {d["latency"] for d in seen} == {0, 1, 2}
    assert len({d["marble_mass"] for d in seen}) == 40
    # The physics of the draws is on the model.
    sim, drawn = env.sim, seen[-1]
    assert sim.model.body_mass[sim.model.body("marble0").id] == pytest.approx(MERL.marble_mass * drawn["marble_mass"])
    assert sim.max_tilt == pytest.approx(MERL.max_tilt * drawn["max_tilt"])
    assert sim.model.geom_size[sim.model.geom("marble0").id, 0] == pytest.approx(MERL.marble_radius * drawn["marble_radius"])


@pytest.mark.parametrize("autoreset_mode", ["next_step", "same_step"])
def test_vector_env_equals_sync_vector_env_with_randomization(autoreset_mode):
    """The batched env draws for each sub-env exactly what a single env seeded the same way draws
    (Gymnasium's sync vector env: seeds seed, seed+1, …) and steps and observes identically,
    across autoresets (new draws) and same-step final observations."""
    kwargs = dict(obs_mode="pixels", max_episode_steps=25, randomize=EVERYTHING)
    mode = gym.vector.AutoresetMode.SAME_STEP if autoreset_mode == "same_step" else gym.vector.AutoresetMode.NEXT_STEP
    sync = gym.make_vec("BiMGame/STG1-v0", num_envs=3, vectorization_mode="sync",
                        vector_kwargs={"autoreset_mode": mode}, **kwargs)
    fast = gym.make_vec("BiMGame/STG1-v0", num_envs=3, autoreset_mode=autoreset_mode, **kwargs)
    assert isinstance(fast, BallInMazeVectorEnv)
    obs_a, info_a = sync.reset(seed=11)
    obs_b, info_b = fast.reset(seed=11)
    np.testing.assert_array_equal(obs_a, obs_b)
    assert info_a["randomization"].keys() == info_b["randomization"].keys()
    for i in range(3):  # each sub-env's draws are a single env's with seed 11 + i
        single = BallInMazeEnv("STG1", **{k: v for k, v in kwargs.items() if k != "max_episode_steps"})
        drawn = single.reset(seed=11 + i)[1]["randomization"]
        assert {k: v[i].item() for k, v in info_b["randomization"].items() if not k.startswith("_")} == drawn
    episodes = 0
    for action in np.random.default_rng(1).integers(5, size=(60, 3)):
        a, b = sync.step(action), fast.step(action)
        for x, y in zip(a[:4], b[:4]):
            np.testing.assert_array_equal(x, y)
        for key, value in a[4]["randomization"].items():
            np.testing.assert_array_equal(value, b[4]["randomization"][key])
        if "final_obs" in a[4]:
            for i in np.flatnonzero(a[4]["_final_obs"]):
                np.testing.assert_array_equal(a[4]["final_obs"][i], b[4]["final_obs"][i])
                assert a[4]["final_info"]["randomization"]["marble_mass"][i] == \
                    b[4]["final_info"]["randomization"]["marble_mass"][i]
        episodes += int((a[2] | a[3]).sum())
    assert episodes >= 6  # every env was reset, with new draws, at least twice
    sync.close()
    fast.close()


def test_pickled_env_continues_the_same_randomized_episode():
    env = BallInMazeEnv("FULL", randomize=EVERYTHING)
    env.reset(seed=2)
    for action in (1, 1, 3, 0, 2):
        env.step(action)
    copy = pickle.loads(pickle.dumps(env))
    for action in (3, 3, 0, 1, 0, 0):
        a, b = env.step(action), copy.step(action)
        np.testing.assert_array_equal(a[0], b[0])
        assert a[4]["randomization"] == b[4]["randomization"]


def test_check_env_passes_with_randomization():
    check_env(BallInMazeEnv("STG1", randomize=EVERYTHING), skip_render_check=True)
    state = BallInMazeEnv("STG1", obs_mode="state", randomize=Randomization(**{**PHYSICS, "max_tilt": (1.5, 1.5)}))
    check_env(state, skip_render_check=True)
    state.reset(seed=0)
    for _ in range(12):
        obs = state.step(1)[0]  # the board tilts to 7.5°: still inside the observation space
    assert state.observation_space.contains(obs) and obs[4] > math.radians(6)


# ------------------------------------------------------------------ physics and actuation
def fixed(**ranges) -> Randomization:
    """A randomisation that always draws the given values."""
    return Randomization(**{k: (v, v) for k, v in ranges.items()})


def board_velocity(randomize: Randomization | None, maze: MazeSpec, steps: int = 18) -> float:
    """Board-frame x velocity of a marble released on an open board tilted +y by 3 steps."""
    env = BallInMazeEnv("FULL", obs_mode="state", maze=maze, randomize=randomize)
    env.reset(seed=0, options={"marble_xy": [[-0.2, 0.0]]})
    for action in [3, 3, 3] + [0] * steps:
        obs = env.step(action)[0]
    return float(obs[2])


OPEN = MazeSpec(walls=(Wall(0.016, 0.021, (Gate.deg(180, 60),)),), rim_radius=0.3)


def test_heavier_rolling_friction_slows_the_rolling_marble():
    nominal = board_velocity(None, OPEN)
    unit = board_velocity(fixed(rolling_friction=1.0), OPEN)
    slowed = board_velocity(fixed(rolling_friction=100.0), OPEN)  # 1e-4 m: above MuJoCo's floor
    assert nominal > 0.1 and unit == nominal
    # Rolling resistance decelerates by (5/7)·g·roll/r ≈ 0.11 m/s² against (5/7)·g·sin 3° ≈ 0.37 m/s².
    assert 0.6 < slowed / nominal < 0.8


def test_sliding_friction_matters_for_the_low_friction_marble():
    low = OPEN.replace(friction=Friction.low())
    sliding = board_velocity(None, low)
    rolling = board_velocity(fixed(sliding_friction=300.0), low)  # 0.3: grips, so it rolls
    assert rolling / sliding == pytest.approx(5 / 7, rel=0.03)


def target_tilts(randomize: Randomization | None, actions) -> np.ndarray:
    env = BallInMazeEnv("FULL", obs_mode="state", randomize=randomize)
    env.reset(seed=5)
    out = []
    for action in actions:
        env.step(action)
        out.append(env.sim.target_tilt)
    return np.array(out)


def test_latency_delays_the_tilt_by_exactly_that_many_steps():
    actions = [1, 3, 3, 0, 2, 4, 0, 0, 1, 0]
    nominal = target_tilts(None, actions)
    for latency in (1, 2):
        delayed = target_tilts(fixed(latency=latency), actions)
        np.testing.assert_array_equal(delayed[:latency], 0.0)
        np.testing.assert_array_equal(delayed[latency:], nominal[:-latency])


def test_tilt_step_scale_and_servo_limit():
    one = target_tilts(None, [1])[0]
    scaled = target_tilts(fixed(tilt_step=1.5), [1])[0]
    assert one[0] == pytest.approx(math.radians(1)) and scaled[0] == pytest.approx(1.5 * one[0])
    tilts = []
    for randomize in (None, fixed(tilt_step=1.5)):
        env = BallInMazeEnv("FULL", obs_mode="state", randomize=randomize)
        env.reset(seed=5)
        tilts.append(env.step(1)[4]["tilt"][0])  # the board's own tilt, after one action
    assert tilts[1] / tilts[0] == pytest.approx(1.5, rel=0.01)
    limited = target_tilts(fixed(max_tilt=0.6), [1] * 6)
    assert limited[-1, 0] == pytest.approx(math.radians(3.0))


def test_tilt_error_perturbs_moves_but_not_no_ops():
    actions = [1, 0, 0, 3, 0, 2]
    nominal = target_tilts(None, actions)
    noisy = target_tilts(fixed(tilt_error=0.2), actions)
    assert not np.allclose(noisy, nominal)
    error = noisy[0, 0] - math.radians(1)
    assert 0 < abs(error) < math.radians(1)  # std 0.2 steps: |error| < 5 std
    np.testing.assert_array_equal(noisy[1], noisy[0])  # a no-op adds nothing
    np.testing.assert_array_equal(noisy[0, 1], 0.0)    # nor does the axis not moved


def test_vector_env_gives_each_env_its_own_physics():
    env = BallInMazeVectorEnv(4, task="FULL", obs_mode="state", randomize=Randomization(marble_mass=(0.5, 2.0)))
    _, info = env.reset(seed=0)
    masses = [model.body_mass[model.body("marble0").id] for model in env._models]
    np.testing.assert_allclose(masses, MERL.marble_mass * info["randomization"]["marble_mass"])
    assert len(set(masses)) == 4 and env.sim.model.body_mass[env.sim.model.body("marble0").id] == MERL.marble_mass


def test_vector_env_clamps_each_env_at_its_own_servo_limit():
    env = BallInMazeVectorEnv(3, task="FULL", obs_mode="state", randomize=Randomization(max_tilt=(0.5, 0.9)))
    _, info = env.reset(seed=1)
    for _ in range(6):
        _, _, _, _, info = env.step(np.ones(3, dtype=np.int64))  # +x, six times: past every limit
    limits = MERL.max_tilt * info["randomization"]["max_tilt"]
    np.testing.assert_allclose(env._states[:, env.sim.layout.target_tilt[0]], limits, rtol=1e-12)
    np.testing.assert_allclose(info["tilt"][:, 0], limits, rtol=0.02)


def test_set_parameters_equals_rebuilding_the_model():
    friction = Friction(slide=0.6, spin=2e-5, roll=5e-5)
    changes = dict(friction=friction, marble_mass=0.011, marble_radius=0.0065, max_tilt=math.radians(4))
    rebuilt = MazeSim(MERL.replace(**changes))
    fast = MazeSim(MERL)
    fast.set_parameters(**changes)
    for name in ("pair_friction", "pair_dim", "geom_size", "geom_rbound", "body_mass", "body_inertia",
                 "body_invweight0", "dof_invweight0", "actuator_actrange", "qpos0"):
        np.testing.assert_allclose(getattr(fast.model, name), getattr(rebuilt.model, name), rtol=1e-9, err_msg=name)
    assert fast.model.stat.meaninertia == pytest.approx(rebuilt.model.stat.meaninertia, rel=1e-12)
    xy = np.array([[0.0888, 0.0]])
    fast.reset(xy)
    rebuilt.reset(xy)
    rng = np.random.default_rng(0)
    for _ in range(30):
        delta = rng.choice([-1, 0, 1], size=2) * math.radians(1)
        fast.step(delta)
        rebuilt.step(delta)
    np.testing.assert_allclose(fast.get_state(), rebuilt.get_state(), rtol=0, atol=1e-9)


@pytest.mark.parametrize("scale, passes", [(None, True), (1.10, False)])
def test_largest_allowed_marble_passes_the_narrowest_gate(scale, passes):
    """MERL's narrowest opening is wall 1's 21.4° gates; the largest allowed marble rolls through
    the one at 45° from channel 2 into channel 1, a marble 10% larger than nominal does not."""
    limit, where = max_marble_radius_scale(MERL)
    assert where.startswith("walls[1].gates[0]") and 1.03 < limit < 1.04
    sim = MazeSim(MERL)
    sim.set_parameters(marble_radius=MERL.marble_radius * (scale or limit))
    angle = math.radians(45)
    r = MERL.channel_centre_radius(2)
    sim.reset([[r * math.cos(angle), r * math.sin(angle)]])
    state = sim.get_state()
    state[sim.layout.marble_vel[0, :2]] = -0.3 * math.cos(angle), -0.3 * math.sin(angle)
    sim.set_state(state)
    closest = r
    for _ in range(20):
        sim.step((0.0, 0.0))
        x, y = sim.marble_kinematics()[0][0, :2]
        closest = min(closest, math.hypot(x, y))
    # Through: the whole marble inside the wall's inner face, the gate's narrowest point.
    assert (closest < MERL.walls[1].inner_radius - sim.marble_radius) == passes


# ------------------------------------------------------------------ camera
def frames_of(randomize: Randomization, xy, seed: int = 0):
    """A nominal and a randomised first frame with the marble at ``xy``."""
    options = {"marble_xy": [xy]}
    nominal = BallInMazeEnv("STG1").reset(seed=seed, options=options)[0][0].astype(np.int64)
    env = BallInMazeEnv("STG1", randomize=randomize)
    return nominal, env.reset(seed=seed, options=options)[0][0], env


def test_brightness_and_contrast_change_the_mean_as_expected():
    nominal, brighter, _ = frames_of(fixed(brightness=-20.0), [0.0888, 0.0])
    assert brighter.dtype == np.uint8
    np.testing.assert_array_equal(brighter, nominal - 20)  # no pixel is clipped: 30 - 20 >= 0
    _, flatter, _ = frames_of(fixed(contrast=0.5), [0.0888, 0.0])
    assert flatter.mean() == pytest.approx((nominal.mean() - 127.5) * 0.5 + 127.5, abs=0.5)
    assert flatter.std() == pytest.approx(nominal.std() * 0.5, rel=0.02)


def test_pixel_noise_changes_pixels_keeps_uint8_and_differs_per_frame():
    nominal, noisy, env = frames_of(fixed(pixel_noise=5.0), [0.0888, 0.0])
    assert noisy.dtype == np.uint8 and noisy.shape == (84, 84)
    difference = noisy.astype(np.int64) - nominal
    assert abs(difference.mean()) < 0.5 and 4.0 < difference.std() < 6.0
    after_noop = env.step(0)[0][0]  # the marble stays put, the noise does not
    assert (after_noop != noisy).mean() > 0.5


def test_blur_spreads_the_marble_and_keeps_the_mean():
    nominal, blurred, _ = frames_of(fixed(blur=1.5), [0.0, 0.0])
    assert blurred.max() < nominal.max() == 255
    assert blurred.mean() == pytest.approx(nominal.mean(), abs=0.5)


def marble_pixels(frame: np.ndarray, empty: np.ndarray) -> int:
    return int((np.abs(frame.astype(np.int64) - empty) > 20).sum())


@pytest.mark.parametrize("direction", [(1, 1), (-1, -1), (1, -1), (-1, 1)])
def test_marble_stays_in_view_at_the_largest_camera_offset_and_rotation(direction):
    """The marble as far out as it can be, towards the image's corner the camera moves it to: its
    disc still differs from the camera's view of the empty maze in as many pixels as unmoved."""
    shift = max_camera_shift(MERL, 84)
    assert 2.0 < shift < 2.1
    raster = MazeRenderer(MERL, 84)
    reach = MERL.rim_radius - MERL.marble_radius - 1e-6
    # Moved right (down), the image shows the marble at the right (bottom) farther right (down).
    xy = np.array([[[direction[0] * reach, 0.0]], [[0.0, -direction[1] * reach]]])
    randomizer = EpisodeRandomizer(Randomization(camera_shift=(-shift, shift), camera_rotation=(-15.0, 15.0)),
                                   MERL, 2, raster)
    for row in range(2):
        randomizer.set_row(row, {"camera_shift_x": direction[0] * shift, "camera_shift_y": direction[1] * shift,
                                 "camera_rotation": 15.0 * direction[0]})
    frames = randomizer.pixels(raster.gray(xy)[:, None], np.zeros(2, dtype=np.int64), xy)
    empty = randomizer.pixels(raster.gray(np.full((2, 1, 2), np.nan))[:, None], np.zeros(2, dtype=np.int64),
                              np.full((2, 1, 2), np.nan))
    for row in range(2):
        unmoved = marble_pixels(raster.gray(xy[row]), raster.background.astype(np.int64))
        assert unmoved > 15
        assert marble_pixels(frames[row, 0], empty[row, 0].astype(np.int64)) >= 0.85 * unmoved
    with pytest.raises(ValueError, match="camera_shift"):
        BallInMazeEnv("STG1", randomize=Randomization(camera_shift=(0.0, shift + 0.1)))


def test_camera_transform_equals_whole_frame_reference():
    """The per-marble windows give exactly what transforming whole frames gives."""
    raster = MazeRenderer(MERL, 84)
    randomizer = EpisodeRandomizer(Randomization(**{k: v for k, v in CAMERA.items() if k != "pixel_noise"}),
                                   MERL, 8, raster)
    rng = np.random.default_rng(1)
    for row in range(8):
        randomizer.reset_row(row, rng)
    angle, radius = rng.uniform(0, 2 * np.pi, 8), rng.uniform(0, 0.088, 8)
    xy = np.stack([radius * np.cos(angle), radius * np.sin(angle)], -1)[:, None]
    frames = raster.gray(xy)[:, None]
    expected = [reference_camera(frames[row, 0], randomizer.row(row)) for row in range(8)]
    out = randomizer.pixels(frames.copy(), np.zeros(8, dtype=np.int64), xy)
    np.testing.assert_array_equal(out[:, 0], np.array(expected))


def reference_camera(frame: np.ndarray, drawn: dict) -> np.ndarray:
    """Bilinear camera offset and rotation, blur, contrast and brightness of one whole frame."""
    size, centre = frame.shape[0], (frame.shape[0] - 1) / 2
    rows, cols = np.mgrid[0:size, 0:size].astype(np.float64)
    u = cols - centre - drawn["camera_shift_x"]
    v = -(rows - centre - drawn["camera_shift_y"])
    c, s = math.cos(math.radians(drawn["camera_rotation"])), math.sin(math.radians(drawn["camera_rotation"]))
    src_c, src_r = np.clip(centre + c * u + s * v, 0, size - 1), np.clip(centre + s * u - c * v, 0, size - 1)
    i0, j0 = np.floor(src_r).astype(int), np.floor(src_c).astype(int)
    fr, fc = src_r - i0, src_c - j0
    i1, j1 = np.minimum(i0 + 1, size - 1), np.minimum(j0 + 1, size - 1)
    f = frame.astype(np.float64)
    out = f[i0, j0] * (1 - fr) * (1 - fc) + f[i0, j1] * (1 - fr) * fc + f[i1, j0] * fr * (1 - fc) + f[i1, j1] * fr * fc
    radius = math.ceil(3 * CAMERA["blur"][1])
    taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / max(drawn["blur"], 1e-12)) ** 2)
    taps /= taps.sum()
    padded = np.pad(out, radius, mode="edge")
    out = sum(taps[i] * padded[i:i + size, radius:radius + size] for i in range(2 * radius + 1))
    padded = np.pad(out, radius, mode="edge")
    out = sum(taps[i] * padded[radius:radius + size, i:i + size] for i in range(2 * radius + 1))
    out = (out - 127.5) * drawn["contrast"] + 127.5 + drawn["brightness"]
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


# ------------------------------------------------------------------ bad ranges
@pytest.mark.parametrize("field, value", [
    ("sliding_friction", (1.3, 0.7)),          # low > high
    ("sliding_friction", (0.0, 1.0)),          # a scale must be > 0
    ("rolling_friction", (float("nan"), 1.0)),
    ("torsional_friction", 1.2),               # not a pair
    ("marble_mass", (0.5, 1.0, 2.0)),
    ("marble_mass", ("1", 2)),
    ("tilt_step", (1.0, float("inf"))),
    ("tilt_error", (-0.1, 0.1)),               # a negative std
    ("latency", (0, 3)),
    ("latency", (-1, 1)),
    ("latency", (0.0, 1.5)),                   # not integers
    ("latency", (True, 1)),
    ("brightness", (-300.0, 0.0)),
    ("contrast", (0.0, 1.0)),
    ("pixel_noise", (-1.0, 2.0)),
    ("blur", (0.0, 4.0)),
    ("camera_rotation", (-20.0, 0.0)),
])
def test_bad_ranges_raise_naming_the_field(field, value):
    with pytest.raises(ValueError, match=rf"Randomization\.{field} must be .* got"):
        Randomization(**{field: value})


@pytest.mark.parametrize("randomize, obs_mode, match", [
    (Randomization(marble_radius=(1.0, 1.05)), "state", r"marble_radius.*at most 1\.03.*walls\[1\]\.gates\[0\]"),
    (Randomization(max_tilt=(1.0, 7.0)), "state", r"max_tilt.*30°"),
    (Randomization(camera_shift=(-3.0, 0.0)), "pixels", r"camera_shift.*\[-2\.06"),
    (Randomization(pixel_noise=(0.0, 1.0), blur=(0.0, 1.0)), "state", r"\['pixel_noise', 'blur'\].*obs_mode='pixels'"),
    ({"marble_mass": (0.9, 1.1), "gravity": (0.9, 1.1)}, "state", r"unknown randomize fields \['gravity'\]"),
    ("everything", "state", r"randomize must be None, a Randomization or a dict"),
])
def test_ranges_the_env_cannot_take_are_refused_at_construction(randomize, obs_mode, match):
    with pytest.raises(ValueError, match=match):
        BallInMazeEnv("STG1", obs_mode=obs_mode, randomize=randomize)
    with pytest.raises(ValueError, match=match):
        gym.make_vec("BiMGame/STG1-v0", num_envs=2, obs_mode=obs_mode, randomize=randomize)


def test_a_dict_is_taken_as_a_randomization():
    env = gym.make("BiMGame/STG1-v0", obs_mode="state", randomize={"marble_mass": [0.9, 1.1]})
    assert env.unwrapped.randomize == Randomization(marble_mass=(0.9, 1.1))
    assert set(env.reset(seed=0)[1]["randomization"]) == {"marble_mass"}
