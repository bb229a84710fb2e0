"""Pre-training on the labyrinth's expert data (continuous actions) and fine-tuning it with PPO: π^s
clones the expert's tilt changes, starts a PPO run that keeps it with the Gaussian KL, and what does
not fit (the other puzzle's data, another action kind, V̂) is refused by name."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch

from bimgame.cli.main import main
from bimgame.expert.labyrinth_datasets import generate_labyrinth_dataset, load_labyrinth_sequences
from bimgame.expert.labyrinth_mpc import LabyrinthMPCConfig
from bimgame.learn.checkpoints import load_checkpoint
from bimgame.learn.common import load_run_network
from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.learn.pretrain import pretrain
from bimgame.learn.runs import read_run_config
from bimgame.learn.supervised import PretrainConfig

TASK = "LABYRINTH-EASY"
SMALL = dict(task=TASK, obs="state", action_type="continuous", hidden=32, features=32, bptt=20, batch_episodes=4,
             epochs=15, patience=15, lr=3e-3, eval_episodes=0, seed=0)


@pytest.fixture(scope="module")
def lab_data(tmp_path_factory):
    """Six short expert episodes (60 steps each, a cheap expert) on the easy layout."""
    return generate_labyrinth_dataset(tmp_path_factory.mktemp("lab") / "data", TASK, 6, seed=3, max_steps=60,
                                      config=LabyrinthMPCConfig(n_samples=6, horizon=10), workers=1, progress=False)


@pytest.fixture(scope="module")
def pi_s(lab_data, tmp_path_factory):
    out = tmp_path_factory.mktemp("lab") / "pi_s"
    return pretrain(PretrainConfig(**SMALL), lab_data, out, progress=False)


def test_pi_s_clones_the_experts_continuous_actions(pi_s, lab_data):
    # Six short episodes are too few to predict a sampling expert's tilt changes well (the synthetic
    # expert of test_supervised is), but −log π of the held-out episodes' actions falls.
    assert pi_s.best_epoch > 0
    with open(pi_s.run_dir / "pretrain.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert min(float(row["val_loss"]) for row in rows[1:]) < float(rows[0]["val_loss"]) - 0.5
    assert float(rows[-1]["train_loss"]) < float(rows[1]["train_loss"]) - 0.5
    net = load_run_network(pi_s.run_dir)[0]
    assert net.config.action_type == "continuous"
    assert torch.all(net.log_std < -0.5)  # sharper than the untrained policy (−0.5)
    sequences = load_labyrinth_sequences(lab_data, gamma=0.99)
    assert sequences[0].actions.dtype == np.float32 and sequences[0].actions.shape[1] == 2


def test_ppo_fine_tunes_pi_s_keeping_it_with_the_gaussian_kl(pi_s, tmp_path):
    config = PPOConfig.from_flat(dict(task=TASK, obs="state", action_type="continuous", hidden=32, features=32,
                                      envs_per_worker=2, n_steps=32, minibatches=2, sequence_length=8, steps=128,
                                      eval_every=0, eval_episodes=2, log_every=64, max_episode_steps=40,
                                      kl_coef=0.5))
    train_ppo(config, tmp_path / "tuned", init=pi_s.run_dir, progress=False)
    teacher = load_checkpoint(tmp_path / "tuned" / "teacher.pt")["model"]
    start = load_checkpoint(pi_s.run_dir)["model"]
    assert all(torch.equal(teacher[key], start[key]) for key in start)
    with open(tmp_path / "tuned" / "updates.csv") as handle:
        kl = [float(row["kl"]) for row in csv.DictReader(handle)]
    # Averaged over each update's minibatches: π starts as π^s and moves away from it a little.
    assert len(kl) == 2 and all(0 < value < 0.05 for value in kl)


def test_pretraining_refuses_data_that_does_not_fit(lab_data, tmp_path, capsys):
    with pytest.raises(ValueError, match="holds LABYRINTH-EASY episodes, which cannot teach LABYRINTH-HARD"):
        pretrain(PretrainConfig(**{**SMALL, "task": "LABYRINTH-HARD"}), lab_data, tmp_path / "a", progress=False)
    with pytest.raises(ValueError, match="holds LABYRINTH-EASY episodes, which cannot teach STG1"):
        pretrain(PretrainConfig(**{**SMALL, "task": "STG1"}), lab_data, tmp_path / "b", progress=False)
    with pytest.raises(ValueError, match="holds continuous actions; set action_type='continuous'"):
        pretrain(PretrainConfig(**{**SMALL, "action_type": "discrete"}), lab_data, tmp_path / "c", progress=False)
    with pytest.raises(ValueError, match="V̂ shapes the circular maze's rewards only"):
        pretrain(PretrainConfig(**SMALL, target="value"), lab_data, tmp_path / "d", progress=False)
    assert not any((tmp_path / name).exists() and any((tmp_path / name).iterdir()) for name in "abcd")


def test_the_command_line_takes_the_datasets_action_type(lab_data, tmp_path, capsys):
    code = main(["pretrain", "--data", str(lab_data), "--out", str(tmp_path / "cli"), "--task", TASK,
                 "--hidden", "16", "--features", "16", "--epochs", "1", "--eval-episodes", "0", "--no-progress"])
    assert code == 0
    out = capsys.readouterr().out
    assert "each tilt change within 0.25 of the expert's" in out
    assert "bimgame train --algo ppo --action-type continuous --task LABYRINTH-EASY" in out
    assert load_run_network(tmp_path / "cli")[0].config.action_type == "continuous"


def test_pi_s_from_pixels_with_the_marbles_motion_reads_two_frames(lab_data, tmp_path, capsys):
    """``--obs pixels --motion``: the dataset's frames re-rendered in pairs (the previous step's, then the
    step's) train a two-frame conv network, and the printed next step keeps the motion."""
    code = main(["pretrain", "--data", str(lab_data), "--out", str(tmp_path / "px"), "--task", TASK, "--obs",
                 "pixels", "--motion", "--hidden", "8", "--features", "8", "--epochs", "1", "--eval-episodes", "0",
                 "--no-progress"])
    assert code == 0
    assert "--motion" in capsys.readouterr().out
    net, run, _ = load_run_network(tmp_path / "px")
    assert (run.network.motion, net.config.obs_shape) == (True, (2, 84, 84))


def test_the_same_seed_and_threads_pretrain_the_same_weights(lab_data, tmp_path, one_torch_thread):
    """Same seed, same result: two pre-trainings of CyberRunner's observation with the marble's motion
    (the crop re-rendered from stored states, episodes split and shuffled by the seed) end bit for bit
    equal, and each run records the torch threads it computed with — a different count sums in another
    order, so a rerun has to match it to reproduce."""
    settings = {**SMALL, "obs": "cyberrunner", "motion": True, "hidden": 16, "features": 16, "epochs": 2}
    runs = [pretrain(PretrainConfig(**settings), lab_data, tmp_path / name, progress=False) for name in "ab"]
    first, second = (load_checkpoint(run.run_dir)["model"] for run in runs)
    assert all(torch.equal(first[key], second[key]) for key in first)
    assert runs[0].best_epoch == runs[1].best_epoch
    assert read_run_config(runs[0].run_dir)["torch_threads"] == 1
