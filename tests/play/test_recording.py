"""Recording people's episodes: a dataset in the format of ``bimgame generate`` (read by
``iterate_sequences``, ``load_dataset``, pre-training), replayable, marked human, appended to by a
second session, refusing what is not a recording, and intact after a crash."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from bimgame.envs.env import BallInMazeEnv
from bimgame.expert.datasets import (
    DatasetError,
    dataset_manifest,
    iterate_sequences,
    load_dataset,
)
from bimgame.expert.minari_build import episode_path
from bimgame.learn.pretrain import data_source, pretrain
from bimgame.learn.runs import torch_threads
from bimgame.learn.supervised import PretrainConfig
from bimgame.play import recording as recording_module
from bimgame.play.controls import KEY_ACTIONS
from bimgame.play.recording import HumanRecording
from bimgame.play.session import PlaySession

BUILD_TIMEOUT = 120  # s: the Minari build runs in a child process, on a busy machine


def play(session: PlaySession, keys: list[list[str]]) -> list[int]:
    """Hold each set of keys for one tick; returns the actions executed."""
    executed = []
    for held in keys:
        session.set_keys("tab", held)
        if session.tick():
            executed.append(session.last_action)
    return executed


def open_recording(path, task="STG1", max_steps=30) -> HumanRecording:
    recording = HumanRecording(path, task, max_steps=max_steps, seed=0)
    recording.open()
    return recording


def replay(task: str, episode) -> np.ndarray:
    """The state observations of stepping the recorded actions from the recorded start."""
    env = BallInMazeEnv(task, obs_mode="state")
    obs, _ = env.reset(options={"sim_state": np.asarray(episode.infos["sim_state"][0])})
    observations = [obs]
    for action in episode.actions:
        obs, *_ = env.step(int(action))
        observations.append(obs)
    env.close()
    return np.array(observations)


def test_a_recorded_episode_is_a_dataset_that_replays_exactly(tmp_path):
    out = tmp_path / "human"
    recording = open_recording(out)
    session = PlaySession("STG1", max_steps=30, seed=0, recording=recording)
    keys = [["up"]] * 10 + [["up", "right"]] * 8 + [[]] * 5 + [["left"]] * 7 + [[]] * 3  # 30 steps, then over
    executed = play(session, keys)
    assert len(executed) == 30 and session.phase == "over"
    assert executed == [2] * 10 + [3] * 8 + [0] * 5 + [4] * 7
    assert recording.wait_built(BUILD_TIMEOUT), recording.last_error
    session.close()
    assert recording.close()

    manifest = dataset_manifest(out)
    assert manifest["source"] == "human" and manifest["task"] == "STG1" and manifest["episodes"] == 1
    dataset = load_dataset(out)  # verified: marker, sizes, SHA-256
    assert dataset.storage.metadata["algorithm_name"] == "human (bimgame play)"
    (episode,) = list(dataset.iterate_episodes())
    np.testing.assert_array_equal(episode.actions, executed)
    assert episode.truncations[-1] and not episode.terminations.any()
    np.testing.assert_array_equal(replay("STG1", episode), episode.observations)  # bit for bit
    (sequence,) = list(iterate_sequences(out, obs="state"))
    np.testing.assert_array_equal(sequence.actions, executed)
    (pixels,) = list(iterate_sequences(out, obs="pixels"))
    assert pixels.obs.shape == (30, 1, 84, 84)
    assert data_source(out) == "human"


def test_only_the_persons_steps_are_recorded_from_the_take_over(tmp_path, tiny_agent_run):
    """The agent plays 6 steps, the person 5, the agent 4, the person until the limit: two episodes,
    each starting at the state the person took over in, the first truncated at the hand-back."""
    out = tmp_path / "mixed"
    recording = open_recording(out, max_steps=25)
    session = PlaySession("STG1", max_steps=25, seed=0, agent=tiny_agent_run, recording=recording)
    for _ in range(6):
        session.tick()
    session.set_controller("human")
    first = play(session, [["down"]] * 5)
    session.set_controller("agent")
    for _ in range(4):
        session.tick()
    session.set_controller("human")
    second = play(session, [["right"]] * 20)
    assert session.phase == "over" and session.steps == 25 and len(second) == 10
    assert recording.wait_built(BUILD_TIMEOUT), recording.last_error
    session.close()
    recording.close()

    episodes = list(load_dataset(out).iterate_episodes())
    assert [list(e.actions) for e in episodes] == [first, second[:10]]
    assert all(e.truncations[-1] for e in episodes)
    starts = [int(np.load(episode_path(out, i))["start_step"]) for i in range(2)]
    reasons = [str(np.load(episode_path(out, i))["end_reason"]) for i in range(2)]
    assert starts == [6, 15] and reasons == ["handed to the agent", "time limit"]
    for episode in episodes:
        np.testing.assert_array_equal(replay("STG1", episode), episode.observations)


def test_a_second_session_appends(tmp_path):
    out = tmp_path / "human"
    recording = open_recording(out, max_steps=12)
    session = PlaySession("STG1", max_steps=12, seed=0, recording=recording)
    play(session, [["up"]] * 12)
    assert recording.wait_built(BUILD_TIMEOUT), recording.last_error
    session.close()
    recording.close()
    first = list(load_dataset(out).iterate_episodes())[0]

    recording = open_recording(out, max_steps=12)
    assert recording.episodes == 1
    session = PlaySession("STG1", max_steps=12, seed=0, recording=recording)
    assert session.episode == 1  # the starts go on from the recording's episodes: no repeat
    play(session, [["left"]] * 4)
    session.reset()  # R after 4 steps: recorded, truncated
    play(session, [[]] * 3)  # ready: no key pressed, nothing stepped, nothing recorded
    session.reset()
    assert recording.wait_built(BUILD_TIMEOUT), recording.last_error
    session.close()
    recording.close()

    episodes = list(load_dataset(out).iterate_episodes())
    assert len(episodes) == 2
    np.testing.assert_array_equal(episodes[0].observations, first.observations)
    assert list(episodes[1].actions) == [KEY_ACTIONS["left"]] * 4 and episodes[1].truncations[-1]
    assert str(np.load(episode_path(out, 1))["end_reason"]) == "reset"
    assert not np.array_equal(episodes[0].observations[0], episodes[1].observations[0])


def test_refuses_what_is_not_its_recording(tmp_path):
    expert = tmp_path / "expert"
    expert.mkdir()
    (expert / "generation.json").write_text(json.dumps({"format": "bimgame-expert-dataset", "format_version": 1,
                                                        "task": "STG1", "episodes": 3}))
    with pytest.raises(ValueError, match="expert dataset"):
        HumanRecording(expert, "STG1").open()
    assert data_source(expert) == "expert"
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="not empty"):
        HumanRecording(other, "STG1").open()
    assert sorted(p.name for p in other.iterdir()) == ["notes.txt"]

    out = tmp_path / "human"
    recording = open_recording(out, task="STG1", max_steps=30)
    with pytest.raises(BlockingIOError, match="another process"):
        HumanRecording(out, "STG1", max_steps=30).open()  # one recorder at a time
    recording.close()
    with pytest.raises(ValueError, match="STG1 episodes"):
        HumanRecording(out, "STG2", max_steps=30).open()
    with pytest.raises(ValueError, match="time limit"):
        HumanRecording(out, "STG1").open()


def test_a_crash_before_the_build_keeps_every_episode(tmp_path, monkeypatch):
    out = tmp_path / "human"
    recording = open_recording(out, max_steps=8)
    session = PlaySession("STG1", max_steps=8, seed=0, recording=recording)
    play(session, [["up"]] * 8)
    assert recording.wait_built(BUILD_TIMEOUT), recording.last_error

    def crash(*args, **kwargs):  # the build dies (a kill -9 of the child, a full disk …)
        raise RuntimeError("simulated crash")

    monkeypatch.setattr(recording_module, "run_build_process", crash)
    session.reset()
    play(session, [["down"]] * 8)
    deadline = time.monotonic() + BUILD_TIMEOUT
    while recording.last_error is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert "simulated crash" in recording.last_error and recording.built == 1
    session.close()
    assert not recording.close()
    assert episode_path(out, 1).is_file()
    assert len(list(load_dataset(out).iterate_episodes())) == 1  # still the complete earlier dataset

    (out / "COMPLETE").unlink()  # a crash in the middle of the swap: incomplete
    with pytest.raises(DatasetError, match="incomplete"):
        load_dataset(out)
    monkeypatch.undo()
    recording = open_recording(out, max_steps=8)  # the next start rebuilds from the episode files
    assert recording.episodes == 2
    assert recording.wait_built(BUILD_TIMEOUT), recording.last_error
    recording.close()
    episodes = list(load_dataset(out).iterate_episodes())
    assert [list(e.actions) for e in episodes] == [[2] * 8, [1] * 8]


def test_pretraining_reports_a_human_data_source(tmp_path, one_torch_thread):
    out = tmp_path / "human"
    recording = open_recording(out, max_steps=10)
    session = PlaySession("STG1", max_steps=10, seed=0, recording=recording, over_ticks=1)
    for key in ("up", "down", "left", "right", "up"):
        play(session, [[key]] * 10 + [[]])
    assert recording.wait_built(BUILD_TIMEOUT), recording.last_error
    session.close()
    recording.close()
    config = PretrainConfig(task="STG1", obs="state", target="policy", epochs=1, eval_episodes=0, hidden=8,
                            features=8, seed=0)
    with torch_threads(1):
        result = pretrain(config, out, tmp_path / "pi", progress=False)
    assert result.data_source == "human"
    assert json.loads((tmp_path / "pi" / "summary.json").read_text())["data_source"] == "human"
