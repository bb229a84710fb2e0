"""The numbers beyond the paper, from hand-written eval.csv files: final success, the dip after step 0,
steps to 80% greedy success, and their means over seeds with bootstrap intervals."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from bimgame.experiments.beyond import beyond_numbers, mean_ci, run_metrics, shows_beyond
from bimgame.experiments.budgets import BUDGETS
from bimgame.experiments.results import RunResults
from bimgame.learn.curves import read_table


def _eval_table(tmp_path: Path, rows: list[tuple[int, float, float]]) -> dict[str, np.ndarray]:
    """An eval.csv of (step, greedy success, sampled success) rows, written and read back as a run's is."""
    path = tmp_path / "eval.csv"
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["step", "greedy_success_rate", "greedy_mean_length", "greedy_mean_return",
                         "sampled_success_rate", "sampled_mean_length", "sampled_mean_return"])
        for step, greedy, sampled in rows:
            writer.writerow([step, greedy, 300, greedy, sampled, 400, sampled])
    return read_table(path)


def test_dip_steps_to_80_and_final_of_a_run_that_forgets_then_recovers(tmp_path):
    # π^s solves 65% greedy, 50% sampled; fine-tuning falls to 20% greedy at 100k, 35% sampled at
    # 50k, then learns: 80% greedy first at 200k; the last row is the final evaluation.
    table = _eval_table(tmp_path, [(0, 0.65, 0.5), (50_000, 0.4, 0.35), (100_000, 0.2, 0.45), (150_000, 0.7, 0.6),
                                   (200_000, 0.85, 0.75), (250_000, 0.75, 0.9), (250_240, 0.9, 0.95)])
    m = run_metrics(table)
    assert (m["start_greedy"], m["start_sampled"]) == (0.65, 0.5)
    assert (m["final_greedy"], m["final_sampled"]) == (0.9, 0.95)
    assert (m["lowest_greedy"], m["lowest_greedy_step"]) == (0.2, 100_000)
    assert (m["lowest_sampled"], m["lowest_sampled_step"]) == (0.35, 50_000)
    assert m["drop_greedy"] == pytest.approx(0.45) and m["drop_sampled"] == pytest.approx(0.15)
    assert m["steps_to_target"] == 200_000 and m["censored_at"] is None
    assert m["evaluations"] == 7


def test_a_run_that_never_falls_or_starts_above_the_target(tmp_path):
    m = run_metrics(_eval_table(tmp_path, [(0, 0.85, 0.6), (50_000, 0.9, 0.7), (100_000, 0.95, 0.8)]))
    assert m["drop_greedy"] == 0.0 and m["drop_sampled"] == 0.0  # its lowest is above its start: no drop
    assert m["lowest_greedy"] == 0.9
    assert m["steps_to_target"] == 0.0  # π^s itself already succeeds 80% of the time


def test_a_run_that_never_reaches_the_target_is_censored_at_its_last_evaluation(tmp_path):
    m = run_metrics(_eval_table(tmp_path, [(0, 0.0, 0.0), (50_000, 0.1, 0.3), (100_000, 0.79, 0.5)]))
    assert m["steps_to_target"] is None and m["censored_at"] == 100_000
    assert run_metrics(_eval_table(tmp_path, [(0, 0.0, 0.0), (100_000, 0.79, 0.5)]), target=0.5)[
        "steps_to_target"] == 100_000


def test_without_a_step_0_evaluation_there_is_no_start_and_no_dip(tmp_path):
    m = run_metrics(_eval_table(tmp_path, [(100_000, 0.5, 0.6)]))  # eval_every=0: only the final evaluation
    assert math.isnan(m["start_greedy"]) and math.isnan(m["drop_greedy"])
    assert m["final_greedy"] == 0.5 and m["lowest_greedy"] == 0.5
    empty = run_metrics({})
    assert empty["evaluations"] == 0 and math.isnan(empty["final_greedy"]) and empty["censored_at"] is None
    with pytest.raises(ValueError, match=r"target must be a success rate in \(0, 1\], got 1.5"):
        run_metrics({}, target=1.5)


def test_mean_over_seeds_with_a_seeded_bootstrap_interval():
    summary = mean_ci([0.2, 0.4, float("nan"), None, 0.9], resamples=500, rng=np.random.default_rng(0))
    assert summary["mean"] == pytest.approx(0.5) and summary["n"] == 3
    assert 0.2 <= summary["ci"][0] < 0.5 < summary["ci"][1] <= 0.9
    assert summary == mean_ci([0.2, 0.4, 0.9], resamples=500, rng=np.random.default_rng(0))
    assert mean_ci([0.3], rng=np.random.default_rng(0)) == {"mean": 0.3, "ci": None, "n": 1}
    assert mean_ci([], rng=np.random.default_rng(0))["n"] == 0


def test_numbers_per_task_and_algorithm_keep_every_seed(tmp_path):
    curves = {0: [(0, 0.6, 0.5), (50_000, 0.3, 0.4), (100_000, 0.9, 0.8)],
              1: [(0, 0.7, 0.5), (50_000, 0.7, 0.6), (100_000, 0.75, 0.7)]}
    runs = []
    for seed, rows in curves.items():
        (tmp_path / f"seed{seed}").mkdir()
        runs.append(RunResults(seed, tmp_path / f"seed{seed}", {}, _eval_table(tmp_path / f"seed{seed}", rows), None))
    numbers = beyond_numbers({"STG3": {"pretrain+a3c": runs, "dagger": []}}, {("STG3", "pretrain+a3c"): 3},
                             out_dir=tmp_path, resamples=200, rng=np.random.default_rng(1))
    entry = numbers["tasks"]["STG3"]["algorithms"]
    assert list(entry) == ["pretrain+a3c"]  # DAgger has no periodic evaluations
    group = entry["pretrain+a3c"]
    assert group["seeds_finished"] == 2 and group["seeds_planned"] == 3 and group["starts_from_policy"]
    assert [r["dir"] for r in group["runs"]] == ["seed0", "seed1"]
    assert [r["final_greedy"] for r in group["runs"]] == [0.9, 0.75]
    assert group["final_greedy"]["mean"] == pytest.approx(0.825)
    assert group["drop_greedy"]["mean"] == pytest.approx(0.15)  # 0.3 below 0.6, and no drop
    assert group["steps_to_target"] == {"reached": 1, "mean": 100_000.0, "ci": None, "bound": "lower"}


def test_which_grids_get_the_section():
    assert not shows_beyond(BUDGETS["quick"]) and not shows_beyond(BUDGETS["paper"])
    assert shows_beyond(BUDGETS["beyond"]) and shows_beyond(BUDGETS["ablation"])
    assert shows_beyond(BUDGETS["quick"].with_grid(tasks=["STG3"]))
    assert shows_beyond(BUDGETS["quick"].with_grid(algorithms=["a3c", "a3c+reverse"]))
    # The paper's network beside the improved one is no fine-tuning method; without evaluations
    # during the runs there are no dips to show.
    assert not shows_beyond(BUDGETS["pixels"]) and not shows_beyond(BUDGETS["quick"].with_grid(
        algorithms=["a3c", "a3c+papernet"]))
    assert not shows_beyond(BUDGETS["beyond"].replace(a3c={"eval_every": 0}))
