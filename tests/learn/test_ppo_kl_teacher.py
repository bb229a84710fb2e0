"""PPO kickstarted from a state teacher (``kl_teacher``): the run's KL pulls the learner towards a policy
trained on the labyrinth's state while the learner observes something else, its envs record the state
for the teacher, no π^s is kept, and the setting is refused where it cannot apply."""

from __future__ import annotations

import csv
import json

import shutil

import numpy as np
import pytest
import torch

from bimgame.cli.main import main
from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.learn.actor import RecurrentActor, env_action, tilt_input
from bimgame.learn.checkpoints import load_checkpoint, save_checkpoint
from bimgame.learn.common import load_run_network
from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.learn.run_dir import TEACHER
from bimgame.learn.runs import CHECKPOINT

pytestmark = pytest.mark.usefixtures("one_torch_thread")

#: A learner on the easy layout from state *without* surroundings (17 values) taught by a state
#: policy *with* them (33 values): the teacher reads the recorded state, not the learner's input.
FLAGS = ["--task", "LABYRINTH-EASY", "--obs", "state", "--hidden", "16", "--features", "16", "--envs-per-worker", "4",
         "--n-steps", "32", "--minibatches", "2", "--eval-every", "0", "--eval-episodes", "2",
         "--max-episode-steps", "100", "--action-type", "continuous", "--log-every", "128", "--no-progress"]


@pytest.fixture
def leaning_teacher(surroundings_teacher_run, tmp_path):
    """The suite's tiny state policy made to tilt one way wherever it is (mean (0.8, −0.6), its σ):
    a teacher far from a fresh learner, whose means start near zero."""
    run_dir = tmp_path / "teacher"
    shutil.copytree(surroundings_teacher_run, run_dir)
    payload = load_checkpoint(run_dir / CHECKPOINT)
    weights = dict(payload["model"])
    weights["policy.weight"] = torch.zeros_like(weights["policy.weight"])
    weights["policy.bias"] = torch.tensor([0.8, -0.6])
    save_checkpoint(run_dir / CHECKPOINT, model=weights, step=int(payload["step"]))
    return run_dir


def test_ppo_pulls_its_learner_towards_the_state_teacher(leaning_teacher, tmp_path):
    run_dir = tmp_path / "taught"
    assert main(["train", "--algo", "ppo", "--run-dir", str(run_dir), "--steps", "2048", "--kl-coef", "5",
                 "--kl-means-only", "--kl-teacher", str(leaning_teacher), "--lr", "0.003", *FLAGS]) == 0
    stored = json.loads((run_dir / "config.json").read_text())
    assert stored["ppo"]["kl_teacher"] == str(leaning_teacher)
    assert not (run_dir / TEACHER).exists()  # the teacher is the state policy, not π^s: nothing kept
    with open(run_dir / "updates.csv") as f:
        kl = [float(row["kl"]) for row in csv.DictReader(f)]
    # A fresh learner starts far from the teacher; a heavily weighted KL brings its means close.
    assert len(kl) >= 8 and kl[0] > 0
    assert sum(kl[-3:]) / 3 < 0.2 * sum(kl[:3]) / 3, kl
    # The learner now leans as the teacher does: its greedy actions along an episode of its own.
    torch.testing.assert_close(_greedy_actions(run_dir).mean(0), torch.tensor([0.8, -0.6]), atol=0.2, rtol=0)


def _greedy_actions(run_dir, steps: int = 30) -> torch.Tensor:
    """The executed greedy actions (steps, 2) of a run's policy acting alone on the easy layout."""
    net, _, _ = load_run_network(run_dir)
    env = LabyrinthEnv("easy", obs_mode="state", action_type="continuous")
    actor = RecurrentActor(net, 1, greedy=True)
    obs, info = env.reset(seed=0)
    executed = []
    for _ in range(steps):
        actions, _, _ = actor.act(obs[None], tilt_input({"tilt": info["tilt"][None]}, env.board.max_tilt))
        done_actions = actor.executed(actions)
        executed.append(done_actions[0])
        obs, reward, terminated, truncated, info = env.step(env_action(done_actions[0]))
        if terminated or truncated:
            break
        actor.observe(done_actions, np.array([reward]), np.array([False]))
    env.close()
    return torch.stack(executed)


def test_kl_teacher_is_refused_where_it_cannot_teach(surroundings_teacher_run, tmp_path, capsys):
    base = dict(task="LABYRINTH-EASY", obs="pixels", action_type="continuous")
    with pytest.raises(ValueError, match="kl_teacher is the KL term's teacher: give kl_coef > 0"):
        PPOConfig.from_flat({**base, "kl_teacher": str(surroundings_teacher_run)})
    with pytest.raises(ValueError, match="task STG1 is the circular maze"):
        PPOConfig.from_flat({"task": "STG1", "kl_coef": 0.1, "kl_teacher": str(surroundings_teacher_run)})
    with pytest.raises(ValueError, match="kl_teacher must be a run directory or checkpoint path"):
        PPOConfig.from_flat({**base, "kl_coef": 0.1, "kl_teacher": ""})
    # A teacher of another layout: refused before the run directory is made.
    run_dir = tmp_path / "medium"
    flags = [*FLAGS]
    flags[flags.index("--task") + 1] = "LABYRINTH-MEDIUM"
    assert main(["train", "--algo", "ppo", "--run-dir", str(run_dir), "--steps", "128", "--kl-coef", "1",
                 "--kl-teacher", str(surroundings_teacher_run), *flags]) == 2
    assert "trained on LABYRINTH-EASY, the learner runs on LABYRINTH-MEDIUM" in capsys.readouterr().err
    assert not run_dir.exists()
    # An A3C run has no such setting.
    assert main(["train", "--run-dir", str(tmp_path / "a3c"), "--steps", "128", "--kl-coef", "1",
                 "--kl-teacher", str(surroundings_teacher_run), *FLAGS[:4]]) == 2
    assert "--kl-teacher: PPO's own settings" in capsys.readouterr().err


def test_a_run_with_a_state_teacher_resumes_with_it_and_refuses_another(surroundings_teacher_run, leaning_teacher,
                                                                        tmp_path):
    settings = dict(task="LABYRINTH-EASY", obs="state", hidden=16, features=16, envs_per_worker=4, n_steps=32,
                    minibatches=2, eval_every=0, eval_episodes=2, max_episode_steps=100, action_type="continuous",
                    kl_coef=1.0, kl_teacher=str(surroundings_teacher_run), log_every=128)
    run_dir = tmp_path / "run"
    train_ppo(PPOConfig.from_flat(settings, steps=256), run_dir, progress=False)
    with pytest.raises(ValueError, match="kl_teacher"):
        train_ppo(PPOConfig.from_flat({**settings, "kl_teacher": str(leaning_teacher)}, steps=512), run_dir,
                  resume=True, progress=False)
    resumed = train_ppo(PPOConfig.from_flat(settings, steps=512), run_dir, resume=True, progress=False)
    assert resumed.steps == 512
    with open(run_dir / "updates.csv") as f:
        kl = [float(row["kl"]) for row in csv.DictReader(f)]
    assert len(kl) == 512 // 128 and all(value > 0 for value in kl)  # the teacher followed after the resume too
