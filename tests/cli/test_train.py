from __future__ import annotations

import argparse
import json

import pytest

from bimgame.cli.argtypes import step_count
from bimgame.cli.flags import given_settings
from bimgame.cli.main import build_parser, main
from bimgame.learn.a3c import A3CConfig, resolve_config, train


def a3c_config_from(args: argparse.Namespace) -> A3CConfig:
    """What ``bimgame train`` makes of its flags."""
    given = given_settings(args, A3CConfig, A3CConfig.flat_names())
    return resolve_config(given, args.run_dir, resume=args.resume, init=args.init)


@pytest.mark.parametrize("text, value", [("300000", 300_000), ("200k", 200_000), ("5M", 5_000_000),
                                         ("2.5m", 2_500_000), ("1e6", 1_000_000), ("1E6", 1_000_000),
                                         ("1e12", 10**12), ("1000G", 10**12)])
def test_step_counts(text, value):
    assert step_count(text) == value


@pytest.mark.parametrize("text", ["", "five", "-3", "0", "1.5", "2x"])
def test_bad_step_counts_are_rejected(text):
    with pytest.raises(argparse.ArgumentTypeError, match="step"):
        step_count(text)


@pytest.mark.parametrize("text", ["1e30", "1e400", "2e12", "1001G", "99999999999999999999"])
def test_step_counts_are_bounded_by_1e12(text):
    """--steps 1e30 used to be accepted (and 1e400 raised OverflowError, a traceback)."""
    with pytest.raises(argparse.ArgumentTypeError, match=r"at most 1e12 \(10\^12\) steps"):
        step_count(text)


def test_train_flags_become_the_config(tmp_path):
    args = build_parser().parse_args(["train", "--run-dir", str(tmp_path / "r"), "--task", "stg2", "--obs", "state",
                                      "--steps", "1M", "--lr", "3e-4", "--no-tilt-input", "--envs-per-worker", "8"])
    config = a3c_config_from(args)
    network, schedule = config.network, config.schedule
    assert (config.task, network.obs, schedule.steps, config.optimization.lr, network.tilt_input,
            schedule.envs_per_worker) == ("STG2", "state", 1_000_000, 3e-4, False, 8)
    assert network.hidden == 128  # the state network's size unless given


def test_bad_flags_name_the_allowed_values(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["train", "--run-dir", "x", "--obs", "rgb"])
    assert "invalid choice: 'rgb'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        build_parser().parse_args(["train", "--run-dir", "x", "--lr", "-1"])
    assert "expected a positive" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # a negative seed used to crash inside the workers
        build_parser().parse_args(["train", "--run-dir", "x", "--seed", "-1"])
    assert "--seed: expected a non-negative integer" in capsys.readouterr().err


def test_resume_takes_the_stored_settings_and_evaluate_reports(tmp_path, capsys):
    run_dir = tmp_path / "run"
    config = A3CConfig.from_flat(task="STG1", obs="state", steps=400, workers=1, envs_per_worker=2, n_steps=10,
                                 hidden=16, features=16, eval_every=0, lr=1e-3)
    train(config, run_dir, progress=False)
    args = build_parser().parse_args(["train", "--run-dir", str(run_dir), "--resume", "--steps", "800"])
    resumed = a3c_config_from(args)
    assert resumed == A3CConfig.from_flat({**config.to_dict(), "steps": 800})
    out = tmp_path / "eval.json"
    assert main(["evaluate", str(run_dir), "--episodes", "3", "--out", str(out), "--gif", str(tmp_path / "e.gif")]) == 0
    result = json.loads(out.read_text())
    assert result["episodes"] == 3 and result["step"] >= 400 and len(result["lengths"]) == 3
    assert (tmp_path / "e.gif").stat().st_size > 1000
    printed = " ".join(capsys.readouterr().out.split())
    assert "greedy" in printed and "STG1" in printed and "wrote" in printed
    assert main(["evaluate", str(tmp_path)]) == 2
    assert "is not a training run" in capsys.readouterr().err


def test_resume_refuses_init_instead_of_ignoring_it(tmp_path, capsys):
    assert main(["train", "--run-dir", str(tmp_path / "r"), "--resume", "--init", str(tmp_path / "pi")]) == 2
    err = capsys.readouterr().err
    assert "--init" in err and "a resumed run continues from its own checkpoint" in err
