"""Tests of the labyrinth's batched vector env (bimgame.envs.labyrinth_vector): it equals N single
``LabyrinthEnv``s bit for bit (every layout, both action types, across episode ends, in both
autoreset modes and every observation mode), autoresets in the same step with the finished step's
observation kept, seeds, the learners' collector drives it, and bad input is refused by name."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.vector import AutoresetMode

import bimgame  # noqa: F401 - registers the labyrinth ids
from bimgame.envs.labyrinth_vector import LabyrinthVectorEnv

N = 4
SEED = 7


def env_id(layout: str) -> str:
    return f"BiMGame/Labyrinth-{layout.capitalize()}-v0"


def held_actions(action_type: str, steps: int, seed: int = 1, hold: int = 15) -> np.ndarray:
    """Random actions, each held for ``hold`` steps so that marbles travel far enough to fall into
    holes, leave the path and hit the time limit."""
    rng = np.random.default_rng(seed)
    draws = -(-steps // hold)
    if action_type == "discrete":
        actions = rng.integers(0, 5, (draws, N))
    else:
        actions = rng.uniform(-1, 1, (draws, N, 2)).astype(np.float32)
    return np.repeat(actions, hold, axis=0)[:steps]


def assert_obs_equal(a, b) -> None:
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])
    else:
        np.testing.assert_array_equal(a, b)


def row(obs, i):
    return {k: v[i] for k, v in obs.items()} if isinstance(obs, dict) else obs[i]


# ------------------------------------------------------------------------------------ equality
@pytest.mark.parametrize("layout", ["easy", "medium", "hard"])
@pytest.mark.parametrize("action_type", ["continuous", "discrete"])
def test_equals_single_envs_step_by_step_across_episode_ends(layout, action_type):
    """300 steps of 4 boards against 4 ``gym.make`` envs seeded ``SEED + i``, each reset by hand
    when its episode ends (what SAME_STEP autoreset does): identical observations, rewards,
    terminations, truncations, final observations and infos. Board 0 starts over a hole, so that
    every layout has a terminated episode (random play rarely ends one on the open medium board)."""
    _equals_single_envs(layout, action_type)


@pytest.mark.parametrize("layout", ["easy", "hard"])
def test_equals_single_envs_with_cyberrunners_off_path_rule(layout):
    """The same comparison with episodes judged off the path by CyberRunner's free-box test."""
    _equals_single_envs(layout, "continuous", off_path_rule="cyberrunner")


def _equals_single_envs(layout: str, action_type: str, **options) -> None:
    limit = 100
    vec = LabyrinthVectorEnv(N, layout, action_type=action_type, max_episode_steps=limit, **options)
    singles = [gym.make(env_id(layout), action_type=action_type, max_episode_steps=limit, **options)
               for _ in range(N)]
    starts = np.array([vec.board.holes[0]] + [vec.board.start] * (N - 1))
    obs, info = vec.reset(seed=SEED, options={"marble_xy": starts})
    for i, env in enumerate(singles):
        o, inf = env.reset(seed=SEED + i, options={"marble_xy": starts[i]})
        np.testing.assert_array_equal(obs[i], o)
        assert info["progress"][i] == inf["progress"] and info["segment"][i] == inf["segment"]
    ends = {"terminated": 0, "truncated": 0}
    for actions in held_actions(action_type, 300):
        obs, reward, terminated, truncated, info = vec.step(actions)
        for i, env in enumerate(singles):
            o, r, term, trunc, inf = env.step(actions[i])
            assert (reward[i], terminated[i], truncated[i]) == (r, term, trunc)
            for key in ("progress", "segment", "over_hole", "off_path", "is_success"):
                got = (info["final_info"] if term or trunc else info)[key][i]
                assert got == inf[key], key
            if term or trunc:
                assert info["_final_obs"][i]
                np.testing.assert_array_equal(info["final_obs"][i], o)
                np.testing.assert_array_equal(info["final_info"]["tilt"][i], inf["tilt"])
                assert info["final_info"]["task_reward"][i] == r
                ends["terminated"] += term
                ends["truncated"] += trunc
                o, _ = env.reset()
            elif "final_obs" in info:
                assert not info["_final_obs"][i]
            np.testing.assert_array_equal(obs[i], o)
        np.testing.assert_array_equal(info["task_reward"], reward)
    assert ends["terminated"] > 0 and ends["truncated"] > 0, ends


def test_next_step_autoreset_equals_gymnasiums_sync_vector_env():
    """With NEXT_STEP autoreset it is Gymnasium's own sync vector env of the single env, exactly."""
    limit = 60
    vec = LabyrinthVectorEnv(N, "hard", max_episode_steps=limit, autoreset_mode=AutoresetMode.NEXT_STEP)
    sync = gym.vector.SyncVectorEnv([lambda: gym.make(env_id("hard"), max_episode_steps=limit)] * N)
    assert vec.metadata["autoreset_mode"] == sync.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    np.testing.assert_array_equal(vec.reset(seed=SEED)[0], sync.reset(seed=SEED)[0])
    resets = 0
    for actions in held_actions("continuous", 150, seed=2):
        a, b = vec.step(actions), sync.step(actions)
        for got, expected in zip(a[:4], b[:4], strict=True):
            np.testing.assert_array_equal(got, expected)
        np.testing.assert_array_equal(a[4]["progress"], b[4]["progress"])
        resets += int((a[2] | a[3]).sum())
    assert resets >= N


@pytest.mark.parametrize(
    "obs_mode, extra",
    [("pixels", {}), ("pixels", {"motion": True}), ("cyberrunner", {}), ("cyberrunner", {"motion": True})],
)
def test_image_observations_and_privileged_state_equal_single_envs(obs_mode, extra):
    """Pixel and CyberRunner observations (also with the marble's motion, which each board measures
    from its own previous observation, across resets) are the single env's; ``state_info`` reports
    the state observation of the same step (the state-mode env's observation)."""
    limit = 30
    vec = LabyrinthVectorEnv(N, "easy", obs_mode=obs_mode, max_episode_steps=limit, state_info=True, **extra)
    singles = [gym.make(env_id("easy"), obs_mode=obs_mode, max_episode_steps=limit, **extra) for _ in range(N)]
    states = LabyrinthVectorEnv(N, "easy", max_episode_steps=limit)
    obs, info = vec.reset(seed=SEED)
    np.testing.assert_array_equal(info["state"], states.reset(seed=SEED)[0])
    for i, env in enumerate(singles):
        assert_obs_equal(row(obs, i), env.reset(seed=SEED + i)[0])
    assert vec.observation_space.contains(obs)
    ends = 0
    for actions in held_actions("continuous", 40, seed=3):
        obs, _, terminated, truncated, info = vec.step(actions)
        ends += int((terminated | truncated).sum())
        state_obs, _, _, _, state_info = states.step(actions)
        np.testing.assert_array_equal(info["state"], state_obs)
        for i, env in enumerate(singles):
            o, _, term, trunc, _ = env.step(actions[i])
            if term or trunc:
                assert_obs_equal(row(info["final_obs"], i), o)
                np.testing.assert_array_equal(info["final_info"]["state"][i], state_info["final_obs"][i])
                o, _ = env.reset()
            assert_obs_equal(row(obs, i), o)
    assert ends >= N  # the 30-step limit ended the episodes on the way


# ------------------------------------------------------------------------------------ autoreset
def test_a_marble_over_a_hole_terminates_and_resets_in_the_same_step():
    vec = LabyrinthVectorEnv(N, "hard", action_type="discrete")
    starts = np.tile(vec.board.start, (N, 1))
    hole = vec.board.holes[4]
    starts[1] = hole
    obs, info = vec.reset(seed=0, options={"marble_xy": starts})
    assert info["over_hole"].tolist() == [False, True, False, False]
    obs, reward, terminated, truncated, info = vec.step(np.zeros(N, dtype=np.int64))
    assert terminated.tolist() == [False, True, False, False] and not truncated.any()
    assert reward[1] == 0.0 and info["_final_obs"].tolist() == [False, True, False, False]
    final = info["final_obs"][1]
    assert np.hypot(*(final[:2] - hole)) < 1e-3  # the last observation: the marble at the hole
    assert info["final_info"]["over_hole"][1] and not info["final_info"]["is_success"][1]
    # ... and the env already shows its next episode: the marble near the start, progress from 0.
    assert np.abs(obs[1, :2] - vec.board.start).max() <= vec.template.start_noise + 1e-4
    assert not info["over_hole"][1] and info["progress"][1] < 0.01
    np.testing.assert_array_equal(info["tilt"][1], [0.0, 0.0])


def test_the_time_limit_truncates_and_resets_in_the_same_step():
    vec = LabyrinthVectorEnv(N, "medium", max_episode_steps=5)
    single = gym.make(env_id("medium"), max_episode_steps=5)
    vec.reset(seed=SEED)
    single.reset(seed=SEED)
    actions = np.full((N, 2), 0.5, dtype=np.float32)
    for t in range(5):
        obs, _, terminated, truncated, info = vec.step(actions)
        expected, _, _, _, _ = single.step(actions[0])
        assert truncated.all() == (t == 4) and not terminated.any()
    assert info["_final_obs"].all()
    np.testing.assert_array_equal(info["final_obs"][0], expected)
    np.testing.assert_array_equal(obs[0], single.reset()[0])  # the next episode, from the same generator
    assert vec.step(actions)[3].sum() == 0  # the new episodes run on


def test_next_step_autoreset_resets_on_the_following_step():
    vec = LabyrinthVectorEnv(2, "hard", action_type="discrete", autoreset_mode="next_step")
    starts = np.array([vec.board.start, vec.board.holes[4]])
    vec.reset(seed=0, options={"marble_xy": starts})
    _, _, terminated, _, info = vec.step(np.zeros(2, dtype=np.int64))
    assert terminated.tolist() == [False, True] and "final_obs" not in info
    obs, reward, terminated, truncated, info = vec.step(np.zeros(2, dtype=np.int64))
    assert reward[1] == 0.0 and not terminated[1] and not truncated[1] and not info["over_hole"][1]
    assert np.abs(obs[1, :2] - vec.board.start).max() <= vec.template.start_noise + 1e-4


# ------------------------------------------------------------------------------------ seeds
def test_same_seed_same_trajectory_other_seed_another():
    def run(seed: int) -> tuple[np.ndarray, np.ndarray]:
        vec = LabyrinthVectorEnv(N, "easy", max_episode_steps=40)
        observations, rewards = [vec.reset(seed=seed)[0]], []
        for actions in held_actions("continuous", 60, seed=5):
            obs, reward, *_ = vec.step(actions)
            observations.append(obs)
            rewards.append(reward)
        return np.array(observations), np.array(rewards)

    (first, first_rewards), (again, again_rewards), (other, _) = run(3), run(3), run(4)
    np.testing.assert_array_equal(first, again)
    np.testing.assert_array_equal(first_rewards, again_rewards)
    assert not np.array_equal(first[0], other[0])  # other starts
    assert not np.array_equal(first[41], other[41])  # and other starts after the autoresets at step 40
    assert len({tuple(row) for row in first[0, :, :2]}) == N  # every board starts elsewhere


def test_the_rollout_collector_steps_it():
    """The learners' collector reads what it needs (max tilt, template, start tags, tilt, final
    observations at time limits) and books the truncated episodes."""
    from bimgame.learn.actor import RecurrentActor
    from bimgame.learn.nets import NetConfig, RecurrentActorCritic
    from bimgame.learn.rollout import RolloutCollector

    torch.manual_seed(0)
    vec = LabyrinthVectorEnv(3, "easy", max_episode_steps=6)
    config = NetConfig(encoder="mlp", obs_shape=(17,), features=16, hidden=16, action_type="continuous")
    actor = RecurrentActor(RecurrentActorCritic(config), 3, generator=torch.Generator().manual_seed(0))
    episodes: list = []
    collector = RolloutCollector(vec, vec, actor, gamma=0.9, on_episode=episodes.append)
    collector.reset(0, 0)
    segment = collector.collect(13, 0)
    assert segment.obs.shape == (14, 3, 17) and segment.tilt is not None
    assert float(segment.tilt.abs().max()) <= 1.0 and float(segment.tilt.abs().max()) > 0
    assert len(episodes) == 6 and all(e.length == 6 for e in episodes)


# ------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    ("kwargs", "named"),
    [
        ({"num_envs": 0}, "num_envs"),
        ({"num_envs": 2.5}, "num_envs"),
        ({"layout": "impossible"}, "layout"),
        ({"obs_mode": "rgb"}, "obs_mode"),
        ({"action_type": "torque"}, "action_type"),
        ({"control_hz": 40}, "control_hz"),
        ({"autoreset_mode": "disabled"}, "autoreset_mode"),
        ({"autoreset_mode": AutoresetMode.DISABLED}, "autoreset_mode"),
        ({"nthread": 0}, "nthread"),
        ({"max_episode_steps": 0}, "max_episode_steps"),
        ({"state_info": "yes"}, "state_info"),
        ({"start_noise": 0.1}, "start_noise"),
    ],
)
def test_bad_arguments_are_refused_by_name(kwargs, named):
    args = {"num_envs": 2, **kwargs}
    with pytest.raises(ValueError, match=named):
        LabyrinthVectorEnv(**args)


def test_allowed_values_are_named():
    with pytest.raises(ValueError, match="easy, medium, hard"):
        LabyrinthVectorEnv(2, "impossible")
    with pytest.raises(ValueError, match="state, pixels, cyberrunner"):
        LabyrinthVectorEnv(2, obs_mode="rgb")
    with pytest.raises(ValueError, match=r"next_step.*same_step"):
        LabyrinthVectorEnv(2, autoreset_mode="disabled")


@pytest.mark.parametrize(
    ("action_type", "actions"),
    [
        ("continuous", np.zeros((3, 2))),
        ("continuous", np.zeros(2)),
        ("continuous", np.full((2, 2), 1.5)),
        ("continuous", np.array([[0.0, np.nan], [0.0, 0.0]])),
        ("continuous", [["a", "b"], ["c", "d"]]),
        ("discrete", np.array([0, 5])),
        ("discrete", np.array([0.0, 1.0])),
        ("discrete", np.array([True, False])),
        ("discrete", np.array([0, 1, 2])),
    ],
)
def test_bad_actions_are_refused(action_type, actions):
    vec = LabyrinthVectorEnv(2, "easy", action_type=action_type)
    vec.reset(seed=0)
    with pytest.raises(ValueError, match="invalid actions"):
        vec.step(actions)


def test_step_before_reset_and_bad_reset_options():
    vec = LabyrinthVectorEnv(2, "easy")
    with pytest.raises(RuntimeError, match="reset"):
        vec.step(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="seed list"):
        vec.reset(seed=[1, 2, 3])
    with pytest.raises(ValueError, match="marble_xy"):
        vec.reset(options={"marble_xy": np.zeros(2)})
    with pytest.raises(ValueError, match=r"options\['marble_xy'\]\[1\]"):
        vec.reset(options={"marble_xy": [vec.board.start, (0.2, 0.2)]})  # outside the board
    with pytest.raises(ValueError, match="at most one of"):
        vec.reset(options={"tilt": 0})


def test_what_the_collector_reads():
    vec = LabyrinthVectorEnv(3, "medium", action_type="discrete")
    assert vec.maze.max_tilt == pytest.approx(np.radians(10.0))
    assert vec.template.action_type == "discrete" and vec.start_tags.tolist() == [0, 0, 0]
    assert vec.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert vec.single_action_space == gym.spaces.Discrete(5) and vec.action_space.shape == (3,)
    assert vec.observation_space.shape == (3, 17)
    assert vec.max_episode_steps == 3000
    assert LabyrinthVectorEnv(1, control_hz=30).max_episode_steps == 1636


def test_reaching_the_goal_pays_the_bonus_and_terminates_with_success():
    vec = LabyrinthVectorEnv(2, "easy", action_type="discrete")
    single = gym.make(env_id("easy"), action_type="discrete")
    goal = np.array(vec.board.waypoints[-1])
    starts = np.array([goal, vec.board.start])
    vec.reset(seed=0, options={"marble_xy": starts})
    single.reset(seed=0, options={"marble_xy": goal})
    _, reward, terminated, _, info = vec.step(np.zeros(2, dtype=np.int64))
    _, expected, term, _, expected_info = single.step(0)
    assert terminated.tolist() == [True, False] and term and expected_info["is_success"]
    assert reward[0] == expected and reward[0] > vec.template.goal_bonus - 0.01  # + a tiny progress
    assert info["final_info"]["is_success"].tolist() == [True, False] and not info["is_success"][0]


def test_render_draws_every_board():
    vec = LabyrinthVectorEnv(2, "easy", render_mode="rgb_array", render_size=32)
    vec.reset(seed=0)
    frames = vec.render()
    assert len(frames) == 2 and all(f.shape == (32, 32, 3) and f.dtype == np.uint8 for f in frames)
    assert not np.array_equal(frames[0], frames[1])  # the marbles start at different places
