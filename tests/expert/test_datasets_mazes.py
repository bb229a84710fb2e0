"""Expert datasets on many random mazes (``generate_dataset(num_mazes=..., start_maze=...)``): episode j
on training maze start + (j mod N), played as an env with ``num_mazes`` plays it, with the expert
planning in that maze; the maze recorded per episode; resumes with other maze settings refused."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from bimgame.cli.main import main
from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.mazes import maze_encoding
from bimgame.expert.datasets import (
    DatasetError,
    dataset_mazes,
    dataset_summary,
    generate_dataset,
    iterate_sequences,
    load_dataset,
)
from bimgame.expert.minari_build import episode_bytes, episode_path, read_episode
from bimgame.expert.mpc import MPCConfig, RandomShootingMPC, run_expert_episode
from bimgame.sim.maze import MazeSpec
from bimgame.sim.maze_sets import maze_number
from bimgame.util.seeding import episode_seed

CONFIG = MPCConfig(n_samples=4, horizon=8)
ARGS = dict(task="STG1", episodes=5, seed=1, config=CONFIG, max_steps=40, progress=False, num_mazes=3, start_maze=4)
#: The maze of each episode: start_maze + (j mod num_mazes).
MAZES = [4, 5, 6, 4, 5]


@pytest.fixture(scope="module")
def on_mazes(tmp_path_factory):
    """A dataset of 5 STG1 episodes on training mazes 4, 5 and 6, generated in this process."""
    return generate_dataset(tmp_path_factory.mktemp("mazes") / "data", workers=1, **ARGS)


def _episodes(out):
    dataset = load_dataset(out)
    metadata = list(dataset.storage.get_episode_metadata(dataset.episode_indices))
    return dataset, list(zip(metadata, dataset.iterate_episodes(), strict=True))


def test_each_episode_is_played_on_its_maze_and_records_it(on_mazes):
    manifest = json.loads((on_mazes / "generation.json").read_text())
    assert (manifest["num_mazes"], manifest["start_maze"]) == (3, 4)
    assert dataset_mazes(on_mazes) == {"num_mazes": 3, "start_maze": 4}
    dataset, episodes = _episodes(on_mazes)
    assert len(episodes) == 5
    encodings = {}
    for index, ((meta, episode), number) in enumerate(zip(episodes, MAZES, strict=True)):
        steps = len(episode.actions)
        assert meta["seed"] == episode_seed(1, index) and meta["options"] == {"maze": number}
        assert episode.infos["maze"].shape == (steps + 1,) and set(episode.infos["maze"]) == {number}
        saved = read_episode(episode_path(on_mazes, index), index, episode_seed(1, index), number)
        assert int(saved["maze"]) == number
        # The observations end with the episode's maze encoding, at every step.
        assert episode.observations.shape == (steps + 1, 7 + 128)
        encoding = maze_encoding(maze_number(number, "train"))
        assert np.array_equal(episode.observations[:, 7:], np.broadcast_to(encoding, (steps + 1, 128)))
        encodings[number] = encoding.tobytes()
    assert len(set(encodings.values())) == 3  # three different mazes

    # The Minari dataset's environment is the one the episodes were played in: reset with an
    # episode's seed and options, it replays the episode step for step.
    env = dataset.recover_environment()
    assert env.spec.kwargs["num_mazes"] == 3 and env.spec.kwargs["start_maze"] == 4
    assert env.observation_space.shape == (135,)
    for meta, episode in episodes:
        obs, info = env.reset(seed=meta["seed"], options=meta["options"])
        assert info["maze"] == meta["options"]["maze"]
        observed, rewards = [obs], []
        for action in episode.actions:
            obs, reward, terminated, truncated, info = env.step(int(action))
            observed.append(obs)
            rewards.append(reward)
        assert np.array_equal(np.stack(observed), episode.observations)
        assert np.array_equal(rewards, episode.rewards)
        assert (terminated, truncated) == (bool(episode.terminations[-1]), bool(episode.truncations[-1]))
    env.close()


def test_the_expert_plans_in_the_episodes_maze(on_mazes):
    """Replaying the expert's planner on the recorded states gives the recorded actions when it plans
    in the episode's maze; one planning in MERL's maze chooses otherwise somewhere."""
    _, episodes = _episodes(on_mazes)
    differs_in_merl = False
    for (meta, episode), number in zip(episodes, MAZES, strict=True):
        states = episode.infos["sim_state"]
        planners = {
            name: RandomShootingMPC(spec, CONFIG, rng=np.random.default_rng(meta["seed"]), task="STG1")
            for name, spec in (("maze", maze_number(number, "train")), ("merl", MazeSpec.merl()))
        }
        chosen = {name: [planner.act(state) for state in states[:-1]] for name, planner in planners.items()}
        for planner in planners.values():
            planner.close()
        assert chosen["maze"] == list(episode.actions)
        differs_in_merl |= chosen["merl"] != list(episode.actions)
    assert differs_in_merl


def test_sequences_carry_the_encoding_and_pixels_show_the_episodes_maze(on_mazes):
    _, episodes = _episodes(on_mazes)
    states = list(iterate_sequences(on_mazes, obs="state"))
    pixels = list(iterate_sequences(on_mazes, obs="pixels"))
    for (meta, episode), state, frames in zip(episodes, states, pixels, strict=True):
        steps = len(episode.actions)
        assert state.obs.shape == (steps, 135) and np.array_equal(state.obs, episode.observations[:steps])
        # The privileged state is the marbles' and the board's, without the maze (as the vector env's).
        assert np.array_equal(state.state_obs, episode.observations[:steps, :7])
        np.testing.assert_array_equal(state.tilt, episode.observations[:steps, 4:6])
        assert np.array_equal(state.channels[:, 0], episode.infos["channel"][:, 0])
        env = BallInMazeEnv("STG1", obs_mode="pixels", num_mazes=3, start_maze=4)
        obs, _ = env.reset(seed=meta["seed"], options=meta["options"])
        expected = [obs]
        for action in episode.actions[:-1]:
            expected.append(env.step(int(action))[0])
        env.close()
        assert np.array_equal(frames.obs, np.stack(expected))
    # MERL's maze would look different: the re-rendered frames do show the mazes.
    merl = BallInMazeEnv("STG1", obs_mode="pixels")
    first, _ = merl.reset(seed=episodes[0][0]["seed"])
    merl.close()
    assert not np.array_equal(pixels[0].obs[0], first)


def test_same_dataset_whatever_the_workers_and_a_resume_regenerates_only_what_is_missing(on_mazes, tmp_path):
    copy = shutil.copytree(on_mazes, tmp_path / "copy")
    (copy / "COMPLETE").unlink()
    shutil.rmtree(copy / "minari")
    kept = {i: episode_path(copy, i).stat().st_mtime_ns for i in (0, 2, 3)}
    for index in (1, 4):
        episode_path(copy, index).unlink()
    generate_dataset(copy, workers=2, **ARGS)  # two worker processes, one episode each
    assert dataset_summary(copy)["content_sha256"] == dataset_summary(on_mazes)["content_sha256"]
    assert {i: episode_path(copy, i).stat().st_mtime_ns for i in kept} == kept
    for index in (1, 4):
        assert episode_path(copy, index).read_bytes() == episode_path(on_mazes, index).read_bytes()


def test_resuming_with_other_maze_settings_is_refused_by_name(on_mazes, tmp_path):
    before = {p: p.read_bytes() for p in on_mazes.rglob("*") if p.is_file() and p.name != ".lock"}
    for changes, expected in (
        (dict(num_mazes=2), "num_mazes: 3 there, 2 now"),
        (dict(start_maze=5), "start_maze: 4 there, 5 now"),
        (dict(num_mazes=None, start_maze=0), "num_mazes: 3 there, None now; start_maze: 4 there, None now"),
    ):
        with pytest.raises(ValueError, match=expected):
            generate_dataset(on_mazes, workers=1, **{**ARGS, **changes})
    assert {p: p.read_bytes() for p in before} == before

    # And a dataset of MERL's maze is not continued on mazes.
    merl = generate_dataset(
        tmp_path / "merl", workers=1, **{**ARGS, "episodes": 1, "max_steps": 3, "num_mazes": None, "start_maze": 0}
    )
    assert "num_mazes" not in json.loads((merl / "generation.json").read_text())
    with pytest.raises(ValueError, match="num_mazes: None there, 3 now; start_maze: None there, 4 now"):
        generate_dataset(merl, workers=1, **{**ARGS, "episodes": 1, "max_steps": 3})


def test_bad_maze_arguments_are_refused_naming_the_problem(tmp_path, capsys):
    out = tmp_path / "never"
    for changes, expected in (
        (dict(num_mazes=0), r"num_mazes must be an integer >= 1 .*got 0; a dataset must name its mazes"),
        (dict(num_mazes=-2), "num_mazes must be an integer >= 1"),
        (dict(num_mazes=2.5), "num_mazes must be an integer >= 1"),
        (dict(num_mazes=None, start_maze=3), "start_maze 3 needs num_mazes"),
        (dict(start_maze=-1), r"start_maze must be an integer in 0\.\.2147483645"),
        (dict(start_maze=2**31 - 2), r"start_maze must be an integer in 0\.\.2147483645 .*num_mazes=3"),
    ):
        with pytest.raises(ValueError, match=expected):
            generate_dataset(out, workers=1, **{**ARGS, **changes})
    assert not out.exists()
    with pytest.raises(ValueError, match=r"maze_number must be an integer in 0\.\.2147483647"):
        run_expert_episode("STG1", 0, CONFIG, maze_number=-1)

    code = main(["generate", "--task", "STG1", "--episodes", "2", "--num-mazes", "0", "--out", str(out)])
    assert code == 2
    assert "a dataset must name its mazes" in capsys.readouterr().err
    assert not out.exists()


def test_an_episode_file_of_another_maze_is_refused(on_mazes, tmp_path):
    path = tmp_path / "episode.npz"
    data = read_episode(episode_path(on_mazes, 0), 0, episode_seed(1, 0), 4)
    path.write_bytes(episode_bytes(0, {**data, "maze": np.int64(9)}))
    with pytest.raises(DatasetError, match="holds an episode on maze 9, expected maze 4"):
        read_episode(path, 0, episode_seed(1, 0), 4)
    with pytest.raises(DatasetError, match="holds an episode on maze 9, expected MERL's maze"):
        read_episode(path, 0, episode_seed(1, 0))
    without = {key: value for key, value in data.items() if key != "maze"}
    path.write_bytes(episode_bytes(0, without))
    with pytest.raises(DatasetError, match="holds an episode on MERL's maze, expected maze 4"):
        read_episode(path, 0, episode_seed(1, 0), 4)
