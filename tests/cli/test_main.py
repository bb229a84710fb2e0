"""The command line: maze picture, rollout summary and GIF, demo, and clear errors."""

from __future__ import annotations

import pytest
from PIL import Image

from bimgame.cli.main import build_parser, main


def test_maze_writes_a_png(tmp_path):
    out = tmp_path / "maze.png"
    assert main(["maze", "--out", str(out)]) == 0
    image = Image.open(out)
    assert image.format == "PNG" and image.size[0] > 500


def test_rollout_prints_a_summary_and_writes_a_gif(tmp_path, capsys):
    gif = tmp_path / "run.gif"
    assert main(["rollout", "--task", "stg1", "--policy", "random", "--episodes", "2",
                 "--max-steps", "20", "--gif", str(gif)]) == 0
    out = capsys.readouterr().out
    assert "random policy on STG1" in out and "success" in out
    image = Image.open(gif)
    assert image.format == "GIF" and image.n_frames == 21  # reset frame + 20 steps


def test_demo_writes_both_files(tmp_path):
    assert main(["demo", "--out", str(tmp_path), "--task", "STG1"]) == 0
    assert (tmp_path / "maze.png").stat().st_size > 0 and (tmp_path / "episode.gif").stat().st_size > 0


@pytest.mark.parametrize("argv, message", [
    (["rollout", "--task", "STG7"], "invalid choice: 'STG7'"),
    (["rollout", "--episodes", "0"], "expected a positive integer"),
    (["rollout", "--policy", "oracle"], "invalid choice: 'oracle'"),
    (["fly"], "invalid choice: 'fly'"),
])
def test_bad_flags_name_the_value_and_the_choices(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_every_verb_prints_its_help(capsys):
    """Every verb's --help renders: help texts come from docstrings, where a bare % would break
    argparse's formatting."""
    verbs = next(a for a in build_parser()._actions if a.dest == "verb").choices
    assert {"train", "reproduce", "generate", "pretrain", "play"} <= set(verbs)
    for verb in verbs:
        with pytest.raises(SystemExit) as exit_info:
            main([verb, "--help"])
        assert exit_info.value.code == 0, verb
        assert "usage:" in capsys.readouterr().out
