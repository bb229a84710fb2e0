"""A trained policy as DAgger's expert (bimgame.learn.dagger.teacher): its labels are its own greedy
actions in each rollout's state, read in its own observation (state with surroundings while the
learner sees pixels), its recurrent inputs follow the executed actions, and a teacher of another
layout, kind of action or puzzle is refused by name."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch

from bimgame.cli.main import main
from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.envs.puzzles import puzzle
from bimgame.learn.actor import RecurrentActor, tilt_input
from bimgame.learn.common import load_run_network
from bimgame.learn.dagger import DAggerConfig, collect_episodes
from bimgame.learn.dagger.teacher import PolicyTeacher
from bimgame.learn.supervised import PretrainConfig

TASK = "LABYRINTH-EASY"
LEARNER = dict(task=TASK, hidden=16, features=16, bptt=20, batch_episodes=4, eval_episodes=0, seed=0,
               asymmetric_critic=False, action_type="continuous")

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture
def teacher_run(surroundings_teacher_run):
    """The suite's tiny PPO policy from state with surroundings on the easy layout."""
    return surroundings_teacher_run


def test_the_teacher_labels_with_its_own_greedy_actions_in_its_own_observation(teacher_run):
    teacher = PolicyTeacher(teacher_run, TASK, "continuous", count=2)
    # The learner's boards observe pixels; the teacher reads the same physics state with surroundings.
    boards = [LabyrinthEnv("easy", obs_mode="pixels"), LabyrinthEnv("easy", obs_mode="pixels")]
    own = [LabyrinthEnv("easy", obs_mode="state", surroundings=True) for _ in boards]
    net, _, _ = load_run_network(teacher_run)
    alone = RecurrentActor(net, 2, greedy=True)  # the teacher acting by itself on its own observations
    infos = [board.reset(seed=s)[1] for s, board in enumerate(boards)]
    observations = [env.reset(seed=s)[0] for s, env in enumerate(own)]
    rng, max_tilt = np.random.default_rng(0), puzzle(TASK).spec.max_tilt
    for _ in range(25):
        tilt = tilt_input({"tilt": np.stack([info["tilt"] for info in infos])}, max_tilt)
        labels = torch.as_tensor(np.stack(teacher.labels(boards, infos, tilt, np.ones(2, dtype=bool))))
        actions, _, _ = alone.act(np.stack(observations), tilt)
        torch.testing.assert_close(labels, alone.executed(actions))
        assert labels.shape == (2, 2) and labels.abs().max() <= 1.0
        # Execute something else than the labels (a learner's actions): the teacher's recurrent
        # inputs follow what was executed, as the actor's alone.
        executed = torch.as_tensor(rng.uniform(-1, 1, (2, 2)), dtype=torch.float32)
        rewards, done = np.zeros(2), np.zeros(2, dtype=bool)
        for i, (board, env) in enumerate(zip(boards, own, strict=True)):
            _, rewards[i], terminated, _, infos[i] = board.step(executed[i].numpy())
            observations[i], twin_reward, _, _, _ = env.step(executed[i].numpy())
            assert twin_reward == rewards[i] and not terminated
        teacher.observe(executed, rewards, done)
        alone.observe(executed, rewards, done)
    teacher.close()


def test_dagger_with_a_teacher_labels_every_state_and_plans_nothing(teacher_run):
    learner = PretrainConfig(**LEARNER, obs="cyberrunner", aux_heads=False)
    config = DAggerConfig(learner=learner, teacher=str(teacher_run), episodes_per_iteration=3, max_episode_steps=30,
                          iterations=1, epochs_per_iteration=1, eval_episodes=0)
    net = learner.build_policy(0, LabyrinthEnv("easy").board)
    episodes, costs = collect_episodes(net, config, beta=1.0, seed=3)
    assert costs["labels"] == costs["env_steps"] == sum(len(e) for e in episodes) and costs["expert_sim_steps"] == 0
    for episode in episodes:  # β = 1: the teacher's labels were executed
        np.testing.assert_array_equal(episode.executed, episode.actions)
        assert episode.actions.dtype == np.float32 and np.all(np.abs(episode.actions) <= 1.0)
    again, _ = collect_episodes(net, config, beta=1.0, seed=3)
    for a, b in zip(episodes, again, strict=True):
        np.testing.assert_array_equal(a.actions, b.actions)  # same seed, same labels
    # β = 0: the learner's sampled actions are executed, the labels stay the teacher's (a greedy policy's).
    learner_run, _ = collect_episodes(net, config, beta=0.0, seed=3)
    executed = np.concatenate([e.executed for e in learner_run])
    labels = np.concatenate([e.actions for e in learner_run])
    assert np.mean(np.abs(executed - labels) > 1e-6) > 0.9


def test_a_teacher_that_does_not_fit_is_refused_by_name(teacher_run, tmp_path):
    learner = PretrainConfig(**LEARNER, obs="state", aux_heads=False)
    with pytest.raises(ValueError, match="trained on LABYRINTH-EASY, the learner runs on LABYRINTH-MEDIUM"):
        PolicyTeacher(teacher_run, "LABYRINTH-MEDIUM", "continuous", 1)
    with pytest.raises(ValueError, match="acts with continuous actions, the learner with discrete"):
        PolicyTeacher(teacher_run, TASK, "discrete", 1)
    with pytest.raises(ValueError, match="does not exist"):
        DAggerConfig(learner=learner, teacher=str(tmp_path / "missing"))
    with pytest.raises(ValueError, match="labels the labyrinth's rollouts"):
        DAggerConfig(learner=PretrainConfig(task="STG1", obs="state", aux_heads=False, asymmetric_critic=False),
                     teacher=str(teacher_run))
    assert "teacher" in DAggerConfig.FIXED_ON_RESUME


def test_bimgame_dagger_takes_a_teacher_and_refuses_mpc_settings_beside_it(teacher_run, tmp_path, capsys):
    run_dir = tmp_path / "dagger"
    flags = ["dagger", "--task", TASK, "--obs", "state", "--action-type", "continuous", "--hidden", "16",
             "--features", "16", "--iterations", "1", "--episodes-per-iteration", "2", "--epochs-per-iteration", "1",
             "--max-episode-steps", "20", "--eval-episodes", "0", "--no-progress", "--teacher", str(teacher_run)]
    assert main([*flags, "-K", "8", "--run-dir", str(tmp_path / "refused")]) == 2
    assert "--teacher labels the rollouts instead of the MPC expert" in capsys.readouterr().err
    assert not (tmp_path / "refused").exists()
    assert main([*flags, "--run-dir", str(run_dir)]) == 0
    stored = json.loads((run_dir / "config.json").read_text())
    assert stored["dagger"]["teacher"] == str(teacher_run)
    with (run_dir / "dagger.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert int(rows[-1]["labels"]) > 0 and int(rows[-1]["expert_sim_steps"]) == 0
