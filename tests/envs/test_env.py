"""The Gymnasium env: API conformance, tasks, determinism, pickling, vectorisation, bad input."""

from __future__ import annotations

import math
import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import bimgame
from bimgame.envs.env import BallInMazeEnv
from bimgame.sim.maze import MazeSpec
from bimgame.sim.tasks import MAX_EPISODE_STEPS, Task

IDS = bimgame.ENV_IDS


def polar(r: float, deg: float) -> list[float]:
    return [r * math.cos(math.radians(deg)), r * math.sin(math.radians(deg))]


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize("obs_mode", ["pixels", "state"])
def test_check_env_passes_for_every_id(env_id, obs_mode):
    env = gym.make(env_id, obs_mode=obs_mode)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_registered_ids_and_time_limits():
    assert IDS == ("BiMGame/FULL-v0", "BiMGame/STG1-v0", "BiMGame/STG2-v0", "BiMGame/STG3-v0", "BiMGame/STG4-v0")
    for env_id in IDS:
        spec = gym.spec(env_id)
        task = Task(env_id.split("/")[1].split("-")[0])
        assert spec.max_episode_steps == MAX_EPISODE_STEPS[task]
    env = gym.make("BiMGame/STG1-v0", obs_mode="state")
    env.reset(seed=0)
    for step in range(MAX_EPISODE_STEPS[Task.STG1]):
        _, _, terminated, truncated, _ = env.step(0)  # no-op: the marble stays put
        assert not terminated
    assert truncated and step == 299


def test_observation_layouts():
    env = BallInMazeEnv("FULL", obs_mode="pixels")
    obs, info = env.reset(seed=3)
    assert obs.shape == (1, 84, 84) and obs.dtype == np.uint8
    env = BallInMazeEnv("FULL", obs_mode="state", n_marbles=2)
    obs, info = env.reset(seed=3)
    assert obs.shape == (12,) and obs.dtype == np.float32
    positions, velocities = env.sim.marble_kinematics()
    np.testing.assert_allclose(obs[0:2], positions[0, :2], atol=1e-7)
    np.testing.assert_allclose(obs[4:6], positions[1, :2], atol=1e-7)
    assert list(obs[10:]) == [4.0, 4.0]
    assert set(info) == {"channel", "gate_crossings", "geodesic_distance", "goal_distance", "is_success", "tilt"}
    assert info["channel"].tolist() == [4, 4]


def test_reset_starts_at_rest_on_the_outermost_channel_at_random_angles():
    env = BallInMazeEnv("FULL", obs_mode="state")
    spec = env.maze
    radius = spec.channel_centre_radius(spec.outermost_channel)
    angles = []
    for seed in range(40):
        obs, info = env.reset(seed=seed)
        assert math.hypot(obs[0], obs[1]) == pytest.approx(radius, abs=1e-6)  # float32
        assert obs[2] == 0 and obs[3] == 0 and obs[4] == 0 and obs[5] == 0
        angles.append(math.atan2(obs[1], obs[0]))
    # Spread over the whole circle: every quadrant is hit.
    assert len({int((a + math.pi) // (math.pi / 2)) for a in angles}) == 4


def test_same_seed_same_episode_and_different_seed_differs():
    def episode(seed):
        env = gym.make("BiMGame/STG1-v0", obs_mode="state")
        obs, _ = env.reset(seed=seed)
        env.action_space.seed(seed)
        trace = [obs]
        for _ in range(150):
            obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
            trace.append(np.append(obs, reward))
            if terminated or truncated:
                break
        return trace
    a, b, c = episode(7), episode(7), episode(8)
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not np.array_equal(a[0], c[0])


def test_pickle_round_trip_continues_identically():
    env = BallInMazeEnv("FULL", obs_mode="state")
    env.reset(seed=11)
    for action in [1, 1, 3, 0, 2]:
        env.step(action)
    clone = pickle.loads(pickle.dumps(env))
    for action in [4, 4, 1, 0, 0, 3, 2, 2]:
        a = env.step(action)
        b = clone.step(action)
        assert np.array_equal(a[0], b[0]) and a[1:4] == b[1:4]
    # The random generator travels too: the next reset draws the same start.
    assert np.array_equal(env.reset()[0], clone.reset()[0])


def test_tilt_actions_move_the_board_and_the_marble_rolls_downhill():
    env = BallInMazeEnv("FULL", obs_mode="state")
    # On the outermost channel's centre circle where downhill is along the channel: free to roll
    # (not in the centre region, where FULL's episode would end at the first step).
    radius = env.maze.channel_centre_radius(4)
    env.reset(seed=0, options={"marble_xy": [[0.0, radius]]})
    for _ in range(3):
        obs, *_ = env.step(3)  # +y tilt three times: the +x edge goes down
    assert obs[5] == pytest.approx(math.radians(3), abs=math.radians(0.05))
    for _ in range(5):
        obs, *_ = env.step(0)
    assert obs[2] > 0.01 and abs(obs[3]) < 1e-4  # rolling towards +x
    env.reset(seed=0, options={"marble_xy": [[radius, 0.0]]})
    for _ in range(8):
        obs, *_ = env.step(1 if _ < 3 else 0)  # +x tilt: the +y edge goes up
    assert obs[3] < -0.01 and abs(obs[2]) < 1e-4  # rolling towards -y
    # The tilt is clamped at max_tilt_deg.
    for _ in range(10):
        obs, *_ = env.step(1)
    assert obs[4] == pytest.approx(math.radians(5), abs=math.radians(0.06))


def test_continuous_actions():
    env = BallInMazeEnv("FULL", obs_mode="state", action_type="continuous", tilt_step_deg=0.5)
    env.reset(seed=0)
    for _ in range(4):
        obs, *_ = env.step(np.array([1.0, -0.5], dtype=np.float32))
    assert obs[4] == pytest.approx(math.radians(2.0), abs=math.radians(0.05))
    assert obs[5] == pytest.approx(math.radians(-1.0), abs=math.radians(0.05))


def _drive_through_gate(task: str, start_deg: float, push_deg: float):
    """Tilt the board so the marble, starting at a wall-3 gate, rolls inwards."""
    spec = MazeSpec.merl()
    env = BallInMazeEnv(task, obs_mode="state")
    env.reset(options={"marble_xy": [polar(spec.channel_centre_radius(4), start_deg)]})
    # Downhill towards (ux, uy) needs tilt_x = -uy·θ and tilt_y = +ux·θ (+x tilt raises the +y
    # edge, +y tilt lowers the +x edge).
    ux, uy = math.cos(math.radians(push_deg)), math.sin(math.radians(push_deg))
    rewards, infos = [], []
    target = np.array([0.0, 0.0])
    for step in range(120):
        desired = np.array([-uy, ux]) * math.radians(3)
        error = desired - target
        axis = int(np.argmax(np.abs(error)))
        action = 0
        if abs(error[axis]) >= math.radians(0.5):
            action = (1 if error[0] > 0 else 2) if axis == 0 else (3 if error[1] > 0 else 4)
            target[axis] += math.radians(1) * (1 if action in (1, 3) else -1)
        _, reward, terminated, truncated, info = env.step(action)
        rewards.append(reward)
        infos.append(info)
        if terminated:
            break
    return rewards, infos, terminated


def test_stg1_rewards_one_and_terminates_when_the_marble_passes_wall_3():
    rewards, infos, terminated = _drive_through_gate("STG1", 45.0, 225.0)
    assert terminated and rewards[-1] == 1.0 and sum(rewards) == 1.0
    assert infos[-1]["is_success"] and infos[-1]["channel"].tolist() == [3]
    assert infos[-1]["gate_crossings"].tolist() == [1]
    # The geodesic distance fell on the way in; the distance to STG1's goal (through wall 3) is
    # down to the rest of the way through its gate at the end, the one to the centre is not.
    assert infos[-1]["geodesic_distance"][0] < infos[0]["geodesic_distance"][0] - 0.01
    assert infos[-1]["goal_distance"][0] < 0.01 < infos[0]["goal_distance"][0] < infos[0]["geodesic_distance"][0]
    assert infos[-1]["geodesic_distance"][0] > 0.05


def test_full_rewards_each_inward_crossing_and_does_not_terminate_at_wall_3():
    rewards, infos, terminated = _drive_through_gate("FULL", 45.0, 225.0)
    crossings = [i for i, r in enumerate(rewards) if r != 0]
    assert crossings and rewards[crossings[0]] == 1.0
    assert not infos[crossings[0]]["is_success"]


def test_full_penalises_outward_crossings_and_terminates_in_the_centre():
    spec = MazeSpec.merl()
    env = BallInMazeEnv("FULL", obs_mode="state")
    # In channel 1 right at wall 0's gate (180°), rolled inwards: +1 and the episode ends.
    env.reset(options={"marble_xy": [polar(spec.channel_centre_radius(1), 180.0)]})
    total, terminated = 0.0, False
    for action in [3, 3, 3] + [0] * 60:  # +y tilt sends the marble towards +x: through the gate
        _, reward, terminated, _, info = env.step(action)
        total += reward
        if terminated:
            break
    assert terminated and total == 1.0 and info["channel"].tolist() == [0] and info["is_success"]
    # From channel 3 at a wall-3 gate (45°), rolled outwards: -1, no termination.
    env.reset(options={"marble_xy": [polar(spec.channel_centre_radius(3), 45.0)]})
    total = 0.0
    for action in [2, 2, 3, 3] + [0] * 40:  # tilt so that downhill points to 45°
        _, reward, terminated, _, info = env.step(action)
        total += reward
    assert total == -1.0 and info["channel"].tolist() == [4] and not terminated


@pytest.mark.parametrize("task, wall", [("STG2", 2), ("STG3", 1), ("STG4", 0)])
def test_stgk_ends_at_the_kth_wall(task, wall):
    spec = MazeSpec.merl()
    gate = math.degrees(spec.walls[wall].gates[0].angle)
    env = BallInMazeEnv(task, obs_mode="state")
    # Just outside the k-th wall at one of its gates: crossing it is worth 1 and ends the episode.
    env.reset(options={"marble_xy": [polar(spec.channel_centre_radius(wall + 1), gate)]})
    ux, uy = -math.cos(math.radians(gate)), -math.sin(math.radians(gate))
    actions = [2 if uy > 0.5 else 1 if uy < -0.5 else 0, 3 if ux > 0.5 else 4 if ux < -0.5 else 0] * 2
    total, terminated = 0.0, False
    for action in actions + [0] * 60:
        _, reward, terminated, _, info = env.step(action)
        total += reward
        if terminated:
            break
    assert terminated and total == 1.0 and info["channel"][0] == wall


def test_bad_inputs_name_the_value_and_the_allowed_ones():
    with pytest.raises(ValueError, match="unknown task 'STG9'.*FULL, STG1, STG2, STG3, STG4"):
        BallInMazeEnv("STG9")
    with pytest.raises(ValueError, match="unknown obs_mode 'rgb'.*pixels, state"):
        BallInMazeEnv("FULL", obs_mode="rgb")
    with pytest.raises(ValueError, match="unknown action_type"):
        BallInMazeEnv("FULL", action_type="multi")
    with pytest.raises(ValueError, match="render_mode"):
        BallInMazeEnv("FULL", render_mode="human")
    with pytest.raises(ValueError, match="tilt_step_deg"):
        BallInMazeEnv("FULL", tilt_step_deg=-1)
    with pytest.raises(ValueError, match="STG4 needs a maze with at least 4 walls"):
        BallInMazeEnv("STG4", maze=MazeSpec(walls=MazeSpec.merl().walls[:2], rim_radius=0.06))
    env = BallInMazeEnv("FULL", obs_mode="state")
    with pytest.raises(RuntimeError, match="reset"):
        env.step(0)
    env.reset(seed=0)
    for bad in (5, -1, 1.5, "1", None, True):
        with pytest.raises(ValueError, match=r"integers 0\.\.4"):
            env.step(bad)
    env = BallInMazeEnv("FULL", obs_mode="state", action_type="continuous")
    env.reset(seed=0)
    for bad in (np.array([np.nan, 0.0]), np.array([2.0, 0.0]), np.zeros(3)):
        with pytest.raises(ValueError, match=r"finite numbers in\s+\[-1, 1\]"):
            env.step(bad)
    with pytest.raises(ValueError, match="marble_xy"):
        env.reset(options={"marble_xy": [[0.5, 0.0]]})
    with pytest.raises(ValueError, match="unknown reset options"):
        env.reset(options={"start": 1})


def test_render_rgb_frame_and_mujoco_renderer_message():
    env = BallInMazeEnv("FULL", obs_mode="state", render_mode="rgb_array", render_size=200)
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (200, 200, 3) and frame.dtype == np.uint8
    env = BallInMazeEnv("FULL", obs_mode="state", render_mode="rgb_array", renderer="mujoco")
    env.reset(seed=0)
    try:
        frame = env.render()
    except RuntimeError as error:  # no OpenGL here: the message says what to do
        assert "MUJOCO_GL" in str(error) and "renderer='raster'" in str(error)
    else:
        assert frame.ndim == 3 and frame.shape[2] == 3


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_make_vec_sync_and_async(mode):
    envs = gym.make_vec("BiMGame/STG1-v0", num_envs=2, vectorization_mode=mode, obs_mode="state")
    obs, info = envs.reset(seed=1)
    assert obs.shape == (2, 7)
    for _ in range(5):
        obs, reward, terminated, truncated, info = envs.step(np.array([1, 3]))
    assert obs.shape == (2, 7) and reward.shape == (2,)
    assert info["channel"].shape == (2, 1)
    envs.close()
