"""DAgger on random mazes (``DAggerConfig.num_mazes``): the settings a many-maze run takes, an expert that
plans on each episode's own maze, a run whose network reads the maze encoding and scores on held-out
mazes, and the mismatches refused by name."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bimgame.cli.main import main
from bimgame.envs.mazes import maze_encoding, maze_encoding_size
from bimgame.expert.mpc import MPCConfig
from bimgame.learn import runs
from bimgame.learn.dagger import DAggerConfig, collect_episodes, dagger
from bimgame.learn.dagger import rollouts as dagger_rollouts
from bimgame.learn.supervised import PretrainConfig
from bimgame.sim.maze import MazeSpec

STATE = PretrainConfig(task="STG1", obs="state", hidden=16, features=16, aux_heads=False, asymmetric_critic=False)
CHEAP = MPCConfig(n_samples=4, horizon=8, reward="geodesic")


def test_a_many_maze_run_reads_the_encoding_and_its_expert_plans_geodesically():
    config = DAggerConfig(learner=STATE, num_mazes=0)
    assert config.learner.maze_encoding and config.expert == MPCConfig(reward="geodesic")
    assert config.maze_options == {"num_mazes": 0, "start_maze": 0}
    assert DAggerConfig.from_dict(config.to_dict()) == config
    assert DAggerConfig(learner=STATE).expert == MPCConfig()  # MERL's maze keeps the default expert
    assert DAggerConfig(learner=STATE).maze_options == {}


@pytest.mark.parametrize("settings, message", [
    (dict(start_maze=3), "DAggerConfig.start_maze 3 needs num_mazes"),
    (dict(num_mazes=-1), "num_mazes"),
    (dict(learner=PretrainConfig(task="STG1", obs="state", aux_heads=False, asymmetric_critic=False,
                                 maze_encoding=True)), "maze_encoding without num_mazes"),
    (dict(learner=PretrainConfig(task="LABYRINTH-EASY", obs="state", aux_heads=False, asymmetric_critic=False),
          num_mazes=10), "DAggerConfig.num_mazes applies to the circular maze's tasks only"),
])
def test_maze_settings_dagger_cannot_run_with_are_refused_by_name(settings, message):
    with pytest.raises(ValueError, match=message):
        DAggerConfig(**{"learner": STATE, **settings})


def test_each_expert_plans_on_its_episodes_maze(monkeypatch):
    planned: list[tuple[MazeSpec, object]] = []
    make = dagger_rollouts.make_expert

    def recording(env, config, rng, task):
        planned.append((env.maze, env))
        return make(env, config, rng, task)

    monkeypatch.setattr(dagger_rollouts, "make_expert", recording)
    config = DAggerConfig(learner=STATE, num_mazes=0, episodes_per_iteration=3, max_episode_steps=5, expert=CHEAP)
    net = config.learner.build_policy(0, MazeSpec.merl())
    with runs.torch_threads(1):
        episodes, _ = collect_episodes(net, config, beta=1.0, seed=4)
    # Each expert was made after its env's reset, on the maze the episode then ran on (reset picks it).
    assert len(planned) == 3 and len({id(spec) for spec, _ in planned}) == 3
    assert all(spec != MazeSpec.merl() for spec, _ in planned)
    width = 7 + maze_encoding_size(MazeSpec.merl())
    for (spec, env), episode in zip(planned, episodes, strict=True):
        assert env.maze is spec  # one episode per env: the maze never changed under its expert
        assert episode.obs.shape[1] == width
        np.testing.assert_array_equal(episode.obs[0, 7:], maze_encoding(spec))


def test_a_run_on_mazes_is_scored_on_held_out_mazes(tmp_path, capsys):
    config = DAggerConfig(learner=STATE, num_mazes=5, iterations=1, episodes_per_iteration=2, epochs_per_iteration=1,
                          max_episode_steps=20, eval_episodes=2, expert=CHEAP)
    with runs.torch_threads(1):
        result = dagger(config, tmp_path / "run", progress=False)
    assert result.iterations_run == 1
    stored = json.loads((tmp_path / "run" / "config.json").read_text())
    assert stored["num_mazes"] == 5 and stored["network"]["maze_encoding"] is True
    assert DAggerConfig.from_dict(stored["dagger"]) == config
    assert main(["score", str(tmp_path / "run"), "--mazes", "test", "--episodes", "2", "--out",
                 str(tmp_path / "score.json")]) == 0
    assert json.loads((tmp_path / "score.json").read_text())["maze_split"] == "test"


def test_demonstrations_from_merls_maze_are_refused_for_a_run_on_mazes(stg1_dataset, tmp_path):
    config = DAggerConfig(learner=STATE, num_mazes=5, iterations=1, episodes_per_iteration=2,
                          expert_data=str(stg1_dataset), expert=CHEAP)
    with runs.torch_threads(1), pytest.raises(ValueError, match="was generated on MERL's maze alone, the run rolls "
                                                                  "out on random mazes: use a dataset generated"):
        dagger(config, tmp_path / "run", progress=False)
