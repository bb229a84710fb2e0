"""Evaluating the MPC expert: seeded episodes and their results, the summary statistics, the
length histogram (the paper's Fig. 1b) and the results file."""

from __future__ import annotations

import dataclasses
import errno
import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import bimgame.cli.expert as cli_expert
import bimgame.expert.evaluation as evaluation
import bimgame.util.images as images
from bimgame.cli.main import main
from bimgame.expert.evaluation import EpisodeResult, evaluate_expert, plot_length_histogram, summarise, write_results
from bimgame.expert.mpc import MPCConfig, run_expert_episode
from bimgame.util.seeding import episode_seed

#: A weak, cheap expert (K=4, H=8) and a short time limit: some episodes pass STG1's wall, some not.
CHEAP = MPCConfig(n_samples=4, horizon=8)
LIMIT = 60
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _result(index: int, success: bool, length: int, seconds: float = 0.5) -> EpisodeResult:
    return EpisodeResult(index=index, seed=1000 + index, success=success, length=length,
                         episode_return=1.0 if success else 0.0, seconds=seconds)


def _comparable(results: list[EpisodeResult]) -> list[tuple]:
    """Everything but the wall time."""
    return [(r.index, r.seed, r.success, r.length, r.episode_return) for r in results]


# ------------------------------------------------------------------------------ evaluate_expert
@pytest.fixture(scope="module")
def two_episodes() -> list[EpisodeResult]:
    return evaluate_expert("STG1", 2, CHEAP, seed=0, workers=1, max_steps=LIMIT, progress=False)


def test_evaluate_expert_runs_the_seeded_episodes_in_order(two_episodes):
    results = two_episodes
    assert len(results) == 2
    assert [r.index for r in results] == [0, 1]
    assert [r.seed for r in results] == [episode_seed(0, 0), episode_seed(0, 1)]
    # With this seed the cheap expert solves one episode and not the other: both cases are checked.
    assert sorted(r.success for r in results) == [False, True]
    for r in results:
        assert 1 <= r.length <= LIMIT and r.seconds > 0
        # STG1: reward 1 exactly when the marble passes the wall, which ends the episode.
        assert r.episode_return == (1.0 if r.success else 0.0)
        if not r.success:
            assert r.length == LIMIT
    # Each result is the expert's episode from that seed with these settings.
    for r in results:
        episode = run_expert_episode("STG1", r.seed, CHEAP, max_steps=LIMIT)
        assert (r.success, r.length, r.episode_return) == (bool(episode["success"]), len(episode["actions"]),
                                                           float(episode["rewards"].sum()))


def test_evaluate_expert_is_deterministic_for_a_seed(two_episodes):
    again = evaluate_expert("stg1", 2, CHEAP, seed=0, workers=1, max_steps=LIMIT, progress=False)
    assert _comparable(again) == _comparable(two_episodes)
    other = evaluate_expert("STG1", 2, CHEAP, seed=1, workers=1, max_steps=LIMIT, progress=False)
    assert [r.seed for r in other] == [episode_seed(1, 0), episode_seed(1, 1)]
    assert [r.seed for r in other] != [r.seed for r in two_episodes]


@pytest.mark.parametrize("kwargs, message", [
    ({"task": "STG9"}, "STG9"),
    ({"episodes": 0}, "episodes must be a positive integer, got 0"),
    ({"episodes": 1.5}, "episodes must be a positive integer, got 1.5"),
    ({"workers": 0}, "workers must be an integer >= 1, got 0"),
])
def test_evaluate_expert_refuses_bad_arguments_by_name(kwargs, message):
    args = {"task": "STG1", "episodes": 1, **kwargs}
    with pytest.raises(ValueError, match=message):
        evaluate_expert(args.pop("task"), args.pop("episodes"), CHEAP, max_steps=5, progress=False, **args)


# ------------------------------------------------------------------------------------ summarise
def test_summarise_computes_the_rates_and_the_lengths_of_solved_episodes():
    lengths = [40, 300, 20, 90, 300, 60]
    solved = [True, False, True, True, False, True]
    results = [_result(i, s, n, seconds=0.1 * (i + 1)) for i, (s, n) in enumerate(zip(solved, lengths))]
    summary = summarise(results)
    assert summary["episodes"] == 6
    assert summary["success_rate"] == pytest.approx(4 / 6)
    assert summary["mean_length"] == pytest.approx(sum(lengths) / 6)
    # Solved lengths 20, 40, 60, 90: the failures' 300 steps do not count.
    assert summary["median_length_solved"] == pytest.approx(50.0)
    assert summary["p90_length_solved"] == pytest.approx(np.percentile([20, 40, 60, 90], 90))
    assert 60 < summary["p90_length_solved"] <= 90
    assert summary["max_length_solved"] == 90 and isinstance(summary["max_length_solved"], int)
    assert summary["mean_return"] == pytest.approx(4 / 6)
    # Wall time per decision: all the episodes' seconds over all their steps.
    assert summary["ms_per_decision"] == pytest.approx(1e3 * 0.1 * (1 + 2 + 3 + 4 + 5 + 6) / sum(lengths))
    json.dumps(summary, allow_nan=False)  # plain numbers, no numpy types


def test_summarise_with_nothing_solved_has_no_solved_lengths():
    summary = summarise([_result(0, False, 300), _result(1, False, 250)])
    assert summary["success_rate"] == 0.0 and summary["mean_length"] == 275.0
    for key in ("median_length_solved", "p90_length_solved", "max_length_solved"):
        assert summary[key] is None, key
    assert summary["mean_return"] == 0.0


def test_summarise_of_an_evaluation_agrees_with_its_results(two_episodes):
    summary = summarise(two_episodes)
    assert summary["episodes"] == 2
    assert summary["success_rate"] == pytest.approx(np.mean([r.success for r in two_episodes]))
    solved = [r.length for r in two_episodes if r.success]
    assert summary["max_length_solved"] == (max(solved) if solved else None)


# ------------------------------------------------------------------------- histogram and JSON
def test_length_histogram_is_a_png_and_shows_the_solved_lengths(tmp_path):
    results = [_result(i, i % 4 != 0, 20 + 7 * i) for i in range(20)]
    path = plot_length_histogram(results, tmp_path / "figs" / "lengths.png", title="test")
    assert path == tmp_path / "figs" / "lengths.png"
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    with Image.open(path) as image:
        assert image.format == "PNG"
        width, height = image.size
        solved_pixels = np.asarray(image.convert("RGB"))
    # A 6 x 3.6 inch figure at 130 dpi.
    assert (width, height) == (780, 468)

    none = plot_length_histogram([_result(0, False, 300), _result(1, False, 300)], tmp_path / "none.png",
                                 title="test")
    assert none.read_bytes()[:8] == PNG_SIGNATURE
    with Image.open(none) as image:
        assert image.size == (width, height)
        empty_pixels = np.asarray(image.convert("RGB"))
    # The bars are drawn in blue (#4c72b0) only where episodes were solved.
    bar = np.array([0x4C, 0x72, 0xB0])

    def bar_pixels(pixels):
        return int(np.all(np.abs(pixels.astype(int) - bar) <= 8, axis=-1).sum())

    assert bar_pixels(solved_pixels) > 1000
    assert bar_pixels(empty_pixels) == 0
    assert [p.name for p in tmp_path.iterdir() if p.is_file()] == ["none.png"]  # nothing left behind


def test_results_json_holds_the_settings_summary_and_every_episode(tmp_path, two_episodes):
    summary = summarise(two_episodes)
    path = write_results(two_episodes, summary, CHEAP, "STG1", tmp_path / "out" / "results.json")
    assert path == tmp_path / "out" / "results.json"
    payload = json.loads(path.read_text())
    assert payload["task"] == "STG1"
    assert MPCConfig(**payload["config"]) == CHEAP
    assert payload["summary"] == summary
    assert [EpisodeResult(**e) for e in payload["episodes"]] == two_episodes
    assert [p.name for p in path.parent.iterdir()] == ["results.json"]  # written atomically, no leftovers

    # Written again, the file is replaced.
    fewer = two_episodes[:1]
    write_results(fewer, summarise(fewer), dataclasses.replace(CHEAP, horizon=9), "STG1", path)
    payload = json.loads(path.read_text())
    assert len(payload["episodes"]) == 1 and payload["config"]["horizon"] == 9


# ------------------------------------------------------------------------ the command line's files
EVAL_ARGV = ["expert-eval", "--task", "STG1", "--episodes", "1", "--workers", "1", "-K", "4", "-H", "8",
             "--max-steps", "20"]


@pytest.mark.parametrize("name", ["results.json", "lengths.png"])
def test_a_full_disk_while_saving_the_results_names_the_file(tmp_path, monkeypatch, capsys, name):
    real = evaluation.atomic_write_bytes

    def full_disk(path, payload):
        if Path(path).name == name:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(path, payload)
    monkeypatch.setattr(evaluation, "atomic_write_bytes", full_disk)
    monkeypatch.setattr(images, "atomic_write_bytes", full_disk)
    out = tmp_path / "out"
    assert main([*EVAL_ARGV, "--out", str(out)]) == 2
    error = capsys.readouterr().err
    assert f"bimgame expert-eval: error: no space left on device while writing {out / name}" in error
    assert "Traceback" not in error and "Errno" not in error
    assert not list(out.glob(".*.tmp"))


def test_an_out_directory_that_cannot_be_made_fails_before_any_episode(tmp_path, monkeypatch, capsys):
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    monkeypatch.setattr(cli_expert, "evaluate_expert", lambda *args, **kwargs: pytest.fail("episodes were run"))
    assert main([*EVAL_ARGV, "--out", str(blocker / "out")]) == 2
    error = capsys.readouterr().err
    assert error.startswith("bimgame expert-eval: error: ") and str(blocker) in error
