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
