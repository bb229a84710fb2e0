"""The benchmark protocol on numbered random mazes (``--mazes``): which maze each episode is on, the
built-in policies planning in it, the observations each kind of policy gets, and the normalisation's
references on mazes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.mazes import maze_encoding
from bimgame.experiments import protocol as protocol_module
from bimgame.experiments.policy_sources import CallablePolicy, builtin_policy, load_policy
from bimgame.experiments.protocol import (
    MAZE_FORMS,
    PROTOCOL_SEED,
    MazeChoice,
    Protocol,
    _builtin_score,
    measure_references,
    run_protocol,
)
from bimgame.expert.policies import ExpertPolicy, GeodesicPolicy
from bimgame.learn.checkpoints import save_checkpoint
from bimgame.learn.common import NetworkSettings
from bimgame.learn.runs import CHECKPOINT
from bimgame.sim.maze_sets import maze_number
from bimgame.util.seeding import episode_seed


class Recording:
    """Acts like ``policy`` and records, at each episode's first step, the maze the env shows, its
    number in ``info`` and the observation."""

    def __init__(self, policy):
        self.policy = policy
        self.mazes, self.numbers, self.first_obs = [], [], []

    def reset(self, seed):
        self.policy.reset(seed)
        self.fresh = True

    def act(self, env, obs, info):
        if self.fresh:
            self.mazes.append(env.unwrapped.maze)
            self.numbers.append(info["maze"])
            self.first_obs.append(np.array(obs))
            self.fresh = False
        return self.policy.act(env, obs, info)

    def observe(self, reward):
        self.policy.observe(reward)


def _manual_episodes(protocol: Protocol, make_policy) -> list[list[int]]:
    """Each episode's actions, played outside the protocol's code: an env of the set, reset with the
    episode's seed and maze, ``make_policy(maze, seed)`` acting on it."""
    env = BallInMazeEnv(protocol.task, obs_mode="state", **protocol.maze_choice.env_kwargs(protocol.episodes))
    out = []
    for k, (seed, number) in enumerate(zip(protocol.start_seeds(), protocol.maze_numbers(), strict=True)):
        assert seed == episode_seed(PROTOCOL_SEED, k)
        env.reset(seed=seed, options={"maze": number})
        policy, actions = make_policy(maze_number(number, protocol.maze_choice.split), seed), []
        for _ in range(protocol.time_limit):
            actions.append(policy(env))
            if env.step(actions[-1])[2]:
                break
        out.append(actions)
    env.close()
    return out


@pytest.fixture
def env_actions(monkeypatch):
    """Every action any env is stepped with, in order (the protocol's own policies stay unwrapped)."""
    actions = []
    step = BallInMazeEnv.step

    def recording(env, action):
        actions.append(int(action))
        return step(env, action)

    monkeypatch.setattr(BallInMazeEnv, "step", recording)
    return actions


def test_maze_choices_parse_to_episode_mazes_and_bad_ones_name_the_allowed_forms():
    assert str(MazeChoice.parse("merl")) == "merl" and MazeChoice.parse("merl").numbers(5) is None
    assert MazeChoice.parse(" Test ").numbers(4) == [0, 1, 2, 3]
    assert MazeChoice.parse("test:4").numbers(4) == [0, 1, 2, 3]  # test is test:E
    assert MazeChoice.parse("train:3").numbers(7) == [0, 0, 0, 1, 1, 2, 2]  # spread evenly, in blocks
    assert MazeChoice.parse("test:100").numbers(4) == [0, 25, 50, 75]  # more mazes than episodes: spaced out
    assert MazeChoice.parse("train:5:3").numbers(3) == [5, 6, 7]
    assert str(MazeChoice.parse("train:0:3")) == "train:3" and str(MazeChoice.parse("test:2:4")) == "test:2:4"
    assert MazeChoice.parse("train:5:3").env_kwargs(9) == {"num_mazes": 3, "start_maze": 5, "maze_split": "train"}
    assert MazeChoice.parse("test").describe(100) == "held-out test mazes 0..99"
    assert Protocol(mazes="TEST:0:3").mazes == "test:3"
    for bad, says in [
        ("mars", "unknown form"),
        ("train", r"train needs its number of mazes \(train:N\)"),
        ("test:0", "N .* must be >= 1"),
        ("train:x", "must be non-negative integers"),
        ("test:-1:2", "integers"),
        ("train:1:2:3", "unknown form"),
        ("merl:3", "unknown form"),
        ("train:2147483647:2", "up to"),
    ]:
        with pytest.raises(ValueError, match=says) as error:
            MazeChoice.parse(bad)
        if "up to" not in says:
            assert MAZE_FORMS in str(error.value)
    with pytest.raises(ValueError, match=r"Protocol\.mazes 'mars'.*train:START:N"):
        Protocol(mazes="mars")


def test_test_mazes_put_episode_k_on_held_out_test_maze_k():
    protocol = Protocol(task="STG1", episodes=4, mazes="test")
    recording = Recording(builtin_policy("random"))
    first = run_protocol(recording, protocol)
    assert recording.numbers == [0, 1, 2, 3]
    assert recording.mazes == [maze_number(k, "test") for k in range(4)]
    assert len({m.walls for m in recording.mazes}) == 4  # four different mazes
    # Starts from the protocol's seeds: the same first observation as a plain reset on that maze.
    for k, obs in enumerate(recording.first_obs):
        env = BallInMazeEnv("STG1", obs_mode="state", maze=maze_number(k, "test"))
        np.testing.assert_array_equal(obs[:7], env.reset(seed=episode_seed(PROTOCOL_SEED, k))[0])
        np.testing.assert_array_equal(obs[7:], maze_encoding(maze_number(k, "test")))  # a callable sees it
    again = run_protocol(builtin_policy("random"), protocol)
    assert (first.returns, first.lengths) == (again.returns, again.lengths)
    summary = first.summary()
    assert (summary["mazes"], summary["maze_split"], summary["maze_set"]) == (
        "test",
        "test",
        "held-out test mazes 0..3",
    )


def test_train_n_stays_within_the_n_training_mazes():
    recording = Recording(builtin_policy("noop"))
    run_protocol(recording, Protocol(task="STG1", episodes=7, mazes="train:3"))
    assert sorted(set(recording.numbers)) == [0, 1, 2]
    assert recording.mazes == [maze_number(n, "train") for n in recording.numbers]
    recording = Recording(builtin_policy("noop"))
    run_protocol(recording, Protocol(task="STG1", episodes=4, mazes="train:10:2"))
    assert recording.numbers == [10, 10, 11, 11]


def test_the_geodesic_controller_follows_the_episode_maze(env_actions):
    protocol = Protocol(task="STG1", episodes=3, mazes="test")
    run_protocol(builtin_policy("geodesic"), protocol)
    scored = list(env_actions)
    manual = _manual_episodes(protocol, lambda maze, seed: GeodesicPolicy(maze))
    assert scored == [a for episode in manual for a in episode]
    elsewhere = _manual_episodes(protocol, lambda maze, seed: GeodesicPolicy(maze_number(0, "train")))
    assert elsewhere != manual  # another maze's distances steer elsewhere: the comparison can tell


def test_the_expert_plans_in_the_episode_maze_and_its_references_are_its_protocol_episodes(env_actions):
    protocol = Protocol(task="STG1", episodes=1, mazes="test")
    result = run_protocol(builtin_policy("expert"), protocol)
    scored = list(env_actions)
    assert [scored] == _manual_episodes(protocol, lambda maze, seed: ExpertPolicy(maze, np.random.default_rng(seed)))
    assert result.successes == [True] and result.lengths == [len(scored)]
    env_actions.clear()
    measured = measure_references(["STG1"], episodes=1, workers=1, progress=False, mazes="test")
    assert env_actions[-len(scored) :] == scored  # the reference's expert episode is the protocol's
    assert measured["mazes"] == "test" and measured["episodes"] == 1
    entry = measured["tasks"]["STG1"]
    assert entry["expert"] == result.returns[0] and entry["expert_success_rate"] == 1.0
    assert entry["random"] == run_protocol(builtin_policy("random"), protocol).returns[0]


def test_episodes_on_worker_processes_are_the_protocol_episodes():
    protocol = Protocol(task="STG1", episodes=2, mazes="test:7:2")
    parallel = _builtin_score(protocol, "geodesic", workers=2, progress=False)
    in_process = run_protocol(builtin_policy("geodesic"), protocol)
    assert (parallel.returns, parallel.lengths) == (in_process.returns, in_process.lengths)


def test_maze_references_normalise_scores_on_either_split(monkeypatch):
    unpatched = run_protocol(builtin_policy("random"), Protocol(task="STG1", episodes=3, mazes="train:2")).summary()
    stored = protocol_module.maze_references("STG1")
    assert (unpatched["normalised_score"] is None) == (stored is None) == (unpatched["references"] is None)
    monkeypatch.setattr(protocol_module, "maze_references", lambda task, key="test": (0.1, 0.9))
    for mazes in ("train:2", "test"):
        summary = run_protocol(builtin_policy("random"), Protocol(task="STG1", episodes=3, mazes=mazes)).summary()
        assert summary["references"] == "test"
        assert summary["normalised_score"] == pytest.approx(100 * (summary["mean_return"] - 0.1) / 0.8)
        low, high = summary["normalised_score_ci"]
        assert low <= summary["normalised_score"] <= high
    merl = run_protocol(builtin_policy("random"), Protocol(task="STG1", episodes=3)).summary()
    assert merl["references"] == "merl" and merl["maze_split"] == "merl"  # MERL's own references


def test_the_stored_references_keep_merl_at_the_top_and_test_mazes_apart():
    from importlib.resources import files

    stored = json.loads(files("bimgame.expert").joinpath("reference_scores.json").read_text())
    assert stored["tasks"]["STG1"] == {
        "expert": 1.0,
        "expert_success_rate": 1.0,
        "random": 0.16,
        "random_success_rate": 0.16,
    }
    for task, entry in stored.get("mazes", {}).get("test", {}).get("tasks", {}).items():
        assert protocol_module.maze_references(task) == (entry["random"], entry["expert"])
        assert entry["expert"] > entry["random"], task


def _merl_network_run(tmp_path):
    """A run directory of an untrained state network of MERL's maze (no maze encoding)."""
    network = NetworkSettings(obs="state", hidden=8, features=8)
    run_dir = tmp_path / "merl-run"
    run_dir.mkdir()
    (run_dir / "config.json").write_text(
        json.dumps({"kind": "pretrained-policy", "task": "STG1", "seed": 0, "network": network.to_dict()})
    )
    save_checkpoint(run_dir / CHECKPOINT, model=network.build_policy(0).state_dict(), step=0)
    return run_dir


def test_a_network_of_merls_maze_gets_maze_observations_without_the_encoding(tmp_path):
    run_dir = _merl_network_run(tmp_path)
    protocol = Protocol(task="STG1", episodes=2, mazes="test")
    scored = run_protocol(load_policy(str(run_dir), obs="state"), protocol)
    assert scored.summary()["notes"] == [
        "the network was trained on MERL's maze (no maze encoding): its observations leave the encoding out"
    ]
    # It acts as the same network does on the observations cut to the marble's and the board's state.
    network = load_policy(str(run_dir), obs="state")
    cut = run_protocol(_Cut(network), protocol)
    assert (cut.returns, cut.lengths) == (scored.returns, scored.lengths)


class _Cut:
    """A policy given only the first 7 values of each observation (what the protocol should do)."""

    def __init__(self, policy):
        self.policy = policy

    def reset(self, seed):
        self.policy.reset(seed)

    def act(self, env, obs, info):
        return self.policy.act(env, obs[:7], info)

    def observe(self, reward):
        self.policy.observe(reward)


def test_callables_get_the_maze_encoding():
    seen = []
    policy = CallablePolicy(lambda obs: seen.append(np.array(obs)) or 0)
    run_protocol(policy, Protocol(task="STG1", episodes=2, mazes="test:5:2"))
    assert {len(obs) for obs in seen} == {7 + 128}
    np.testing.assert_array_equal(seen[0][7:], maze_encoding(maze_number(5, "test")))
    np.testing.assert_array_equal(seen[-1][7:], maze_encoding(maze_number(6, "test")))
