"""Where a learner's update runs (bimgame.learn.devices) and PPO's learning copy on that device: the
device names, their refusals, and a run whose update trains a separate copy of the network (as on a
GPU) giving exactly the run where the acting network learns itself."""

from __future__ import annotations

import copy
import csv

import pytest
import torch

from bimgame.learn.checkpoints import load_checkpoint
from bimgame.learn.devices import resolve_device
from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.learn.ppo import training as ppo_training

TINY = dict(task="STG1", obs="state", hidden=16, features=16, envs_per_worker=4, n_steps=16, minibatches=2,
            sequence_length=8, steps=192, eval_every=0, eval_episodes=2, log_every=64, seed=2)


def test_device_names_resolve_and_a_missing_gpu_is_named():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(ValueError, match=r"unknown device 'gpu'; allowed: cpu, cuda, auto"):
        resolve_device("gpu")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="device 'cuda' asked for, but torch sees no CUDA device"):
            resolve_device("cuda")


def test_ppo_settings_check_the_device():
    assert PPOConfig.from_flat(TINY, device="auto").device == "auto"
    with pytest.raises(ValueError, match=r"PPOConfig\.device must be one of \('cpu', 'cuda', 'auto'\), got 'tpu'"):
        PPOConfig.from_flat(TINY, device="tpu")
    with pytest.raises(ValueError, match="device 'cuda' takes one process"):
        PPOConfig.from_flat(TINY, device="cuda", workers=2)


def _rows(path):
    with open(path) as handle:
        return list(csv.DictReader(handle))


def test_an_update_on_a_learning_copy_gives_the_run_of_the_acting_network_learning_itself(tmp_path, monkeypatch):
    config = PPOConfig.from_flat(TINY)
    train_ppo(config, tmp_path / "itself", progress=False)
    copies = []

    def learning_copy(net, device, separate=False):  # what a GPU run does, on the CPU: a separate copy learns
        copies.append(copy.deepcopy(net).to(device))
        return copies[-1]

    monkeypatch.setattr(ppo_training, "learning_copy", learning_copy)
    train_ppo(config, tmp_path / "copy", progress=False)
    assert len(copies) == 1
    weights = [load_checkpoint(tmp_path / name)["model"] for name in ("itself", "copy")]
    assert all(torch.equal(weights[0][key], weights[1][key]) for key in weights[0])
    assert all(torch.equal(copies[0].state_dict()[key], weights[1][key]) for key in weights[1])
    assert _rows(tmp_path / "itself" / "episodes.csv") == _rows(tmp_path / "copy" / "episodes.csv")
