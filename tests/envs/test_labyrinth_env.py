"""Tests of CyberRunner's labyrinth as Gymnasium environments (bimgame.envs.labyrinth_env): the API
for every id and mode, holes end episodes, walls stop the marble, the reward pays path progress and
nothing for skipped path, the goal, determinism, observations where the marble is, and bad input.
Few steps each: the whole file runs in seconds."""

from __future__ import annotations

import math
import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import bimgame
from bimgame.envs.labyrinth_env import (
    GOAL_BONUS,
    PROGRESS_SCALE,
    LabyrinthEnv,
    labyrinth_max_episode_steps,
    path_points_ahead,
)
from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.sim.labyrinth_render import GRAY

NOOP, TILT_PX, TILT_MX, TILT_PY, TILT_MY = range(5)  # TILT_PY rolls the marble +x, TILT_MX rolls it +y
R = 0.006  # marble radius


def line_board(**changes) -> LabyrinthSpec:
    """An open board with a straight path along x through the centre (no walls, no holes)."""
    fields = dict(walls=(), holes=(), waypoints=((-0.1, 0.0), (0.0, 0.0), (0.1, 0.0)), name="line")
    return LabyrinthSpec(**{**fields, **changes})


def env_on(board: LabyrinthSpec, **kwargs) -> LabyrinthEnv:
    return LabyrinthEnv(board=board, action_type="discrete", **kwargs)


# ------------------------------------------------------------------------------------ API
@pytest.mark.parametrize("env_id", bimgame.LABYRINTH_ENV_IDS)
def test_ids_are_registered_apart_from_the_circular_maze(env_id):
    assert env_id not in bimgame.ENV_IDS
    bimgame.register_envs()  # idempotent
    assert gym.spec(env_id).max_episode_steps == 3000
    assert labyrinth_max_episode_steps(55) == 3000 and labyrinth_max_episode_steps(30) == 1636


@pytest.mark.parametrize("env_id", bimgame.LABYRINTH_ENV_IDS)
@pytest.mark.parametrize("obs_mode", ["state", "pixels", "cyberrunner"])
@pytest.mark.parametrize("action_type", ["continuous", "discrete"])
def test_check_env(env_id, obs_mode, action_type):
    env = gym.make(env_id, obs_mode=obs_mode, action_type=action_type, render_mode="rgb_array", render_size=64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # infinite bounds of velocities and CyberRunner's Dict: intended
        check_env(env.unwrapped)
    frame = env.unwrapped.render()
    assert frame.shape == (64, 64, 3) and frame.dtype == np.uint8
    env.close()


@pytest.mark.parametrize("control_hz", [30, 55])
def test_control_rates_and_tilt_rate_cap(control_hz):
    env = LabyrinthEnv("easy", control_hz=control_hz, max_tilt_rate_deg=30.0)
    env.reset(seed=0)
    assert env.sim.control_dt == pytest.approx(1 / control_hz)
    for _ in range(5):
        env.step(np.array([1.0, -1.0], dtype=np.float32))
    assert env.sim.target_tilt == pytest.approx(np.radians([30.0, -30.0]) * 5 / control_hz)


# ------------------------------------------------------------------------------------ episode end
def test_marble_over_a_hole_ends_the_episode_as_a_failure():
    env = LabyrinthEnv("hard", action_type="discrete")
    hole = env.board.holes[4]
    _, info = env.reset(seed=0, options={"marble_xy": hole})
    assert info["over_hole"]
    _, reward, terminated, truncated, info = env.step(NOOP)
    assert terminated and not truncated and not info["is_success"] and info["over_hole"] and reward == 0.0
    with pytest.raises(RuntimeError, match="reset"):
        env.step(NOOP)
    penalised = LabyrinthEnv("hard", action_type="discrete", fail_reward=-1.0)
    penalised.reset(seed=0, options={"marble_xy": hole})
    assert penalised.step(NOOP)[1] == -1.0


def test_walls_stop_the_marble():
    """Tilted fully towards an inner wall (and, on the hard board, towards the rim), the marble rests
    against it and never gets through."""
    board = line_board(walls=((0.03, -0.05, 0.035, 0.05),))
    env = env_on(board, end_off_path=False)
    env.reset(seed=0, options={"marble_xy": (0.0, 0.0)})
    xs = [env.step(TILT_PY)[0][0] for _ in range(45)]
    assert max(xs) < 0.03 - R + 5e-4 and xs[-1] > 0.03 - R - 1e-3
    rim = LabyrinthEnv("hard", action_type="discrete", end_off_path=False)
    rim.reset(seed=0)
    ys = [rim.step(TILT_MX)[0][1] for _ in range(45)]
    top = rim.board.board_size[1] / 2 - R
    assert max(ys) < top + 5e-4 and ys[-1] > top - 1e-3


def test_off_path_ends_the_episode_or_pays_nothing():
    board = line_board()
    env = env_on(board)
    env.reset(seed=0, options={"marble_xy": (0.0, 0.05)})  # 50 mm from the path: off it
    _, reward, terminated, _, info = env.step(NOOP)
    assert terminated and info["off_path"] and not info["is_success"] and reward == 0.0
    lenient = env_on(board, end_off_path=False)
    lenient.reset(seed=0, options={"marble_xy": (0.0, 0.05)})
    _, reward, terminated, _, info = lenient.step(NOOP)
    assert not terminated and info["off_path"] and reward == 0.0


@pytest.mark.parametrize(("xy", "tolerance_off", "box_off"), [((0.05, 0.05), True, False), ((0.0, 0.024), False, True)])
def test_cyberrunners_off_path_rule_ends_episodes_by_the_free_box(xy, tolerance_off, box_off):
    """A hole 12 mm above the path at x = 0. At (50, 50) mm the marble is 50 mm from the path on open
    floor: off by the 25 mm tolerance, on by CyberRunner's box. At (0, 24) mm it is within the
    tolerance, but the hole hides the path from its box: on by the tolerance, off by CyberRunner's."""
    board = line_board(holes=((0.0, 0.012),))
    for rule, off in (("tolerance", tolerance_off), ("cyberrunner", box_off)):
        env = env_on(board, off_path_rule=rule)
        _, info = env.reset(seed=0, options={"marble_xy": xy})
        assert info["off_path"] == off and not info["over_hole"], rule
        _, reward, terminated, _, info = env.step(NOOP)
        assert terminated == off == info["off_path"], rule
        assert reward == 0.0 or not off  # a failing step pays fail_reward


# ------------------------------------------------------------------------------------ reward
def test_progress_reward_sums_to_the_path_progress_made():
    env = env_on(line_board())
    _, info = env.reset(seed=0, options={"marble_xy": (-0.08, 0.0)})
    x0, p0, total = -0.08, info["progress"], 0.0
    for _ in range(30):
        obs, reward, terminated, _, info = env.step(TILT_PY)
        total += reward
        assert not terminated
    assert info["progress"] - p0 > 0.02  # it rolled along the path
    assert total == pytest.approx(PROGRESS_SCALE * (info["progress"] - p0), abs=1e-12)
    assert total == pytest.approx(1.25 * (obs[0] - x0), abs=1e-6)  # 1.25 per metre, as CyberRunner's


@pytest.mark.parametrize("end_off_path", [True, False])
def test_teleport_far_ahead_pays_nothing_for_the_skipped_path(end_off_path):
    env = LabyrinthEnv("hard", action_type="discrete", end_off_path=end_off_path)
    _, info = env.reset(seed=0)
    progress = info["progress"]
    far = env.board.waypoints[20]  # 20 segments (≈ 0.5 m of path) ahead
    env.sim.reset(far)  # a state set mid-episode
    _, reward, terminated, _, info = env.step(NOOP)
    assert reward == 0.0 and info["progress"] == progress and info["segment"] == 0 and info["off_path"]
    assert terminated == end_off_path
    if not end_off_path:  # and rolling on from there still pays nothing
        assert sum(env.step(NOOP)[1] for _ in range(3)) == 0.0


def test_reaching_the_goal_terminates_with_success_and_the_bonus():
    env = env_on(line_board())
    env.reset(seed=0, options={"marble_xy": (0.07, 0.0)})
    for _ in range(60):
        obs, reward, terminated, _, info = env.step(TILT_PY)
        if terminated:
            break
    assert terminated and info["is_success"] and not info["over_hole"]
    assert info["segment"] == 1 and math.hypot(obs[0] - 0.1, obs[1]) <= env.board.goal_radius
    assert reward > GOAL_BONUS and reward - GOAL_BONUS < 0.05  # the bonus plus one step's progress


# ------------------------------------------------------------------------------------ determinism
@pytest.mark.parametrize("obs_mode", ["state", "cyberrunner"])
def test_same_seed_same_episode(obs_mode):
    def run(seed: int):
        env = gym.make("BiMGame/Labyrinth-Medium-v0", obs_mode=obs_mode)
        env.action_space.seed(7)
        obs, _ = env.reset(seed=seed)
        frames = [obs]
        for _ in range(15):
            frames.append(env.step(env.action_space.sample())[0])
        return frames

    a, b, c = run(3), run(3), run(4)
    flat = (lambda o: np.concatenate([v.ravel() for v in o.values()])) if obs_mode == "cyberrunner" else np.ravel
    assert all(np.array_equal(flat(x), flat(y)) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(flat(a[0]), flat(c[0]))  # the start offset comes from the seed


def test_start_offset_is_small_and_seeded():
    env = LabyrinthEnv("easy", start_noise=0.002)
    starts = np.array([env.reset(seed=s)[0][:2] for s in range(8)])
    offsets = starts - np.array(env.board.start)
    assert np.abs(offsets).max() <= 0.002 + 1e-9 and np.abs(offsets).max() > 1e-4
    exact = LabyrinthEnv("easy", start_noise=0.0)
    assert exact.reset(seed=1)[0][:2] == pytest.approx(env.board.start, abs=1e-9)


def test_pickle_round_trip_continues_the_episode():
    env = LabyrinthEnv("easy", action_type="discrete")
    env.reset(seed=5)
    for a in (TILT_PY, TILT_PY, NOOP):
        env.step(a)
    twin = pickle.loads(pickle.dumps(env))
    for a in (TILT_MX, NOOP, TILT_PY):
        assert np.array_equal(env.step(a)[0], twin.step(a)[0])


# ------------------------------------------------------------------------------------ observations
def test_state_observation_layout():
    env = LabyrinthEnv("hard")
    obs, info = env.reset(seed=2)
    assert obs.shape == (17,) and obs.dtype == np.float32
    x, y = env.sim.marble_xy()
    assert obs[:2] == pytest.approx([x, y]) and obs[6] == pytest.approx(info["progress_fraction"])
    ahead = path_points_ahead(env.path, info["progress"]) - (x, y)
    assert obs[7:] == pytest.approx(ahead.ravel().astype(np.float32))
    spacing = np.diff(path_points_ahead(env.path, 0.0), axis=0)
    assert np.linalg.norm(spacing, axis=1) == pytest.approx(0.012)  # along the first, straight segment


def test_pixels_show_the_marble_where_it_is():
    env = LabyrinthEnv("hard", obs_mode="pixels", obs_size=84)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (1, 84, 84) and obs.dtype == np.uint8
    for _ in range(10):
        obs = env.step(np.array([0.3, 0.5], dtype=np.float32))[0]
    frame, bg = obs[0].astype(float), env.observer.raster.background
    weight = np.clip(frame - bg, 0, None)
    rows, cols = np.indices(frame.shape)
    centroid = np.array([(weight * cols).sum(), (weight * rows).sum()]) / weight.sum()
    expected = env.observer.raster.grid.to_pixel(env.sim.marble_xy())
    assert np.abs(centroid - expected).max() < 1.0
    holes = np.rint(env.observer.raster.grid.to_pixel(np.array(env.board.holes))).astype(int)
    assert frame[holes[:, 1], holes[:, 0]].max() < 60  # holes where the layout has them


def test_cyberrunner_observation():
    env = LabyrinthEnv("hard", obs_mode="cyberrunner")
    obs, info = env.reset(seed=1)
    assert set(obs) == {"image", "states", "goal"}
    assert obs["image"].shape == (1, 64, 64) and obs["image"][0, 32, 32] == GRAY["marble"][0]
    x, y = env.sim.marble_xy()
    assert obs["states"] == pytest.approx([0.0, 0.0, (x + 0.138) / 0.276, (y + 0.1155) / 0.231], abs=1e-6)
    ahead = (path_points_ahead(env.path, info["progress"]) - (x, y)).ravel()
    assert obs["goal"] == pytest.approx(ahead / np.repeat(0.012 * np.arange(1, 6), 2), abs=1e-6)


# ------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"layout": "expert"}, "allowed: easy, medium, hard"),
        ({"action_type": "torque"}, "allowed: continuous, discrete"),
        ({"control_hz": 60}, r"control_hz must be one of \(30, 55\)"),
        ({"control_hz": True}, r"control_hz must be one of \(30, 55\)"),
        ({"obs_mode": "rgb"}, "allowed: state, pixels, cyberrunner"),
        ({"obs_size": 8}, "obs_size must be an integer in 16..1024"),
        ({"render_mode": "human"}, "allowed: None, 'rgb_array'"),
        ({"render_size": 4096}, "render_size must be an integer in 16..2048"),
        ({"max_tilt_rate_deg": 0}, r"max_tilt_rate_deg must be a finite number in \(0, 180\]"),
        ({"max_tilt_rate_deg": 500.0}, r"max_tilt_rate_deg must be a finite number in \[0, 180\]"),
        ({"progress_scale": math.nan}, "progress_scale must be a finite number"),
        ({"goal_bonus": "1"}, "goal_bonus must be a finite number"),
        ({"end_off_path": "yes"}, "end_off_path must be True or False"),
        ({"off_path_rule": "box"}, "unknown off_path_rule 'box'; allowed: tolerance, cyberrunner"),
        ({"start_noise": 0.01}, r"start_noise must be a finite number in \[0, 0.005\]"),
        ({"start_noise": 0.005, "layout": "easy"}, "start_noise .* lets the marble start"),
        ({"board": "hard"}, "board must be a LabyrinthSpec"),
        ({"path_width": -0.001}, r"path_width must be a finite number in \[0, 0.02\]"),
    ],
)
def test_bad_arguments_name_what_is_allowed(kwargs, message):
    with pytest.raises(ValueError, match=message):
        LabyrinthEnv(**kwargs)


def test_bad_actions_and_options_name_what_is_allowed():
    env = LabyrinthEnv("easy")
    env.reset(seed=0)
    for action in ([2.0, 0.0], [0.0, 0.0, 0.0], [math.nan, 0.0], "up"):
        with pytest.raises(ValueError, match=r"continuous actions are 2 finite numbers in \[-1, 1\]"):
            env.step(action)
    discrete = LabyrinthEnv("easy", action_type="discrete")
    discrete.reset(seed=0)
    for action in (5, -1, 1.5, True, None):
        with pytest.raises(ValueError, match=r"discrete actions are integers 0\.\.4"):
            discrete.step(action)
    with pytest.raises(ValueError, match="'marble_xy', 'sim_state'"):
        discrete.reset(options={"start": (0, 0)})
    with pytest.raises(ValueError, match=r"options\['marble_xy'\]"):
        discrete.reset(options={"marble_xy": (0.5, 0.0)})
    with pytest.raises(ValueError, match=r"options\['sim_state'\]"):
        discrete.reset(options={"sim_state": np.zeros(3)})
    with pytest.raises(RuntimeError, match="reset"):
        LabyrinthEnv("easy").step(np.zeros(2))


def test_state_observation_is_the_state_modes_observation_whatever_the_env_observes():
    """The privileged state a pixel learner's auxiliary heads predict: the 17 values ``obs_mode="state"``
    returns at the same step, for any observation mode."""
    pixels, state = LabyrinthEnv("easy", obs_mode="pixels"), LabyrinthEnv("easy")
    with pytest.raises(RuntimeError, match=r"call reset\(\) before state_observation\(\)"):
        pixels.state_observation()
    _, _ = pixels.reset(seed=4)
    expected, _ = state.reset(seed=4)
    for t in range(15):
        np.testing.assert_array_equal(pixels.state_observation(), expected)
        action = np.array([1.0, -0.5] if t < 8 else [-1.0, 0.0], dtype=np.float32)
        pixels.step(action)
        expected, *_ = state.step(action)
    pixels.close()
    state.close()
