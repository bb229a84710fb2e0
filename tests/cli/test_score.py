"""``bimgame score``: a table, JSON, and clear errors."""

from __future__ import annotations

import json

import pytest

from bimgame.cli.main import main


def test_score_prints_and_writes_json(tmp_path, capsys):
    out = tmp_path / "score.json"
    assert main(["score", "geodesic", "--task", "stg1", "--episodes", "4", "--out", str(out), "--no-progress"]) == 0
    result = json.loads(out.read_text())
    assert result["policy"] == "geodesic" and result["task"] == "STG1" and result["episodes"] == 4
    assert result["normalised_score"] is not None
    assert "geodesic on STG1" in capsys.readouterr().out


def test_bad_policy_and_out_are_refused(tmp_path, capsys):
    assert main(["score", "nonsense", "--episodes", "2", "--no-progress"]) == 2
    assert "is none of" in capsys.readouterr().err
    assert main(["score", "random", "--out", str(tmp_path), "--episodes", "2", "--no-progress"]) == 2
    assert "is a directory" in capsys.readouterr().err
    assert main(["score", "--episodes", "2"]) == 2
    assert "POLICY is required" in capsys.readouterr().err


def test_a_ppo_run_scores_like_an_a3c_run_from_its_directory_or_its_checkpoint(tmp_path):
    """A PPO run directory (kind ``ppo``) or its checkpoint is a POLICY like an A3C run's."""
    from bimgame.learn.ppo import PPOConfig, train_ppo

    run = tmp_path / "ppo-run"
    config = PPOConfig.from_flat({"task": "STG1", "obs": "state", "hidden": 16, "features": 16, "steps": 128,
                                  "envs_per_worker": 4, "n_steps": 32, "eval_every": 0, "eval_episodes": 1})
    train_ppo(config, run, progress=False)
    scores = []
    for policy, extra in ((run, []), (run / "checkpoint.pt", ["--sampled"])):
        out = tmp_path / f"score-{len(scores)}.json"
        argv = ["score", str(policy), "--episodes", "2", "--out", str(out), "--no-progress", *extra]
        assert main(argv) == 0
        scores.append(json.loads(out.read_text()))
    assert [s["policy"] for s in scores] == [str(run), str(run / "checkpoint.pt")]
    assert all(s["episodes"] == 2 and s["normalised_score"] is not None for s in scores)
    assert main(["score", str(run), "--obs", "pixels", "--episodes", "2", "--no-progress"]) == 2  # trained on state


def test_score_on_test_mazes_names_them_in_the_table_and_the_json(tmp_path, capsys):
    out = tmp_path / "score.json"
    argv = ["score", "noop", "--mazes", "test", "--episodes", "3", "--out", str(out), "--no-progress"]
    assert main(argv) == 0
    result = json.loads(out.read_text())
    assert (result["mazes"], result["maze_split"], result["maze_set"]) == ("test", "test", "held-out test mazes 0..2")
    assert result["episodes"] == 3 and result["success_rate"] == 0.0
    assert "held-out test mazes 0..2" in capsys.readouterr().out
    assert main(["score", "noop", "--episodes", "2", "--out", str(out), "--no-progress"]) == 0
    assert json.loads(out.read_text())["maze_split"] == "merl"


def test_a_bad_mazes_value_is_refused_with_the_allowed_forms(capsys):
    for bad in ("mars", "train", "test:0", "train:a:3"):
        with pytest.raises(SystemExit) as exit_info:
            main(["score", "random", "--mazes", bad, "--episodes", "2", "--no-progress"])
        assert exit_info.value.code == 2
        err = capsys.readouterr().err
        assert "--mazes" in err and f"{bad!r}" in err and "train:START:N" in err


def test_a_run_trained_on_mazes_scores_on_held_out_and_its_own_mazes(tmp_path):
    """A PPO run with --num-mazes 3 (its network reads the maze's encoding) scores on the held-out
    test mazes, on its three training mazes and on MERL's maze (given MERL's encoding)."""
    from bimgame.learn.ppo import PPOConfig, train_ppo

    run = tmp_path / "maze-run"
    config = PPOConfig.from_flat(
        {
            "task": "STG1",
            "obs": "state",
            "hidden": 16,
            "features": 16,
            "envs_per_worker": 4,
            "n_steps": 16,
            "minibatches": 2,
            "eval_every": 0,
            "eval_episodes": 2,
            "log_every": 64,
            "steps": 64,
            "num_mazes": 3,
        }
    )
    train_ppo(config, run, progress=False)
    results = {}
    for mazes in ("test", "train:3", "merl"):
        out = tmp_path / f"{mazes.replace(':', '-')}.json"
        assert main(["score", str(run), "--mazes", mazes, "--episodes", "2", "--out", str(out), "--no-progress"]) == 0
        results[mazes] = json.loads(out.read_text())
    assert results["test"]["maze_set"] == "held-out test mazes 0..1" and results["test"]["notes"] == []
    assert results["train:3"]["maze_set"] == "training mazes 0..2 (2 of them played)"
    assert results["train:3"]["notes"] == []
    assert len(results["merl"]["notes"]) == 1 and "MERL's maze's encoding" in results["merl"]["notes"][0]
    assert all(r["episodes"] == 2 and 0.0 <= r["success_rate"] <= 1.0 for r in results.values())


def test_the_labyrinth_refuses_the_mazes_flags_and_runs_of_the_other_puzzle_by_name(tmp_path, capsys):
    """On a labyrinth task, --mazes and --measure-references (the circular maze's) are refused by name,
    as is a run trained on the circular maze; CyberRunner's observation is refused on the maze."""
    from bimgame.learn.ppo import PPOConfig, train_ppo

    base = ["score", "random", "--task", "LABYRINTH-EASY", "--episodes", "1", "--no-progress"]
    assert main([*base, "--mazes", "test"]) == 2
    assert "--mazes test: the circular maze's random mazes" in capsys.readouterr().err
    assert main([*base, "--measure-references", "--out", str(tmp_path / "refs.json")]) == 2
    assert "--measure-references measures the circular maze's" in capsys.readouterr().err
    assert main(["score", "random", "--obs", "cyberrunner", "--episodes", "1", "--no-progress"]) == 2
    assert "'cyberrunner' is CyberRunner's observation of the labyrinth" in capsys.readouterr().err
    run = tmp_path / "maze-run"
    config = PPOConfig.from_flat({"task": "STG1", "obs": "state", "hidden": 16, "features": 16, "steps": 64,
                                  "envs_per_worker": 4, "n_steps": 16, "eval_every": 0, "eval_episodes": 1})
    train_ppo(config, run, progress=False)
    assert main(["score", str(run), "--task", "LABYRINTH-HARD", "--episodes", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "is a run on STG1 (the circular maze), but --task LABYRINTH-HARD is the labyrinth's" in err
    assert "--task STG1" in err
