"""Progress lines read from runs' logs while they run (bimgame.experiments.run_progress): a real tiny
DAgger and PPO run on the labyrinth give lines with their logs' numbers, a row cut off mid-write is
left out, and the watcher yields every future while showing each changed line once."""

from __future__ import annotations

import csv
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from bimgame.expert.labyrinth_mpc import LabyrinthMPCConfig
from bimgame.experiments.run_progress import completed_with_progress, dagger_progress, training_progress
from bimgame.learn import runs
from bimgame.learn.dagger import DAggerConfig, dagger
from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.learn.supervised import PretrainConfig

LEARNER = dict(task="LABYRINTH-EASY", obs="state", hidden=16, features=16, bptt=20, batch_episodes=4, eval_episodes=0,
               seed=0, aux_heads=False, asymmetric_critic=False, action_type="continuous")
PPO = dict(task="LABYRINTH-EASY", obs="state", action_type="continuous", hidden=16, features=16, envs_per_worker=4,
           n_steps=32, eval_every=0, eval_episodes=2, max_episode_steps=40, steps=1024, seed=0)


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    with runs.torch_threads(1):
        yield


def _rows(path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def test_a_dagger_line_counts_its_iterations_labels_and_in_run_scores(tmp_path):
    config = DAggerConfig(learner=PretrainConfig(**LEARNER), expert=LabyrinthMPCConfig(n_samples=6, horizon=10),
                          episodes_per_iteration=2, max_episode_steps=25, iterations=2, epochs_per_iteration=1,
                          eval_episodes=2)
    assert dagger_progress(tmp_path / "run", 2) is None  # nothing logged yet
    dagger(config, tmp_path / "run", progress=False)
    last = _rows(tmp_path / "run" / "dagger.csv")[-1]
    assert last["iteration"] == "1"
    assert dagger_progress(tmp_path / "run", 5) == (
        f"DAgger 2/5 iterations, {int(last['labels']):,} labels; "
        f"in-run greedy {float(last['greedy_success_rate']):.0%} (return {float(last['greedy_mean_return']):.2f}), "
        f"sampled {float(last['sampled_success_rate']):.0%} ({float(last['sampled_mean_return']):.2f})"
    )


def test_a_ppo_line_counts_steps_and_its_last_episodes_from_the_start(tmp_path):
    train_ppo(PPOConfig.from_flat(PPO), tmp_path / "run", progress=False)
    episodes = _rows(tmp_path / "run" / "episodes.csv")
    from_start = [row for row in episodes if row["true_start"] == "True"]
    assert len(from_start) > 3
    recent = from_start[-3:]
    solved = np.mean([row["success"] == "True" for row in recent])
    mean_return = np.mean([float(row["return"]) for row in recent])
    step = int(episodes[-1]["step"])
    expected = (f"PPO {step:,}/2,048 steps ({step / 2048:.0%}); last 3 episodes from the start: {solved:.0%} solved, "
                f"return {mean_return:.2f}")
    assert training_progress(tmp_path / "run", 2048, recent=3) == expected
    # A row being written when the log is read is left out, not misread.
    with (tmp_path / "run" / "episodes.csv").open("a") as handle:
        handle.write("99999,99000,0.5,12,Tr")
    assert training_progress(tmp_path / "run", 2048, recent=3) == expected
    assert training_progress(tmp_path / "none", 2048) is None
    assert training_progress(tmp_path / "run", 2048, learner="A3C", recent=3) == "A3C" + expected[3:]


def test_the_watcher_yields_every_future_and_shows_each_changed_line_once():
    release = threading.Event()
    calls = {"a": 0}
    lines: list[str] = []

    def describe(key: str) -> str | None:
        if key == "b":
            return None  # a run that has logged nothing: no line
        calls["a"] += 1
        if calls["a"] == 6:
            release.set()  # the run ends only after its line has been read six times
        return "started" if calls["a"] < 3 else "halfway"

    with ThreadPoolExecutor(max_workers=2) as pool:
        futures = {pool.submit(release.wait, 30): "a", pool.submit(lambda: "done"): "b"}
        finished = list(completed_with_progress(futures, describe, name=lambda key: f"run {key}", interval=0.01,
                                                echo=lines.append))
    assert sorted(futures[f] for f in finished) == ["a", "b"]
    assert all(f.result() for f in finished)
    assert lines == ["run a: started", "run a: halfway"]
    with pytest.raises(ValueError, match="interval must be > 0 seconds, got 0"):
        list(completed_with_progress(futures, describe, interval=0))


def test_a_log_the_watcher_cannot_read_is_said_and_the_runs_go_on():
    lines: list[str] = []

    def describe(key: str) -> str | None:
        raise ValueError("could not convert string to float: 'Tr'")

    release = threading.Event()
    with ThreadPoolExecutor(max_workers=1) as pool:
        futures = {pool.submit(release.wait, 30): "a"}
        watcher = completed_with_progress(futures, describe, interval=0.01, echo=lambda line: (lines.append(line),
                                                                                                release.set()))
        assert [futures[f] for f in watcher] == ["a"]
    assert lines == ["a: progress unreadable (ValueError: could not convert string to float: 'Tr')"]
