"""The start curricula: Backplay from demonstrations and the reverse curriculum from the goal."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.expert.datasets import generate_dataset, load_dataset
from bimgame.learn.starts import TRUE_START, DemoStartCurriculum, ReverseCurriculum
from bimgame.sim.maze import MazeSpec
from bimgame.sim.physics import MazeSim

SPEC = MazeSpec.merl()


def _demo(before_goal: int, after_goal: int = 3, angle_deg: float = 20.0):
    """A synthetic STG1 demonstration: ``before_goal`` states in channel 4, then ``after_goal`` in
    channel 3 (STG1's goal). Each state's time is its step index, so a state tells where it came from."""
    sim = MazeSim(SPEC)
    states, channels = [], []
    for t in range(before_goal + after_goal):
        channel = 4 if t < before_goal else 3
        angle = math.radians(angle_deg + 0.2 * t)
        radius = SPEC.channel_centre_radius(channel)
        sim.reset(np.array([[radius * math.cos(angle), radius * math.sin(angle)]]))
        state = sim.get_state()
        state[0] = t
        states.append(state)
        channels.append([channel])
    sim.close()
    return np.array(states), np.array(channels)


def _draws(curriculum, rng, n: int = 400):
    return [curriculum(0, rng) for _ in range(n)]


# ------------------------------------------------------------------ DemoStartCurriculum
def test_demo_starts_are_the_stored_states_at_most_d_steps_before_the_goal():
    demos = [_demo(100), _demo(4, angle_deg=60.0)]
    curriculum = DemoStartCurriculum(demos, "STG1", first_back=7, true_share=0.0)
    assert curriculum.demos == 2 and [curriculum.goal_step(i) for i in range(2)] == [100, 4]
    assert curriculum.backs == [7, 14, 28, 56, 112]
    seen = {0: set(), 1: set()}
    for state, tag in _draws(curriculum, np.random.default_rng(0)):
        assert tag == 0
        t = int(state[0])
        demo = 0 if np.array_equal(state, demos[0][0][t]) else 1
        assert np.array_equal(state, demos[demo][0][t])  # exactly the stored state
        seen[demo].add(curriculum.goal_step(demo) - t)
    assert seen[0] == set(range(1, 8))  # d uniform in 1..D_0
    assert seen[1] == {1, 2, 3, 4}  # clipped to t_goal: d = t_goal is the demonstration's first state


def test_demo_stage_moves_once_a_full_window_succeeds_at_the_threshold():
    curriculum = DemoStartCurriculum([_demo(100)], "STG1", first_back=30, window=10, threshold=0.8)
    for success in [False, False, False] + [True] * 7:  # a full window at 7/10
        curriculum.record(0, success)
    assert curriculum.stage == 0
    for _ in range(30):  # other stages' and true starts' episodes do not count
        curriculum.record(TRUE_START, True)
        curriculum.record(1, True)
    assert curriculum.stage == 0
    curriculum.record(0, True)  # the last 10: 8/10
    assert curriculum.stage == 1 and curriculum.status()["curriculum_steps_back"] == 60.0
    assert curriculum.status()["curriculum_window_success"] == 0.0  # the window starts afresh
    for _ in range(9):
        curriculum.record(1, True)
    assert curriculum.stage == 1  # the window is not full yet
    curriculum.record(1, True)
    assert curriculum.stage == 2


def test_demo_final_stage_gives_only_true_starts():
    curriculum = DemoStartCurriculum([_demo(100)], "STG1", first_back=30, growth=2.0, window=2, true_share=0.0)
    assert curriculum.backs == [30, 60, 120]
    for stage in range(3):
        assert not curriculum.finished
        curriculum.record(stage, True)
        curriculum.record(stage, True)
    assert curriculum.finished and curriculum.stage == 3
    assert all(draw == (None, TRUE_START) for draw in _draws(curriculum, np.random.default_rng(0), 50))
    status = curriculum.status()
    assert status["true_start_share"] == 1.0 and status["curriculum_stage"] == 3.0
    curriculum.record(3, False)  # ignored
    assert curriculum.finished


def test_demo_true_share_and_determinism():
    curriculum = DemoStartCurriculum([_demo(50), _demo(30)], "STG1", true_share=0.25)
    a = _draws(curriculum, np.random.default_rng(5))
    b = _draws(curriculum, np.random.default_rng(5))
    assert all(ta == tb and (sa is sb is None or np.array_equal(sa, sb)) for (sa, ta), (sb, tb) in zip(a, b))
    true = sum(state is None for state, _ in a)
    assert all(tag == TRUE_START for state, tag in a if state is None)
    assert 60 < true < 140  # about a quarter of 400


def test_demo_settings_and_episodes_are_checked():
    demos = [_demo(10)]
    for name, value, allowed in [("first_back", 0, "integer >= 1"), ("first_back", 2.5, "integer >= 1"),
                                 ("growth", 1.0, "> 1"), ("threshold", 0.0, r"\(0, 1\]"),
                                 ("threshold", 1.5, r"\(0, 1\]"), ("window", 0, "integer >= 1"),
                                 ("true_share", -0.1, r"\[0, 1\]")]:
        with pytest.raises(ValueError, match=rf"DemoStartCurriculum\.{name} must be .*{allowed}.*got {value!r}"):
            DemoStartCurriculum(demos, "STG1", **{name: value})
    with pytest.raises(ValueError, match=r"none of the 1 episodes of the given episodes reaches the goal of task "
                                         r"STG2 \(every marble in channel <= 2\)"):
        DemoStartCurriculum(demos, "STG2")
    states, channels = _demo(10)
    with pytest.raises(ValueError, match="episode 0 must give sim_states"):
        DemoStartCurriculum([(states, channels[:-1])], "STG1")
    with pytest.raises(ValueError, match=r"episode 0's sim_states must be finite .* of length"):
        DemoStartCurriculum([(states[:, :-1], channels)], "STG1")


def test_demo_goal_is_cut_where_the_position_already_counts_as_reached():
    """In a gate past the wall's mid-line the env counts a start as at the goal: such a state is
    never a start, even while the recorded channel (with hysteresis) is still outside."""
    states, channels = _demo(10)
    sim = MazeSim(SPEC)
    radius, angle = SPEC.walls[3].mid_radius - 1e-3, math.radians(45.0)
    sim.reset(np.array([[radius * math.cos(angle), radius * math.sin(angle)]]))
    states[8] = sim.get_state()  # in wall 3's gate at 45°, inside its mid-line; recorded channel 4
    curriculum = DemoStartCurriculum([(states, channels)], "STG1")
    assert curriculum.goal_step(0) == 8


@pytest.fixture(scope="module")
def tiny_stg1_dataset(tmp_path_factory):
    """Two STG1 expert episodes (about a second of planning)."""
    return generate_dataset(tmp_path_factory.mktemp("stg1") / "data", task="STG1", episodes=2, seed=0,
                            workers=1, progress=False)


def test_demo_from_dataset_starts_before_the_goal(tiny_stg1_dataset):
    curriculum = DemoStartCurriculum.from_dataset(tiny_stg1_dataset, "STG1", first_back=200, true_share=0.0)
    episodes = list(load_dataset(tiny_stg1_dataset).iterate_episodes())
    assert curriculum.demos == 2
    env = BallInMazeEnv("STG1", obs_mode="state")
    for state, tag in _draws(curriculum, np.random.default_rng(0), 30):
        assert tag == 0
        assert any((np.asarray(e.infos["sim_state"]) == state).all(axis=1).any() for e in episodes)
        _, info = env.reset(options={"sim_state": state})
        assert info["channel"].tolist() == [4] and not info["is_success"]  # before STG1's goal (channel 3)
    # A dataset state replays the expert's episode exactly from there.
    episode = episodes[0]
    states = np.asarray(episode.infos["sim_state"])
    env.reset(options={"sim_state": states[5]})
    for t, action in enumerate(episode.actions[5:], start=6):
        env.step(int(action))
        assert np.array_equal(env.sim.get_state(), states[t])
    with pytest.raises(ValueError, match=r"the dataset in .*data reaches the goal of task FULL"):
        DemoStartCurriculum.from_dataset(tiny_stg1_dataset, "FULL")


# ------------------------------------------------------------------ ReverseCurriculum
@pytest.mark.parametrize("task", ["FULL", "STG1", "STG2"])
def test_reverse_seeds_rest_just_outside_the_goal_at_each_gate(task):
    curriculum = ReverseCurriculum(task)
    goal = curriculum.goal
    gates = SPEC.walls[goal].gates
    assert curriculum.seeds == list(range(len(gates))) and curriculum.active == curriculum.seeds
    env = BallInMazeEnv(task, obs_mode="state")
    for tag, gate in zip(curriculum.seeds, gates):
        obs, info = env.reset(options={"sim_state": curriculum.state(tag)})
        x, y, vx, vy, tilt_x, tilt_y = obs[:6]
        assert info["channel"].tolist() == [goal + 1]
        radius = SPEC.channel_centre_radius(goal + 1)
        assert (x, y) == pytest.approx((radius * math.cos(gate.angle), radius * math.sin(gate.angle)), abs=1e-6)
        assert vx == vy == tilt_x == tilt_y == 0.0
        _, reward, terminated, _, _ = env.step(0)
        assert not terminated and reward == 0.0


def test_reverse_expansion_gives_valid_states_before_the_goal():
    curriculum = ReverseCurriculum("FULL", walk_steps=20)
    env = BallInMazeEnv("FULL", obs_mode="state")
    rng = np.random.default_rng(0)
    new = curriculum.expand([curriculum.state(0)], 50, rng)
    assert len(new) == 50
    for state, xy in new:
        _, info = env.reset(options={"sim_state": state})
        assert info["channel"].tolist() == [1]
        assert np.array_equal(xy, env.sim.layout.board_frame(state)[0][:, :2])
    # Rolling inwards through wall 0's gate (180°), walks reach the goal within two steps: every
    # later state is left out, only the first ones (still outside) remain.
    sim = MazeSim(SPEC)
    for radius, expected in [(SPEC.walls[0].outer_radius + SPEC.marble_radius + 1e-3, 50),
                             (SPEC.walls[0].mid_radius + 1e-3, 0)]:
        sim.reset(np.array([[-radius, 0.0]]))
        rolling = sim.get_state()
        rolling[sim.layout.marble_vel[0][0]] = 0.3  # towards +x: into the centre
        new = curriculum.expand([rolling], 50, rng)
        assert len(new) == expected
        for state, xy in new:
            _, info = env.reset(options={"sim_state": state})
            assert info["channel"].tolist() == [1] and np.hypot(*xy[0]) > SPEC.walls[0].outer_radius - 1e-3


def _issue_and_record(curriculum, rng, results: dict[int, list[bool]]):
    """Hand out starts until every listed one got its results recorded (true starts recorded too)."""
    pending = {tag: list(r) for tag, r in results.items()}
    while any(pending.values()):
        _, tag = curriculum(0, rng)
        if tag == TRUE_START:
            curriculum.record(tag, False)
        elif pending.get(tag):
            curriculum.record(tag, pending[tag].pop(0))


def test_reverse_pool_keeps_good_starts_replays_mastered_and_drops_too_hard():
    curriculum = ReverseCurriculum("STG2", pool_size=5, min_tries=3, walk_steps=10)
    rng = np.random.default_rng(1)
    handed_out = []
    while len(handed_out) < 12:  # each seed is handed out min_tries times before any again
        tag = curriculum(0, rng)[1]
        handed_out += [] if tag == TRUE_START else [tag]
    assert sorted(handed_out) == [0, 0, 0, 1, 1, 1, 2, 2, 2, 3, 3, 3]
    _issue_and_record(curriculum, rng, {0: [True] * 3, 1: [False] * 3, 2: [True, False, False],
                                        3: [True, True, False]})
    assert curriculum.rebuilds == 0
    curriculum(0, rng)  # every active start has its tries: this call rebuilds the pool
    assert curriculum.rebuilds == 1
    assert curriculum.mastered == [0]  # 3/3 > high
    assert curriculum.active[:2] == [2, 3] and len(curriculum.active) == 7  # the good ones + 5 new
    assert 1 not in curriculum.active  # 0/3 < low: dropped
    assert curriculum.tries[2] == curriculum.tries[3] == 0  # evaluated afresh
    status = curriculum.status()
    assert status["curriculum_mastered"] == 1.0 and status["curriculum_good"] == 2.0
    assert status["curriculum_pool"] == 7.0 and status["curriculum_start_distance"] > 0
    replaying = ReverseCurriculum("STG2", true_share=0.0, replay_share=1.0)
    replaying.mastered = [2]
    draws = _draws(replaying, rng, 20)
    assert all(tag == 2 and np.array_equal(state, replaying.state(2)) for state, tag in draws)


def test_reverse_is_deterministic_and_its_samples_start_vector_envs():
    runs = []
    for _ in range(2):
        curriculum = ReverseCurriculum("STG1", pool_size=8, min_tries=1, walk_steps=5)
        env = BallInMazeVectorEnv(4, task="STG1", obs_mode="state", max_episode_steps=4,
                                  autoreset_mode=AutoresetMode.SAME_STEP, start_sampler=curriculum)
        obs, _ = env.reset(seed=3)
        record = [obs]
        for step in range(12):
            tags = env.start_tags.copy()  # read before the step that may end the episodes
            obs, _, terminated, truncated, _ = env.step(np.full(4, step % 5))
            for tag, done, success in zip(tags, terminated | truncated, terminated):
                if done:
                    curriculum.record(int(tag), bool(success))
            record += [obs, env.start_tags.copy()]
        runs.append(record)
        assert curriculum.rebuilds >= 1
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


def test_reverse_settings_and_tags_are_checked():
    for name, value in [("walk_steps", 0), ("pool_size", 1.5), ("min_tries", 0), ("low", -0.5), ("high", 2.0),
                        ("true_share", 1.5), ("replay_share", -1.0)]:
        with pytest.raises(ValueError, match=rf"ReverseCurriculum\.{name} must be .*got {value!r}"):
            ReverseCurriculum("FULL", **{name: value})
    with pytest.raises(ValueError, match="low .* must not exceed"):
        ReverseCurriculum("FULL", low=0.8, high=0.5)
    with pytest.raises(ValueError, match="true_share \\+ replay_share must be at most 1"):
        ReverseCurriculum("FULL", true_share=0.6, replay_share=0.6)
    curriculum = ReverseCurriculum("FULL")
    with pytest.raises(ValueError, match=r"unknown start tag 7; .* 0\.\.0"):
        curriculum.record(7, True)
    with pytest.raises(ValueError, match="tag must be an integer"):
        curriculum.record(0.5, True)


def test_curricula_pickle_to_worker_processes_and_continue_identically():
    for curriculum in (DemoStartCurriculum([_demo(40)], "STG1", window=3),
                       ReverseCurriculum("STG1", pool_size=4, min_tries=1, walk_steps=5)):
        for tag in (0, 1, 2, 3):
            curriculum.record(tag, tag % 2 == 0)
        clone = pickle.loads(pickle.dumps(curriculum))
        a = _draws(curriculum, np.random.default_rng(2), 30)
        b = _draws(clone, np.random.default_rng(2), 30)
        assert [t for _, t in a] == [t for _, t in b]
        assert all(x is y is None or np.array_equal(x, y) for (x, _), (y, _) in zip(a, b))
        assert clone.status() == curriculum.status()
