"""``bimgame score``: a table, JSON, and clear errors."""

from __future__ import annotations

import json

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
