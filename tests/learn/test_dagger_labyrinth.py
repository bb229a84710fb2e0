"""DAgger on the labyrinth: the labyrinth's MPC expert labels the learner's states in its kind of
action (continuous tilt rates or discrete), the expert's demonstrations can start the aggregated
dataset, and what does not fit (another layout's data, another kind of action, the maze's expert
settings) is refused by name."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch

from bimgame.cli.main import main
from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.expert.labyrinth_datasets import generate_labyrinth_dataset
from bimgame.expert.labyrinth_mpc import LabyrinthMPCConfig
from bimgame.expert.mpc import MPCConfig
from bimgame.learn import runs
from bimgame.learn.dagger import DAggerConfig, collect_episodes, dagger
from bimgame.learn.dagger.rollouts import STALL_PROGRESS_M
from bimgame.learn.supervised import PretrainConfig

TASK = "LABYRINTH-EASY"
#: A cheap expert: the bookkeeping needs labels, not a good planner.
CHEAP = LabyrinthMPCConfig(n_samples=6, horizon=10)
LEARNER = dict(task=TASK, obs="state", hidden=32, features=32, bptt=20, batch_episodes=4, eval_episodes=0, seed=0,
               aux_heads=False, asymmetric_critic=False)


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    with runs.torch_threads(1):
        yield


@pytest.fixture(scope="module")
def lab_data(tmp_path_factory):
    """Four short continuous expert episodes (50 steps each) on the easy layout."""
    return generate_labyrinth_dataset(tmp_path_factory.mktemp("lab") / "data", TASK, 4, seed=5, max_steps=50,
                                      config=CHEAP, workers=1, progress=False)


def _config(action_type: str = "continuous", **changes) -> DAggerConfig:
    settings = dict(learner=PretrainConfig(**LEARNER, action_type=action_type), episodes_per_iteration=3,
                    expert=CHEAP, max_episode_steps=30, iterations=1, epochs_per_iteration=1, eval_episodes=0)
    return DAggerConfig(**{**settings, **changes})


def test_the_labyrinth_expert_labels_every_state_and_beta_chooses_who_acts():
    config = _config()
    net = config.learner.build_policy(0, LabyrinthEnv("easy").board)
    expert_run, costs = collect_episodes(net, config, beta=1.0, seed=3)
    assert len(expert_run) == 3
    assert costs["labels"] == costs["env_steps"] == sum(len(e) for e in expert_run)
    assert costs["expert_sim_steps"] == costs["labels"] * CHEAP.n_samples * CHEAP.horizon
    for episode in expert_run:
        assert episode.actions.dtype == np.float32 and episode.actions.shape == (len(episode), 2)
        assert np.all(np.abs(episode.actions) <= 1.0)
        # β = 1: the expert's tilt changes are what was executed, and the recurrent input is the
        # previous one (zero at the start).
        np.testing.assert_array_equal(episode.executed, episode.actions)
        np.testing.assert_array_equal(episode.prev_actions[0], [0.0, 0.0])
        np.testing.assert_array_equal(episode.prev_actions[1:], episode.executed[:-1])
        # The expert plans for path progress: the marble moves along the path in 30 steps.
        assert episode.rewards.sum() > 0.0
    again, _ = collect_episodes(net, config, beta=1.0, seed=3)
    for a, b in zip(expert_run, again, strict=True):
        np.testing.assert_array_equal(a.actions, b.actions)  # same seed, same labels

    # β = 0: the learner's own (clipped) sampled actions are executed; the labels are still the expert's.
    learner_run, _ = collect_episodes(net, config, beta=0.0, seed=3)
    executed = np.concatenate([e.executed for e in learner_run])
    labels = np.concatenate([e.actions for e in learner_run])
    assert np.all(np.abs(executed) <= 1.0)
    assert np.mean(np.abs(executed - labels) > 1e-6) > 0.9
    # The expert's tilt rates come from its 5 levels per axis; an untrained Gaussian's do not.
    assert set(np.round(np.unique(labels), 6)) <= {-1.0, -0.5, 0.0, 0.5, 1.0}


def test_discrete_labyrinth_dagger_labels_discrete_actions():
    config = _config("discrete", episodes_per_iteration=2)
    net = config.learner.build_policy(0, LabyrinthEnv("easy").board)
    episodes, _ = collect_episodes(net, config, beta=0.5, seed=1)
    for episode in episodes:
        assert episode.actions.dtype == np.int64
        assert set(np.unique(episode.actions)) <= set(range(5))


def test_a_rollout_that_stops_progressing_for_stall_steps_ends_there():
    """An untrained learner (β = 0) mostly holds the marble near its start: with ``stall_steps`` 8 its
    rollouts end after 8 steps without passing their best progress by 1 mm (read from the rewards:
    1.25 per metre of progress), where without it they run to the time limit or fall."""
    config = _config(max_episode_steps=200, episodes_per_iteration=4, stall_steps=8)
    net = config.learner.build_policy(0, LabyrinthEnv("easy").board)
    episodes, costs = collect_episodes(net, config, beta=0.0, seed=2)
    free, free_costs = collect_episodes(net, _config(max_episode_steps=200, episodes_per_iteration=4), 0.0, seed=2)
    assert free_costs["stalled"] == 0 and costs["stalled"] >= 2
    ended = 0
    for cut, whole in zip(episodes, free, strict=True):
        np.testing.assert_array_equal(cut.actions, whole.actions[: len(cut)])  # the same rollout, cut short
        progress = np.concatenate([[0.0], np.cumsum(cut.rewards) / 1.25])  # from the start, m
        running_best = np.maximum.accumulate(progress)
        if len(cut) < len(whole):  # ended by the limit (a fall ends both at the same step)
            ended += 1
            assert len(cut) >= 8
            # No step of the last 8 passed the best before them by the threshold; the one before did.
            assert progress[-8:].max() < running_best[-9] + STALL_PROGRESS_M + 1e-12
        else:
            assert len(cut) == len(whole)
    assert ended == costs["stalled"]


def test_stall_steps_changes_nothing_while_the_expert_progresses():
    """β = 1: the expert moves the marble along the path, so a 40-step stall limit never ends a rollout."""
    net = _config().learner.build_policy(0, LabyrinthEnv("easy").board)
    with_limit, costs = collect_episodes(net, _config(max_episode_steps=60, stall_steps=40), beta=1.0, seed=4)
    without, _ = collect_episodes(net, _config(max_episode_steps=60), beta=1.0, seed=4)
    assert costs["stalled"] == 0
    for a, b in zip(with_limit, without, strict=True):
        np.testing.assert_array_equal(a.actions, b.actions)


def test_demonstrations_start_the_aggregated_dataset(lab_data, tmp_path):
    config = _config(expert_data=str(lab_data), beta0=0.0)
    result = dagger(config, tmp_path / "run", progress=False)
    with open(tmp_path / "run" / "dagger.csv", newline="") as handle:
        row = next(csv.DictReader(handle))
    demo_steps = 4 * 50  # four episodes cut at 50 steps (the cheap expert does not finish the board)
    labels = int(row["labels"])
    assert 3 <= labels <= 3 * 30
    assert int(row["episodes"]) == 4 + 3
    assert int(row["dataset_steps"]) == result.dataset_steps == demo_steps + labels
    assert result.env_steps == labels  # the demonstrations cost no rollout steps of the run
    stored = json.loads((tmp_path / "run" / "config.json").read_text())
    assert DAggerConfig.from_dict(stored["dagger"]) == config  # the labyrinth expert's settings round-trip
    assert stored["torch_threads"] == 1  # what a rerun must match to reproduce the run bit for bit


def test_a_learner_with_auxiliary_heads_learns_the_states_its_rollouts_record(lab_data, tmp_path, capsys):
    """The labyrinth's rollouts record each step's 17 state values for a learner with auxiliary heads
    (its privileged targets): from state they are the very observations; the aggregated data keeps
    them, demonstrations included, and the heads learn from them."""
    learner = PretrainConfig(**{**LEARNER, "aux_heads": True}, action_type="continuous")
    config = _config(learner=learner, expert_data=str(lab_data), beta0=0.0)
    net = config.learner.build_policy(0, LabyrinthEnv("easy").board)
    fresh = {k: v.clone() for k, v in net.state_dict().items() if k.startswith("aux_")}
    episodes, _ = collect_episodes(net, config, beta=0.0, seed=3)
    for episode in episodes:
        assert episode.state_obs is not None and episode.state_obs.shape == (len(episode), 17)
        np.testing.assert_array_equal(episode.state_obs, episode.obs)
    plain, _ = collect_episodes(net, _config(), beta=0.0, seed=3)
    assert all(e.state_obs is None for e in plain)  # recorded only when a head learns from them
    dagger(config, tmp_path / "run", progress=False)
    with np.load(tmp_path / "run" / "data" / "iteration_000.npz", allow_pickle=False) as data:
        assert data["state_obs"].shape == (int(data["lengths"].sum()), 17)
    trained = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)["model"]
    assert all(not torch.equal(trained[k], v) for k, v in fresh.items())  # the heads learned
    with pytest.raises(ValueError, match=r"aux_heads=False and asymmetric_critic=False on the circular maze: its "
                                         r"rollouts record no state observations"):
        DAggerConfig(learner=PretrainConfig(task="STG1", obs="state", aux_heads=True))
    assert main(["dagger", "--run-dir", str(tmp_path / "maze"), "--task", "STG1", "--obs", "state", "--aux-heads"]) == 2
    assert "on the circular maze: its rollouts record no state observations" in capsys.readouterr().err
    assert not (tmp_path / "maze").exists()


def test_what_does_not_fit_is_refused_by_name(lab_data, tmp_path):
    with pytest.raises(ValueError, match=r"DAggerConfig\.expert on task LABYRINTH-EASY must be LabyrinthMPCConfig"):
        _config(expert=MPCConfig())
    with pytest.raises(ValueError, match=r"DAggerConfig\.expert on task STG1 must be MPCConfig"):
        DAggerConfig(learner=PretrainConfig(task="STG1", obs="state"), expert=CHEAP)
    with pytest.raises(ValueError, match="DAgger supports action_type 'discrete' only"):
        DAggerConfig(learner=PretrainConfig(task="STG1", obs="state", action_type="continuous"))
    assert isinstance(_config(expert=None).expert, LabyrinthMPCConfig)  # the puzzle's default expert
    with pytest.raises(ValueError, match="holds continuous actions, the learner has discrete ones"):
        dagger(_config("discrete", expert_data=str(lab_data)), tmp_path / "a", progress=False)
    hard = _config(expert_data=str(lab_data))
    hard = DAggerConfig(**{**hard.__dict__, "learner": PretrainConfig(**{**LEARNER, "task": "LABYRINTH-HARD"},
                                                                      action_type="continuous")})
    with pytest.raises(ValueError, match="holds LABYRINTH-EASY episodes, which cannot teach LABYRINTH-HARD"):
        dagger(hard, tmp_path / "b", progress=False)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    with pytest.raises(ValueError, match="DAggerConfig.stall_steps must be"):
        _config(stall_steps=0)
    with pytest.raises(ValueError, match="stall_steps: ending rollouts that stop progressing .* not STG1's"):
        DAggerConfig(learner=PretrainConfig(task="STG1", obs="state"), stall_steps=50)


def test_cli_dagger_on_the_labyrinth_takes_the_datasets_action_type(lab_data, tmp_path):
    run_dir = tmp_path / "run"
    assert main(["dagger", "--run-dir", str(run_dir), "--task", TASK, "--obs", "state", "--expert-data",
                 str(lab_data), "--iterations", "1", "--episodes-per-iteration", "2", "--epochs-per-iteration", "1",
                 "--max-episode-steps", "20", "--stall-steps", "5", "--eval-episodes", "0", "--off-path-rule",
                 "cyberrunner", "--no-progress"]) == 0
    stored = DAggerConfig.from_dict(json.loads((run_dir / "config.json").read_text())["dagger"])
    assert stored.stall_steps == 5 and stored.off_path_rule == "cyberrunner"
    with open(run_dir / "dagger.csv", newline="") as handle:
        assert 0 <= int(next(csv.DictReader(handle))["rollouts_stalled"]) <= 2
    assert (stored.learner.task, stored.learner.action_type, stored.learner.hidden) == (TASK, "continuous", 128)
    assert stored.expert == LabyrinthMPCConfig() and stored.expert_data == str(lab_data)
    weights = torch.load(run_dir / "checkpoint.pt", weights_only=True)["model"]
    assert "log_std" in weights


def test_the_rollouts_end_off_the_path_by_the_runs_rule(monkeypatch):
    """``off_path_rule`` reaches every env DAgger's rollouts step; on the maze it is refused by name."""
    built = []
    original = LabyrinthEnv.__init__

    def recording(self, *args, **kwargs):
        original(self, *args, **kwargs)
        built.append(self.off_path_rule)

    monkeypatch.setattr(LabyrinthEnv, "__init__", recording)
    config = _config(off_path_rule="cyberrunner", episodes_per_iteration=2, max_episode_steps=5)
    assert config.maze_options == {"off_path_rule": "cyberrunner"}
    net = config.learner.build_policy(0, LabyrinthEnv("easy").board)
    built.clear()
    collect_episodes(net, config, beta=0.5, seed=3)
    assert built and set(built) == {"cyberrunner"}
    with pytest.raises(ValueError, match=r"DAggerConfig\.off_path_rule applies to the labyrinth's tasks only, not STG1"):
        DAggerConfig(learner=PretrainConfig(task="STG1", obs="state"), off_path_rule="cyberrunner")
