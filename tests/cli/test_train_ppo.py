"""``bimgame train --algo ppo``: PPO's flags, its run, resume, and the flags it refuses."""

from __future__ import annotations

import json

import pytest

from bimgame.cli.main import main
from bimgame.learn.ppo import PPOConfig

TINY = ["--obs", "state", "--hidden", "8", "--features", "8", "--envs-per-worker", "4", "--n-steps", "16",
        "--minibatches", "2", "--eval-every", "0", "--eval-episodes", "2", "--no-progress"]


def test_ppo_trains_resumes_and_takes_its_own_defaults(tmp_path, capsys):
    run_dir = tmp_path / "run"
    assert main(["train", "--algo", "ppo", "--run-dir", str(run_dir), "--steps", "128", "--clip", "0.1", *TINY]) == 0
    assert "done: 128 steps" in capsys.readouterr().out
    stored = PPOConfig.from_dict(json.loads((run_dir / "config.json").read_text())["ppo"])
    assert stored.optimization.clip == 0.1 and stored.schedule.workers == 1
    assert stored.optimization.lr == PPOConfig().optimization.lr  # PPO's default, not A3C's
    assert main(["train", "--algo", "ppo", "--run-dir", str(run_dir), "--resume", "--steps", "192",
                 "--no-progress"]) == 0
    assert "done: 192 steps" in capsys.readouterr().out
    resumed = PPOConfig.from_dict(json.loads((run_dir / "config.json").read_text())["ppo"])
    assert resumed.optimization.clip == 0.1


def test_ppo_refuses_a3c_only_flags_by_name(tmp_path, capsys):
    assert main(["train", "--algo", "ppo", "--run-dir", str(tmp_path / "a"), "--rmsprop-alpha", "0.9", *TINY]) == 2
    assert "unknown PPO settings ['rmsprop_alpha']" in capsys.readouterr().err
    assert not (tmp_path / "a").exists()


def test_ppo_shapes_its_reward_like_a3c_and_a_resume_keeps_it(tmp_path, capsys):
    run_dir = tmp_path / "geo"
    assert main(["train", "--algo", "ppo", "--run-dir", str(run_dir), "--geodesic-reward", "--steps", "128",
                 *TINY]) == 0
    assert "reward shaped: geodesic_coef=10.0" in capsys.readouterr().err
    assert json.loads((run_dir / "config.json").read_text())["reward"]["geodesic_coef"] == 10.0
    assert main(["train", "--algo", "ppo", "--run-dir", str(run_dir), "--resume", "--geodesic-reward", "3",
                 "--steps", "192", "--no-progress"]) == 2
    assert "--resume must keep the run's reward" in capsys.readouterr().err


def test_a3c_refuses_ppos_own_flags_by_name_instead_of_ignoring_them(tmp_path, capsys):
    assert main(["train", "--run-dir", str(tmp_path / "a3c"), "--clip", "0.1", "--policy-lag", "1", "--steps", "64",
                 "--obs", "state", "--no-progress"]) == 2
    assert "--clip, --policy-lag: PPO's own settings; add --algo ppo" in capsys.readouterr().err
    assert not (tmp_path / "a3c").exists()


def test_ppo_trains_continuous_actions_and_a3c_refuses_them(tmp_path, capsys):
    run_dir = tmp_path / "run"
    assert main(["train", "--algo", "ppo", "--action-type", "continuous", "--run-dir", str(run_dir), "--steps", "128",
                 *TINY]) == 0
    assert "done: 128 steps" in capsys.readouterr().out
    stored = PPOConfig.from_dict(json.loads((run_dir / "config.json").read_text())["ppo"])
    assert stored.network.action_type == "continuous"
    assert main(["evaluate", str(run_dir), "--episodes", "2"]) == 0
    at = TINY.index("--minibatches")
    a3c_flags = TINY[:at] + TINY[at + 2 :]  # A3C has no minibatches
    assert main(["train", "--run-dir", str(tmp_path / "a3c"), "--action-type", "continuous", *a3c_flags]) == 2
    assert "A3C supports action_type 'discrete' only; got 'continuous' (use --algo ppo)" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # argparse refuses it, naming the choices
        main(["train", "--algo", "ppo", "--run-dir", str(tmp_path / "x"), "--action-type", "box", *TINY])
    assert "invalid choice: 'box' (choose from 'discrete', 'continuous')" in capsys.readouterr().err
