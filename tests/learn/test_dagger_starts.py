"""DAgger's rollouts started in the expert's states on the labyrinth (``demo_start_share``): the chosen
share of rollouts starts where the expert's successful episode was, the others at the layout's start
exactly as without it, the draws are seeded, and what cannot work is refused by name."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from bimgame.cli.main import main
from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.expert.labyrinth_datasets import load_labyrinth_sequences
from bimgame.expert.labyrinth_mpc import LabyrinthMPCConfig
from bimgame.learn import runs
from bimgame.learn.dagger import DAggerConfig, collect_episodes, dagger
from bimgame.learn.dagger.starts import demo_start_states, draw_demo_starts
from bimgame.learn.path_starts import DemoPathStarts
from bimgame.learn.supervised import PretrainConfig

TASK = "LABYRINTH-EASY"
CHEAP = LabyrinthMPCConfig(n_samples=6, horizon=10)
LEARNER = PretrainConfig(task=TASK, obs="state", action_type="continuous", hidden=16, features=16, eval_episodes=0,
                         seed=0, aux_heads=False, asymmetric_critic=False)


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    with runs.torch_threads(1):
        yield


def _config(data, **changes) -> DAggerConfig:
    settings = dict(learner=LEARNER, expert_data=str(data), episodes_per_iteration=3, expert=CHEAP,
                    max_episode_steps=6, iterations=1, epochs_per_iteration=1, eval_episodes=0,
                    demo_start_share=2 / 3)
    return DAggerConfig(**{**settings, **changes})


def test_a_share_of_the_starts_is_drawn_from_the_states_and_the_rest_is_the_layouts():
    states = np.arange(40, dtype=np.float64).reshape(10, 4)
    starts = draw_demo_starts(states, 0.5, 5, np.random.default_rng(1))  # 2.5 rounds up to 3
    assert [s is None for s in starts] == [False, False, False, True, True]
    assert all(any(np.array_equal(s, row) for row in states) for s in starts[:3])
    again = draw_demo_starts(states, 0.5, 5, np.random.default_rng(1))
    assert all(np.array_equal(a, b) for a, b in zip(starts[:3], again[:3], strict=True))
    picks = draw_demo_starts(states, 1.0, 200, np.random.default_rng(2))
    assert len({s.tobytes() for s in picks}) == 10  # uniform over all states: every one drawn
    assert draw_demo_starts(None, 0.0, 4, np.random.default_rng(0)) == [None] * 4
    with pytest.raises(ValueError, match="starts 2 of 4 rollouts from no states"):
        draw_demo_starts(None, 0.5, 4, np.random.default_rng(0))


def test_rollouts_start_in_the_experts_states_and_the_others_as_without_them(easy_expert_episode):
    config = _config(easy_expert_episode)
    states = demo_start_states(config)
    assert states is not None and len(states) > 300  # the successful episode's ≈ 460 steps, nearly all kept
    net = LEARNER.build_policy(0, LabyrinthEnv("easy").board)
    started, _ = collect_episodes(net, config, beta=0.0, seed=3, demo_states=states)
    plain, _ = collect_episodes(net, dataclasses.replace(config, demo_start_share=0.0), beta=0.0, seed=3)
    expert_obs = load_labyrinth_sequences(easy_expert_episode, gamma=0.99)[0].obs
    for episode in started[:2]:
        # Marble (x, y, vx, vy) and tilt as the expert had them at one of its steps, anywhere on the path.
        distance = np.abs(expert_obs[:, :6] - episode.obs[0, :6]).max(axis=1)
        assert distance.min() < 1e-5
        assert episode.obs[0, 6] != plain[0].obs[0, 6]
    assert max(episode.obs[0, 6] for episode in started[:2]) > 0.05  # progress: not the layout's start
    np.testing.assert_array_equal(started[2].obs, plain[2].obs[: len(started[2].obs)])
    assert plain[2].obs[0, 6] == pytest.approx(0.0, abs=0.01)
    again, _ = collect_episodes(net, config, beta=0.0, seed=3, demo_states=states)
    np.testing.assert_array_equal(again[0].obs[0], started[0].obs[0])  # seeded


def _fractions(data) -> np.ndarray:
    """The progress (fraction of the path) of every expert state a demonstration start may use."""
    return np.sort(DemoPathStarts.from_dataset(data, TASK).path_fractions)


def test_a_window_starts_the_rollouts_only_within_that_part_of_the_path(easy_expert_episode):
    config = _config(easy_expert_episode, demo_start_share=1.0, demo_start_window=[0.3, 0.5])
    assert config.demo_start_window == (0.3, 0.5)  # a list (from JSON or argparse) is kept as a tuple
    states = demo_start_states(config)
    fractions = _fractions(easy_expert_episode)
    inside = ((fractions >= 0.3) & (fractions <= 0.5)).sum()
    assert states is not None and len(states) == inside and 0 < inside < len(fractions) / 2
    net = LEARNER.build_policy(0, LabyrinthEnv("easy").board)
    started, _ = collect_episodes(net, config, beta=0.0, seed=5, demo_states=states)
    begun = [float(episode.obs[0, 6]) for episode in started]  # the state observation's progress fraction
    assert all(0.3 - 1e-6 <= b <= 0.5 + 1e-6 for b in begun), begun
    whole, _ = collect_episodes(net, _config(easy_expert_episode, demo_start_share=1.0, episodes_per_iteration=12),
                                beta=0.0, seed=5, demo_states=demo_start_states(_config(easy_expert_episode)))
    assert any(not 0.3 <= float(episode.obs[0, 6]) <= 0.5 for episode in whole)  # without it: anywhere


def test_a_window_that_holds_no_expert_state_is_refused_by_name(easy_expert_episode):
    fractions = _fractions(easy_expert_episode)
    gap = int(np.argmax(np.diff(fractions)))  # the widest stretch of path between two expert states
    low, high = fractions[gap], fractions[gap + 1]
    window = (low + (high - low) / 3, high - (high - low) / 3)
    with pytest.raises(ValueError, match=r"demo_start_window .*: none of the \d+ expert states .* widen the window"):
        demo_start_states(_config(easy_expert_episode, demo_start_window=window))


def test_a_run_stores_the_share_and_the_command_line_takes_it(easy_expert_episode, tmp_path):
    result = dagger(_config(easy_expert_episode, episodes_per_iteration=2), tmp_path / "run", progress=False)
    assert result.iterations == 1
    stored = json.loads((tmp_path / "run" / "config.json").read_text())["dagger"]
    assert stored["demo_start_share"] == pytest.approx(2 / 3)
    assert main(["dagger", "--run-dir", str(tmp_path / "cli"), "--task", TASK, "--obs", "state", "--expert-data",
                 str(easy_expert_episode), "--demo-start-share", "0.5", "--hidden", "16", "--features", "16",
                 "--iterations", "1", "--episodes-per-iteration", "2", "--epochs-per-iteration", "1",
                 "--max-episode-steps", "5", "--eval-episodes", "0", "--no-progress"]) == 0
    stored = json.loads((tmp_path / "cli" / "config.json").read_text())["dagger"]
    assert stored["demo_start_share"] == 0.5 and stored["demo_start_window"] == [0.0, 1.0]
    assert main(["dagger", "--run-dir", str(tmp_path / "window"), "--task", TASK, "--obs", "state", "--expert-data",
                 str(easy_expert_episode), "--demo-start-share", "1", "--demo-start-window", "0.2", "0.6",
                 "--hidden", "16", "--features", "16", "--iterations", "1", "--episodes-per-iteration", "2",
                 "--epochs-per-iteration", "1", "--max-episode-steps", "5", "--eval-episodes", "0",
                 "--no-progress"]) == 0
    stored = DAggerConfig.from_dict(json.loads((tmp_path / "window" / "config.json").read_text())["dagger"])
    assert stored.demo_start_window == (0.2, 0.6)
    stored.require_resumable_from(stored)  # read back from JSON it is the same setting
    with pytest.raises(ValueError, match="changed: demo_start_window"):
        dataclasses.replace(stored, demo_start_window=(0.2, 0.7)).require_resumable_from(stored)


def test_what_cannot_start_from_the_experts_states_is_refused(easy_expert_episode, tmp_path):
    with pytest.raises(ValueError, match=r"demo_start_share must be a number in \[0, 1\], got 1.5"):
        _config(easy_expert_episode, demo_start_share=1.5)
    for window in ((0.5, 0.5), (0.6, 0.2), (-0.1, 0.5), (0.0, 1.5), (0.2,), (0.1, 0.2, 0.3), ("a", "b")):
        with pytest.raises(ValueError, match=r"demo_start_window must be two fractions .* 0 <= from < to <= 1"):
            _config(easy_expert_episode, demo_start_window=window)
    with pytest.raises(ValueError, match="with demo_start_share 0 no rollout does: set --demo-start-share"):
        _config(easy_expert_episode, demo_start_share=0.0, demo_start_window=(0.2, 0.3))
    with pytest.raises(ValueError, match="demo_start_share needs expert_data"):
        _config(easy_expert_episode, expert_data=None)
    with pytest.raises(ValueError, match="the labyrinth's .* not STG1's; set it to 0"):
        DAggerConfig(learner=PretrainConfig(task="STG1", obs="state", aux_heads=False, asymmetric_critic=False),
                     expert_data=str(easy_expert_episode), demo_start_share=0.5)
    hard = _config(easy_expert_episode, learner=dataclasses.replace(LEARNER, task="LABYRINTH-HARD"))
    with pytest.raises(ValueError, match="holds LABYRINTH-EASY episodes; .* need a dataset of LABYRINTH-HARD"):
        demo_start_states(hard)
    assert not (tmp_path / "run").exists()
