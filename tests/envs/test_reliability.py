"""Bad inputs to the envs fail at once with a message that says what is wrong, instead of hanging,
being silently accepted or corrupting an episode: too many marbles, marbles placed in walls or on
each other, malformed ``marble_xy``, stepping a finished episode, unchecked constructor arguments."""

from __future__ import annotations

import math
import pickle
import subprocess
import sys
import textwrap

import gymnasium as gym
import numpy as np
import pytest

import bimgame  # noqa: F401
from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.sim.maze import MazeSpec

SPEC = MazeSpec.merl()
#: Seeds whose random start of 16 marbles jams (no room is left for the next marble), for which
#: reset() used to loop forever.
JAMMING_SEEDS_16 = (2, 3, 7)


def polar(r: float, deg: float) -> list[float]:
    return [r * math.cos(math.radians(deg)), r * math.sin(math.radians(deg))]


def run_with_timeout(code: str, seconds: float = 60.0) -> str:
    """Run ``code`` in a fresh interpreter; fail (rather than hang the suite) if it takes too long."""
    try:
        done = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                              text=True, timeout=seconds)
    except subprocess.TimeoutExpired:
        pytest.fail(f"did not finish within {seconds:.0f} s (an unbounded loop?)")
    assert done.returncode == 0, done.stderr
    return done.stdout


# ------------------------------------------------------------------ 1. how many marbles fit
def test_too_many_marbles_are_refused_at_construction_naming_the_maximum():
    with pytest.raises(ValueError, match=r"n_marbles=100 is too many: at most 22 marbles fit on the "
                                         r"outermost channel.*two marble diameters"):
        gym.make("BiMGame/FULL-v0", n_marbles=100)
    with pytest.raises(ValueError, match="n_marbles=23 .*at most 22"):
        BallInMazeEnv("STG1", n_marbles=23, obs_mode="state")
    with pytest.raises(ValueError, match="n_marbles=23 .*at most 22"):
        BallInMazeVectorEnv(2, task="FULL", n_marbles=23, obs_mode="state")
    for bad in (0, True, 2.0, "2"):
        with pytest.raises(ValueError, match="n_marbles must be an integer >= 1"):
            BallInMazeEnv("FULL", n_marbles=bad)


def test_reset_with_many_marbles_never_hangs_and_keeps_marbles_apart():
    """Up to the 22 marbles that fit, for seeds where placing marbles one at a time jams (16
    marbles: seeds 2, 3, 7 used to hang for ever), in the single and the vector env."""
    out = run_with_timeout(f"""
        import math
        import numpy as np
        from bimgame.envs.env import BallInMazeEnv
        from bimgame.envs.vector import BallInMazeVectorEnv
        for n, seeds in ((16, {JAMMING_SEEDS_16}), (22, (0, 1))):
            env = BallInMazeEnv("FULL", obs_mode="state", n_marbles=n)
            for seed in seeds:
                obs, info = env.reset(seed=seed)
                xy = obs[:4 * n].reshape(n, 4)[:, :2].astype(float)
                angle = np.arctan2(xy[:, 1], xy[:, 0])
                gap = np.abs((angle[:, None] - angle[None] + np.pi) % (2 * np.pi) - np.pi)
                gap[np.arange(n), np.arange(n)] = np.inf
                radius = env.maze.channel_centre_radius(4)
                assert gap.min() * radius >= 4 * env.maze.marble_radius * (1 - 1e-6), (n, seed, gap.min())
                assert info["channel"].tolist() == [4] * n
                np.testing.assert_array_equal(env.reset(seed=seed)[0], obs)  # same seed, same start
            vec = BallInMazeVectorEnv(3, task="FULL", obs_mode="state", n_marbles=n)
            vec.reset(seed=seeds[0])
            vec.step(np.zeros(3, dtype=np.int64))
        print("ok")
    """)
    assert out.strip() == "ok"


# ------------------------------------------------------------------ 2. marble_xy
def test_a_marble_in_a_wall_is_refused_naming_the_wall():
    """[[0.072, 0]] overlaps wall 3's solid inner face; the contact solver used to kick the marble
    inwards through wall 2's gate at 0°, and FULL paid +1 for no action."""
    env = BallInMazeEnv("FULL", obs_mode="state")
    with pytest.raises(ValueError, match=r"marble_xy'\]\[0\] = \(72\.00, 0\.00\) mm.* overlaps walls\[3\] "
                                         r"\(solid from 76\.20 to 81\.70 mm"):
        env.reset(seed=0, options={"marble_xy": [[0.072, 0.0]]})
    with pytest.raises(ValueError, match=r"overlaps walls\[2\]"):
        env.reset(seed=0, options={"marble_xy": [polar(SPEC.walls[2].mid_radius, 30.0)]})
    with pytest.raises(ValueError, match=r"overlaps walls\[0\]"):  # centred on a gate's edge
        env.reset(seed=0, options={"marble_xy": [polar(SPEC.walls[0].mid_radius, 180.0 - 25.0)]})


def test_marbles_in_channels_and_gates_are_accepted():
    env = BallInMazeEnv("FULL", obs_mode="state", n_marbles=2)
    # In the middle of wall 3's gate at 45° (inside the wall's thickness) and in channel 2.
    xy = [polar(SPEC.walls[3].mid_radius, 45.0), polar(SPEC.channel_centre_radius(2), 10.0)]
    obs, info = env.reset(seed=0, options={"marble_xy": xy})
    np.testing.assert_allclose(obs[[0, 1, 4, 5]], np.ravel(xy), atol=1e-6)
    # Touching the rim and touching each other are allowed.
    edge = SPEC.rim_radius - SPEC.marble_radius
    touching = math.degrees(2 * math.asin(SPEC.marble_radius / edge))
    env.reset(options={"marble_xy": [polar(edge, 0.0), polar(edge, touching)]})


def test_overlapping_marbles_are_refused_naming_both():
    env = BallInMazeEnv("FULL", obs_mode="state", n_marbles=3)
    r = SPEC.channel_centre_radius(4)
    xy = [polar(r, 0.0), polar(r, 90.0), polar(r, 92.0)]
    with pytest.raises(ValueError, match=r"marbles 1 and 2 overlap: .* 3\.12 mm apart, less than the "
                                         r"marble diameter \(12\.70 mm\)"):
        env.reset(options={"marble_xy": xy})


def test_a_marble_off_the_board_is_refused_naming_it():
    env = BallInMazeEnv("FULL", obs_mode="state")
    with pytest.raises(ValueError, match=r"marble_xy'\]\[0\] .* overlaps the rim or lies off the board.*"
                                         r"within 90\.45 mm"):
        env.reset(options={"marble_xy": [[0.5, 0.0]]})
    with pytest.raises(ValueError, match="overlaps the rim"):  # inside the rim by less than a radius
        env.reset(options={"marble_xy": [[0.0, -0.093]]})


def test_marble_xy_errors_say_whether_shape_or_values_are_wrong():
    env = BallInMazeEnv("FULL", obs_mode="state")
    with pytest.raises(ValueError) as error:
        env.reset(options={"marble_xy": [[np.nan, 0.0]]})
    assert "is not finite at (0, 0)" in str(error.value) and "shape" not in str(error.value)
    with pytest.raises(ValueError) as error:
        env.reset(options={"marble_xy": [0.05, 0.0]})
    assert "must have shape (1, 2)" in str(error.value) and "got shape (2,)" in str(error.value)
    assert "finite" not in str(error.value)
    with pytest.raises(ValueError, match=r"options\['marble_xy'\] must be numbers"):
        env.reset(options={"marble_xy": [["a", 0.0]]})
    with pytest.raises(ValueError, match="reset options must be a dict"):
        env.reset(options=[("marble_xy", [[0.0, 0.0]])])


def test_a_start_past_the_goal_earns_nothing():
    """STG1 with the marble already inside wall 3 used to pay +1 on the first no-op."""
    env = BallInMazeEnv("STG1", obs_mode="state")
    env.reset(options={"marble_xy": [polar(SPEC.channel_centre_radius(3), 10.0)]})
    _, reward, terminated, _, info = env.step(0)
    assert reward == 0.0 and terminated and info["is_success"]
    two = BallInMazeEnv("STG1", obs_mode="state", n_marbles=2)
    two.reset(options={"marble_xy": [polar(SPEC.channel_centre_radius(3), 10.0),
                                     polar(SPEC.channel_centre_radius(4), 10.0)]})
    _, reward, terminated, _, _ = two.step(0)
    assert reward == 0.0 and not terminated


# ------------------------------------------------------------------ 3. stepping a finished episode
def test_step_after_termination_raises_until_reset():
    """FULL from channel 1 through wall 0's gate: +1 and the end. Stepping on used to continue the
    episode (and terminated could flip back to False with -1 rewards)."""
    env = BallInMazeEnv("FULL", obs_mode="state")
    env.reset(options={"marble_xy": [polar(SPEC.channel_centre_radius(1), 180.0)]})
    for action in [3, 3, 3] + [0] * 60:
        _, reward, terminated, _, _ = env.step(action)
        if terminated:
            break
    assert terminated and reward == 1.0
    with pytest.raises(RuntimeError, match=r"the episode has ended \(terminated\); call reset\(\) before step\(\)"):
        env.step(0)
    clone = pickle.loads(pickle.dumps(env))  # the flag travels with the env
    with pytest.raises(RuntimeError, match="episode has ended"):
        clone.step(0)
    env.reset(seed=0)
    env.step(0)  # a new episode steps again


def test_wrapped_env_after_termination_and_truncation():
    """gym.make's wrappers pass the error through after termination; after TimeLimit's truncation the
    env has not ended its episode: stepping on continues it and TimeLimit keeps saying truncated."""
    env = gym.make("BiMGame/FULL-v0", obs_mode="state", max_episode_steps=5)
    env.reset(options={"marble_xy": [[0.0, 0.0]]})  # already in the centre: the first step ends it
    _, reward, terminated, truncated, _ = env.step(0)
    assert terminated and not truncated and reward == 0.0
    with pytest.raises(RuntimeError, match="episode has ended"):
        env.step(0)
    env.reset(seed=0)
    for _ in range(5):
        _, _, terminated, truncated, _ = env.step(0)
    assert truncated and not terminated
    _, _, terminated, truncated, _ = env.step(0)
    assert truncated and not terminated


def test_sync_vector_env_never_steps_a_finished_episode():
    envs = gym.make_vec("BiMGame/FULL-v0", num_envs=2, vectorization_mode="sync", obs_mode="state")
    envs.reset(seed=0)
    inner = envs.envs[0].unwrapped
    inner.reset(options={"marble_xy": [[0.0, 0.0]]})  # env 0 ends at the next step, then autoresets
    _, _, terminated, _, _ = envs.step(np.zeros(2, dtype=np.int64))
    assert terminated.tolist() == [True, False]
    for _ in range(3):
        envs.step(np.zeros(2, dtype=np.int64))
    envs.close()


def test_a_refused_reset_does_not_leave_the_previous_episode_running():
    env = BallInMazeEnv("FULL", obs_mode="state")
    env.reset(seed=0)
    env.step(1)
    with pytest.raises(ValueError, match="overlaps walls"):
        env.reset(options={"marble_xy": [[0.072, 0.0]]})
    with pytest.raises(RuntimeError, match=r"call reset\(\) before step\(\)"):
        env.step(0)


# ------------------------------------------------------------------ siblings: constructor arguments
def test_a_maze_without_walls_is_refused_at_construction():
    with pytest.raises(ValueError, match="maze has no walls"):
        BallInMazeEnv("FULL", maze=MazeSpec(walls=(), rim_radius=0.05))


@pytest.mark.parametrize("size", [0, 3.7, "abc", True, 100_000])
def test_render_size_is_checked_at_construction(size):
    with pytest.raises(ValueError, match=r"render_size must be an integer in 16\.\.2048"):
        BallInMazeEnv("FULL", obs_mode="state", render_mode="rgb_array", render_size=size)


def test_mujoco_renderer_size_is_limited_to_its_framebuffer():
    with pytest.raises(ValueError, match=r"render_size must be an integer in 16\.\.640 \(renderer='mujoco'\)"):
        BallInMazeEnv("FULL", obs_mode="state", render_mode="rgb_array", renderer="mujoco", render_size=1000)


def test_tilt_arguments_accept_numpy_numbers_and_refuse_bools():
    env = BallInMazeEnv("FULL", obs_mode="state", tilt_step_deg=np.float32(0.5), max_tilt_deg=np.int64(4))
    assert env.maze.tilt_step == pytest.approx(math.radians(0.5))
    with pytest.raises(ValueError, match="tilt_step_deg must be a positive number"):
        BallInMazeEnv("FULL", tilt_step_deg=True)
    with pytest.raises(ValueError, match=r"must not exceed max_tilt .*from tilt_step_deg=6, max_tilt_deg=None"):
        BallInMazeEnv("FULL", tilt_step_deg=6)


@pytest.mark.parametrize("argument", ["num_envs", "nthread", "max_episode_steps"])
def test_vector_env_counts_refuse_bools(argument):
    kwargs = {"num_envs": 2, argument: True}
    with pytest.raises(ValueError, match=argument):
        BallInMazeVectorEnv(task="FULL", obs_mode="state", **kwargs)


def test_vector_env_refuses_options_naming_them():
    env = BallInMazeVectorEnv(2, task="FULL", obs_mode="state")
    with pytest.raises(ValueError, match=r"takes only the option 'maze' .*\['marble_xy'\]"):
        env.reset(options={"marble_xy": [[0.0, 0.0]]})
