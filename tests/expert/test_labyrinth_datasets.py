"""Expert datasets on CyberRunner's labyrinth: episode files and Minari, the pre-training view
(state, and pixels / CyberRunner's observation re-rendered exactly), determinism across workers,
resuming, refusals, the command line."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import minari
import numpy as np
import pytest

import bimgame.expert.labyrinth_datasets as lab
from bimgame.cli.main import main
from bimgame.envs.env import NO_ACTION
from bimgame.envs.labyrinth_cyberrunner import CYBERRUNNER_FLAT_SIZE
from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.envs.labyrinth_surroundings import SURROUNDINGS_SIZE
from bimgame.expert.datasets import dataset_summary, generate_dataset
from bimgame.expert.labyrinth_datasets import (
    DatasetError,
    generate_labyrinth_dataset,
    labyrinth_dataset_manifest,
    labyrinth_dataset_summary,
    load_labyrinth_dataset,
    load_labyrinth_sequences,
)
from bimgame.expert.labyrinth_episodes import record_labyrinth_episode
from bimgame.expert.labyrinth_mpc import LabyrinthMPC, LabyrinthMPCConfig, run_labyrinth_expert_episode
from bimgame.expert.mpc import MPCConfig
from bimgame.util.files import exclusive_lock
from bimgame.util.seeding import episode_seed

CONFIG = LabyrinthMPCConfig(n_samples=4, horizon=8)
ARGS = dict(task="LABYRINTH-EASY", episodes=3, seed=1, config=CONFIG, max_steps=20, progress=False)
DATASET_ID = "bimgame/labyrinth-easy-expert-v0"
GAMMA = 0.9


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Continuous actions, one worker: the dataset other runs must reproduce."""
    return generate_labyrinth_dataset(tmp_path_factory.mktemp("lab") / "reference", workers=1, **ARGS)


@pytest.fixture(scope="module")
def discrete(tmp_path_factory):
    return generate_labyrinth_dataset(
        tmp_path_factory.mktemp("lab") / "discrete", workers=1, **{**ARGS, "episodes": 2, "max_steps": 15},
        action_type="discrete")


def episode_files(out: Path) -> dict[str, bytes]:
    return {path.name: path.read_bytes() for path in sorted((out / "episodes").glob("episode_*.npz"))}


def snapshot(out: Path) -> dict[str, tuple[int, int]]:
    """Every file's size and modification time, but the lock's (each writer records itself in it)."""
    return {str(p.relative_to(out)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in out.rglob("*") if p.is_file() and p.name != ".lock"}


def replay(seed: int, actions: np.ndarray, obs_mode: str, action_type: str = "continuous", **env_kwargs) -> list:
    """The env's own observations along a recorded episode's actions."""
    env = LabyrinthEnv("easy", obs_mode=obs_mode, action_type=action_type, **env_kwargs)
    obs, _ = env.reset(seed=seed)
    frames = [obs]
    for action in actions:
        frames.append(env.step(action)[0])
    env.close()
    return frames


def test_continuous_round_trip_shapes_returns_and_previous_actions(reference):
    manifest = labyrinth_dataset_manifest(reference)
    assert manifest["puzzle"] == "labyrinth" and manifest["layout"] == "easy" and manifest["dataset_id"] == DATASET_ID
    assert manifest["env_id"] == "BiMGame/Labyrinth-Easy-v0" and manifest["mpc_config"]["n_samples"] == 4
    sequences = load_labyrinth_sequences(reference, gamma=GAMMA)
    assert [s.id for s in sequences] == [0, 1, 2]
    for sequence in sequences:
        steps = len(sequence)
        assert 1 <= steps <= 20
        assert sequence.obs.shape == (steps, 17) and sequence.obs.dtype == np.float32
        assert sequence.actions.shape == (steps, 2) and sequence.actions.dtype == np.float32
        assert np.all(np.abs(sequence.actions) <= 1)
        assert np.array_equal(sequence.prev_actions[0], [0.0, 0.0])
        assert np.array_equal(sequence.prev_actions[1:], sequence.actions[:-1])
        assert sequence.prev_rewards[0] == 0 and np.array_equal(sequence.prev_rewards[1:], sequence.rewards[:-1])
        direct = [sum(GAMMA ** (k - t) * sequence.rewards[k] for k in range(t, steps)) for t in range(steps)]
        np.testing.assert_allclose(sequence.returns, direct, rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(sequence.tilt, sequence.obs[:, 4:6], atol=1e-7)  # rad, as observed
        assert np.array_equal(sequence.state_obs, sequence.obs)
        assert sequence.terminated != sequence.truncated
    summary = labyrinth_dataset_summary(reference)
    assert summary["episodes"] == 3 and summary["steps"] == sum(len(s) for s in sequences)
    assert summary["action_type"] == "continuous" and summary["control_hz"] == 55


def test_episodes_are_the_experts_own_from_the_episode_seeds(reference):
    """Each stored episode is the expert's episode from reset(seed=episode_seed(seed, i)), as the
    expert's own runner plays it; the files hold T+1 physics states, tilts and progress."""
    for index in range(3):
        seed = episode_seed(1, index)
        with np.load(reference / "episodes" / f"episode_{index:06d}.npz", allow_pickle=False) as data:
            stored = {key: data[key] for key in data.files}
        steps = len(stored["actions"])
        assert stored["sim_states"].shape == (steps + 1, 20) and stored["tilt"].shape == (steps + 1, 2)
        assert stored["segments"].shape == stored["progress"].shape == (steps + 1,)
        assert int(stored["seed"]) == seed and stored["time_s"] == pytest.approx(steps / 55)
        env = LabyrinthEnv("easy")
        again = record_labyrinth_episode(
            env, LabyrinthMPC.for_env(env, CONFIG, rng=np.random.default_rng(seed)), seed=seed, max_steps=20)
        assert all(np.array_equal(stored[key], again[key]) for key in again)
        result = run_labyrinth_expert_episode(
            env, LabyrinthMPC.for_env(env, CONFIG, rng=np.random.default_rng(seed)), seed=seed, max_steps=20)
        assert (result["steps"], result["success"]) == (steps, bool(stored["success"]))
        assert str(stored["failure"]) == (result["failure"] or "")
        env.close()


def test_discrete_round_trip(discrete):
    sequences = load_labyrinth_sequences(discrete, gamma=GAMMA)
    assert len(sequences) == 2
    for sequence in sequences:
        assert sequence.actions.dtype == np.int64 and sequence.actions.shape == (len(sequence),)
        assert set(np.unique(sequence.actions)) <= set(range(5))
        assert sequence.prev_actions[0] == NO_ACTION
        assert np.array_equal(sequence.prev_actions[1:], sequence.actions[:-1])
    assert labyrinth_dataset_manifest(discrete)["dataset_id"] == "bimgame/labyrinth-easy-discrete-expert-v0"


def test_rerendered_observations_equal_the_envs_own(reference, discrete):
    for out, action_type in ((reference, "continuous"), (discrete, "discrete")):
        pixels = load_labyrinth_sequences(out, obs="pixels", gamma=GAMMA)
        flat = load_labyrinth_sequences(out, obs="cyberrunner", gamma=GAMMA)
        for index, (p, c) in enumerate(zip(pixels, flat, strict=True)):
            seed = episode_seed(1, index)
            assert p.obs.dtype == np.uint8 and p.obs.shape == (len(p), 1, 84, 84)
            assert np.array_equal(p.obs, np.stack(replay(seed, p.actions, "pixels", action_type)[:-1]))
            assert c.obs.shape == (len(c), CYBERRUNNER_FLAT_SIZE)
            assert np.array_equal(c.obs, np.stack(replay(seed, c.actions, "cyberrunner_flat", action_type)[:-1]))
            assert np.array_equal(p.state_obs, c.state_obs) and np.array_equal(p.actions, c.actions)


def test_surroundings_computed_from_stored_positions_equal_the_envs_own(reference):
    plain = load_labyrinth_sequences(reference, gamma=GAMMA)
    around = load_labyrinth_sequences(reference, gamma=GAMMA, surroundings=True)
    for index, (p, a) in enumerate(zip(plain, around, strict=True)):
        assert a.obs.shape == (len(a), 17 + SURROUNDINGS_SIZE)
        np.testing.assert_array_equal(a.obs[:, :17], p.obs)
        replayed = np.stack(replay(episode_seed(1, index), a.actions, "state", surroundings=True)[:-1])
        np.testing.assert_allclose(a.obs, replayed, atol=1e-6)  # from float32 positions: within rounding
    with pytest.raises(ValueError, match="surroundings are part of the state observation, not of obs 'pixels'"):
        load_labyrinth_sequences(reference, obs="pixels", gamma=GAMMA, surroundings=True)


def test_the_motion_rerendered_from_consecutive_states_equals_the_envs_own(reference):
    plain = load_labyrinth_sequences(reference, obs="cyberrunner", gamma=GAMMA)
    moving = load_labyrinth_sequences(reference, obs="cyberrunner", gamma=GAMMA, motion=True)
    for index, (p, m) in enumerate(zip(plain, moving, strict=True)):
        assert m.obs.shape == (len(m), CYBERRUNNER_FLAT_SIZE + 2)
        np.testing.assert_array_equal(m.obs[:, :CYBERRUNNER_FLAT_SIZE], p.obs)
        replayed = np.stack(replay(episode_seed(1, index), m.actions, "cyberrunner_flat", motion=True)[:-1])
        np.testing.assert_array_equal(m.obs, replayed)
        assert np.any(m.obs[1:, -2:] != 0) and np.array_equal(m.obs[0, -2:], [0.0, 0.0])
    with pytest.raises(ValueError, match="motion is part of CyberRunner's observation .*, not of obs 'state'"):
        load_labyrinth_sequences(reference, gamma=GAMMA, motion=True)


def test_the_previous_frame_rerendered_from_consecutive_states_equals_the_envs_own(reference):
    """Pixels with motion: each step's two frames, re-rendered from the stored physics states of the
    step and the step before, are the env's own; the second is the plain pixel observation."""
    plain = load_labyrinth_sequences(reference, obs="pixels", gamma=GAMMA)
    stacked = load_labyrinth_sequences(reference, obs="pixels", gamma=GAMMA, motion=True)
    for index, (p, m) in enumerate(zip(plain, stacked, strict=True)):
        assert m.obs.dtype == np.uint8 and m.obs.shape == (len(m), 2, 84, 84)
        np.testing.assert_array_equal(m.obs[:, 1:], p.obs)
        np.testing.assert_array_equal(m.obs[1:, :1], p.obs[:-1])  # the previous step's frame
        np.testing.assert_array_equal(m.obs[0, 0], m.obs[0, 1])  # an episode's first: no motion
        replayed = np.stack(replay(episode_seed(1, index), m.actions, "pixels", motion=True)[:-1])
        np.testing.assert_array_equal(m.obs, replayed)


def test_observe_state_gives_the_observation_the_env_returned(reference):
    with np.load(reference / "episodes" / "episode_000000.npz", allow_pickle=False) as data:
        states, progress, observations = data["sim_states"], data["progress"], data["observations"]
    env = LabyrinthEnv("easy")
    env.reset(seed=5)
    before = env.sim.get_state()
    for state, position, obs in zip(states, progress, observations, strict=True):
        assert np.array_equal(env.observe_state(state, position), obs)
    assert np.array_equal(env.sim.get_state(), before)  # the env's own episode is untouched
    with pytest.raises(ValueError, match="sim_state must be a finite float vector of length 20"):
        env.observe_state(states[0][:5], 0.0)
    with pytest.raises(ValueError, match="progress must be a finite number"):
        env.observe_state(states[0], float("nan"))
    env.close()


def test_same_dataset_with_two_workers(reference, tmp_path):
    two = generate_labyrinth_dataset(tmp_path / "two", workers=2, **ARGS)
    assert episode_files(two) == episode_files(reference)
    assert dataset_summary(two)["content_sha256"] == dataset_summary(reference)["content_sha256"]


def test_resume_regenerates_exactly_a_deleted_episode(reference, tmp_path, monkeypatch):
    out = shutil.copytree(reference, tmp_path / "copy")
    original = episode_files(reference)
    (out / "episodes" / "episode_000001.npz").unlink()
    kept = {name: (out / "episodes" / name).stat().st_mtime_ns for name in ("episode_000000.npz", "episode_000002.npz")}
    calls = []
    real = lab.labyrinth_episode_job

    def counting(*arguments):
        calls.append(arguments[3])  # the episode index
        return real(*arguments)

    monkeypatch.setattr(lab, "labyrinth_episode_job", counting)
    with pytest.warns(UserWarning, match="missing episodes/episode_000001.npz; repairing"):
        generate_labyrinth_dataset(out, workers=1, **ARGS)
    assert calls == [1]
    assert episode_files(out) == original
    assert {name: (out / "episodes" / name).stat().st_mtime_ns for name in kept} == kept
    assert len(load_labyrinth_sequences(out, gamma=GAMMA)) == 3

    (out / "COMPLETE").unlink()  # an interrupted run: incomplete until resumed
    with pytest.raises(DatasetError, match=r"incomplete \(3 of 3 episode files"):
        load_labyrinth_sequences(out, gamma=GAMMA)


def test_other_arguments_a_maze_run_and_a_second_writer_are_refused_and_nothing_changes(reference, tmp_path):
    out = shutil.copytree(reference, tmp_path / "copy")
    before = snapshot(out)
    for change, message in [
        ({"seed": 2}, r"different arguments \(seed: 1 there, 2 now\).*another directory"),
        ({"action_type": "discrete"}, r"action_type: 'continuous' there, 'discrete' now"),
        ({"config": LabyrinthMPCConfig(n_samples=5, horizon=8)}, "mpc_config"),
        ({"task": "LABYRINTH-HARD"}, "task: 'LABYRINTH-EASY' there, 'LABYRINTH-HARD' now"),
    ]:
        with pytest.raises(ValueError, match=message):
            generate_labyrinth_dataset(out, workers=1, **{**ARGS, **change})
    with pytest.raises(ValueError, match="task: 'LABYRINTH-EASY' there, 'STG1' now"):
        generate_dataset(out, "STG1", 3, seed=1, config=MPCConfig(n_samples=4, horizon=8), workers=1, progress=False)
    with exclusive_lock(out / ".lock", "held"), pytest.raises(BlockingIOError, match="another process is generating"):
        generate_labyrinth_dataset(out, workers=1, **ARGS)
    assert snapshot(out) == before
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert generate_labyrinth_dataset(out, workers=1, **ARGS) == out  # finished: verified, returned as is
    assert snapshot(out) == before


def test_minari_loads_the_dataset(reference, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(reference / "minari"))
    dataset = minari.load_dataset(DATASET_ID)
    assert dataset.total_episodes == 3 and dataset.total_steps == dataset_summary(reference)["steps"]
    seeds = [m["seed"] for m in dataset.storage.get_episode_metadata(dataset.episode_indices)]
    assert seeds == [episode_seed(1, i) for i in range(3)]
    sequences = load_labyrinth_sequences(reference, gamma=GAMMA)
    for episode, sequence in zip(dataset.iterate_episodes(), sequences, strict=True):
        assert np.array_equal(episode.observations[:-1], sequence.obs)
        assert np.array_equal(episode.actions, sequence.actions) and episode.actions.dtype == np.float32
        assert set(episode.infos) == {"sim_state", "tilt", "segment", "progress"}
        assert episode.infos["sim_state"].shape == (len(sequence) + 1, 20)
    env = dataset.recover_environment()
    assert env.spec.id == "BiMGame/Labyrinth-Easy-v0" and env.spec.max_episode_steps == 20
    assert env.action_space.shape == (2,) and env.observation_space.shape == (17,)
    env.close()
    assert load_labyrinth_dataset(reference).total_episodes == 3


@pytest.mark.parametrize("change, error, message", [
    ({"episodes": 0}, ValueError, "episodes must be an integer >= 1, got 0"),
    ({"task": "LABYRINTH-HUGE"}, ValueError,
     "unknown labyrinth task 'LABYRINTH-HUGE'; allowed: LABYRINTH-EASY, LABYRINTH-MEDIUM, LABYRINTH-HARD"),
    ({"task": "STG1"}, ValueError, "unknown labyrinth task 'STG1'; allowed: LABYRINTH-EASY"),
    ({"action_type": "analog"}, ValueError, "unknown action_type 'analog'; allowed: continuous, discrete"),
    ({"control_hz": 60}, ValueError, r"control_hz must be one of \(30, 55\)"),
    ({"workers": 0}, ValueError, "workers must be an integer >= 1"),
    ({"seed": -1}, ValueError, "seed must be an integer >= 0"),
    ({"max_steps": 0}, ValueError, "max_steps must be an integer >= 1"),
    ({"backend": "dask"}, ValueError, "unknown backend 'dask'; allowed: local, ray"),
    ({"config": MPCConfig()}, TypeError, "config must be a LabyrinthMPCConfig"),
])
def test_bad_arguments_name_the_problem_and_create_nothing(tmp_path, change, error, message):
    with pytest.raises(error, match=message):
        generate_labyrinth_dataset(tmp_path / "new", **{**ARGS, "workers": 1, **change})
    assert not (tmp_path / "new").exists()


def test_bad_loads_name_the_problem(reference, tmp_path):
    with pytest.raises(ValueError, match="unknown obs 'rgb'; allowed: state, pixels, cyberrunner, cyberrunner_flat"):
        load_labyrinth_sequences(reference, obs="rgb", gamma=GAMMA)
    with pytest.raises(ValueError, match=r"gamma must be a number in \[0, 1\]"):
        load_labyrinth_sequences(reference, gamma=1.5)
    with pytest.raises(DatasetError, match="does not exist"):
        load_labyrinth_sequences(tmp_path / "nothing", gamma=GAMMA)
    maze = shutil.copytree(reference, tmp_path / "maze")
    manifest = json.loads((maze / "generation.json").read_text())
    del manifest["puzzle"]
    (maze / "generation.json").write_text(json.dumps(manifest))
    with pytest.raises(DatasetError, match="a dataset of the circular maze"):
        load_labyrinth_sequences(maze, gamma=GAMMA)


def test_command_line(reference, tmp_path, capsys):
    out = shutil.copytree(reference, tmp_path / "copy")
    common = ["generate", "--task", "labyrinth-easy", "--episodes", "3", "--out", str(out), "--seed", "1",
              "--workers", "1", "--max-steps", "20", "--no-progress"]
    assert main([*common, "-K", "4", "-H", "8"]) == 0  # the same run: verified and summarised
    printed = capsys.readouterr().out
    assert f"{DATASET_ID} in {out}: 3 episodes" in printed and "load_labyrinth_sequences" in printed
    assert main(common) == 2  # the labyrinth expert's own defaults (K=16, H=30): another run
    assert "mpc_config" in capsys.readouterr().err
    assert main([*common, "-K", "4", "-H", "8", "--plans", "2"]) == 2  # the mean of 2 searches: another run
    assert "mpc_config" in capsys.readouterr().err
    for flags, named in [(["--num-mazes", "2"], "--num-mazes"),
                         (["--planning-reward", "geodesic"], "--planning-reward")]:
        assert main([*common, "-K", "4", "-H", "8", *flags]) == 2
        assert named in capsys.readouterr().err
    maze = ["generate", "--task", "STG1", "--out", str(tmp_path / "maze"), "--no-progress"]
    assert main([*maze, "--action-type", "discrete"]) == 2
    assert "--action-type: the labyrinth's option" in capsys.readouterr().err
    assert main([*maze, "--plans", "2"]) == 2
    assert "--plans: the labyrinth's expert setting, not the circular maze's" in capsys.readouterr().err
    assert main([*maze, "--sampling", "mppi"]) == 2
    assert "--sampling mppi: the labyrinth's expert setting" in capsys.readouterr().err
    assert not (tmp_path / "maze").exists()
    with pytest.raises(SystemExit):
        main(["generate", "--task", "LABYRINTH-HUGE", "--out", str(tmp_path / "x")])
    assert "invalid choice: 'LABYRINTH-HUGE'" in capsys.readouterr().err
