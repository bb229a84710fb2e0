"""The report's statistics on hand-made numbers (bootstrap, binning, steps to threshold, censoring,
speed-ups) and rebuilding a whole report from saved results without training."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from bimgame.expert.datasets import generate_dataset
from bimgame.experiments.reproduce import Budget, write_plan
from bimgame.experiments.report import (CURVE_BINS, MIN_EPISODES, Crossing, binned_means, bootstrap_mean_band, build_report,
                            dagger_crossing, first_crossing, percentile_interval, run_crossing, speedup,
                            stratified_bootstrap)


# ------------------------------------------------------------------------------- statistics
def test_first_crossing_finds_the_first_value_at_or_above_the_threshold():
    steps = np.array([10, 20, 30, 40, 50])
    assert first_crossing(steps, [0.1, 0.5, 0.79, 0.8, 0.95], 0.8) == 40
    assert first_crossing(steps, [0.1, 0.9, 0.2, 0.9, 0.9], 0.8) == 20  # the first, not a lasting one
    assert first_crossing(steps, [np.nan, np.nan, 0.85, 0.1, 0.1], 0.8) == 30  # NaN never crosses
    assert first_crossing(steps, [0.1, 0.2, 0.3, 0.4, 0.5], 0.8) is None


def test_binned_means_counts_episodes_by_start_step_and_hides_thin_bins():
    edges = np.array([0.0, 100.0, 200.0, 300.0])
    start = np.array([0, 50, 99, 100, 150, 250, 400])  # 400 lies past the last edge: last bin
    values = np.array([0, 1, 1, 1, 1, 0, 1])
    means, counts = binned_means(start, values, edges)
    assert counts.tolist() == [3, 2, 2]
    np.testing.assert_allclose(means, [2 / 3, 1.0, 0.5])
    means, _ = binned_means(start, values, edges, min_count=3)
    assert means[0] == pytest.approx(2 / 3) and np.isnan(means[1]) and np.isnan(means[2])


def _episodes(ranges: list[tuple[int, int, float]], bin_steps: int, per_bin: int = 20) -> dict:
    """Training episodes: in every bin of ``bin_steps`` inside each (start, end, rate) range,
    ``per_bin`` episodes started evenly, exactly round(rate · per_bin) of them successful."""
    starts, successes = [], []
    for low, high, rate in ranges:
        for left in range(low, high, bin_steps):
            wins = int(round(rate * per_bin))
            starts += list(np.linspace(left, left + bin_steps - 1, per_bin))
            successes += [1.0] * wins + [0.0] * (per_bin - wins)
    n = len(starts)
    return {"start_step": np.array(starts), "success": np.array(successes), "return": np.array(successes),
            "length": np.full(n, 50.0), "worker": np.zeros(n)}


def test_run_crossing_is_the_right_edge_of_the_first_bin_reaching_the_threshold():
    edges = np.linspace(0, 100_000, 11)  # bins of 10k
    episodes = _episodes([(0, 30_000, 0.2), (30_000, 40_000, 0.6), (40_000, 50_000, 0.85),
                          (50_000, 100_000, 0.95)], 10_000)
    assert run_crossing(episodes, edges, 0.8) == Crossing(50_000.0, True)
    assert run_crossing(episodes, edges, 0.9) == Crossing(60_000.0, True)
    assert run_crossing(episodes, edges, 0.99) == Crossing(100_000.0, False)  # censored at the run's end
    assert run_crossing({}, edges, 0.5) == Crossing(100_000.0, False)  # no finished episode at all
    # A bin with too few episodes cannot cross, however good it looks.
    thin, full = _episodes([(0, 10_000, 1.0)], 10_000, MIN_EPISODES - 1), _episodes([(10_000, 20_000, 0.9)], 10_000,
                                                                                     MIN_EPISODES)
    both = {k: np.concatenate([thin[k], full[k]]) for k in thin}
    assert run_crossing(both, edges, 0.8) == Crossing(20_000.0, True)


def test_dagger_crossing_uses_its_evaluations_and_censors_at_its_last_step():
    table = {"step": np.array([80.0, 900.0, 2100.0]), "greedy_success_rate": np.array([0.1, 0.85, 0.9])}
    assert dagger_crossing(table, 0.8) == Crossing(900.0, True)
    assert dagger_crossing(table, 0.95) == Crossing(2100.0, False)


def test_stratified_bootstrap_resamples_each_stratum_on_its_own():
    rng = np.random.default_rng(0)
    shapes = []

    def statistic(drawn):
        shapes.extend(d.shape for d in drawn)
        return drawn[0].mean(axis=1) - drawn[1].mean(axis=1)

    values = stratified_bootstrap([np.array([1.0, 2.0]), np.array([5.0, 6.0, 7.0, 8.0, 9.0])], statistic,
                                  resamples=300, rng=rng)
    assert shapes == [(300, 2), (300, 5)]
    # Every resample draws from its own stratum only: the difference stays within the strata's ranges.
    assert values.shape == (300,) and values.min() >= 1 - 9 and values.max() <= 2 - 5
    # A constant stratum gives a degenerate interval.
    constant = stratified_bootstrap([np.full(4, 3.0)], lambda d: d[0].mean(axis=1), resamples=100, rng=rng)
    assert percentile_interval(constant) == (3.0, 3.0)
    with pytest.raises(ValueError, match="stratum 1 is empty"):
        stratified_bootstrap([np.ones(2), np.array([])], lambda d: d[0].mean(axis=1), rng=rng)
    with pytest.raises(ValueError, match="resamples must be an integer >= 1"):
        stratified_bootstrap([np.ones(2)], lambda d: d[0].mean(axis=1), resamples=0, rng=rng)


def test_bootstrap_interval_of_a_mean_matches_the_normal_theory_width():
    sample = np.random.default_rng(1).normal(0.0, 1.0, size=400)
    means = stratified_bootstrap([sample], lambda d: d[0].mean(axis=1), resamples=4000,
                                 rng=np.random.default_rng(2))
    low, high = percentile_interval(means)
    expected = 2 * 1.96 * sample.std() / np.sqrt(len(sample))
    assert low < sample.mean() < high
    assert (high - low) == pytest.approx(expected, rel=0.1)
    again = stratified_bootstrap([sample], lambda d: d[0].mean(axis=1), resamples=4000, rng=np.random.default_rng(2))
    np.testing.assert_array_equal(means, again)  # seeded: the same interval every time


def test_mean_band_ignores_missing_points_per_seed():
    curves = np.array([[0.0, 0.2, np.nan], [0.4, 0.6, 0.9]])
    mean, low, high = bootstrap_mean_band(curves, resamples=500, rng=np.random.default_rng(0))
    np.testing.assert_allclose(mean, [0.2, 0.4, 0.9])
    assert low[0] == pytest.approx(0.0) and high[0] == pytest.approx(0.4)
    assert low[2] == high[2] == pytest.approx(0.9)  # only one seed has the last point


def test_speedup_ratio_interval_and_censoring_bounds():
    rng = np.random.default_rng(0)
    a3c = [Crossing(300_000, True), Crossing(360_000, True)]
    faster = [Crossing(100_000, True), Crossing(200_000, True)]
    result = speedup(a3c, faster, rng=rng)
    assert result["bound"] == "exact" and result["estimate"] == pytest.approx(330_000 / 150_000)
    # The stratified bootstrap's extreme resamples: all seeds at the min/max of each group.
    low, high = result["ci"]
    assert 300_000 / 200_000 <= low <= result["estimate"] <= high <= 360_000 / 100_000
    assert speedup([Crossing(300_000, True)], faster, rng=rng)["ci"] is None  # one seed: no interval
    censored_base = speedup([Crossing(400_000, False), Crossing(360_000, True)], faster, rng=rng)
    assert censored_base["bound"] == "lower" and censored_base["estimate"] == pytest.approx(380_000 / 150_000)
    censored_other = speedup(a3c, [Crossing(100_000, True), Crossing(400_000, False)], rng=rng)
    assert censored_other["bound"] == "upper" and censored_other["estimate"] == pytest.approx(330_000 / 250_000)
    assert speedup(a3c, [Crossing(400_000, False)] * 2, rng=rng) == {"estimate": None, "ci": None,
                                                                      "bound": "not reached"}
    assert speedup([Crossing(400_000, False)] * 2, [Crossing(5, True), Crossing(9, False)],
                   rng=rng)["bound"] == "unknown"


# ---------------------------------------------------------------------- a report from saved results
def _write_csv(path: Path, rows: list[dict]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _fake_a3c_run(path: Path, steps: int, curve: list[tuple[int, int, float]]) -> None:
    episodes = _episodes(curve, steps // CURVE_BINS)
    rows = [{"step": int(s) + 50, "start_step": int(s), "worker": 0, "return": float(r), "length": 50,
             "success": bool(r)} for s, r in zip(episodes["start_step"], episodes["success"])]
    _write_csv(path / "episodes.csv", rows)
    _write_csv(path / "eval.csv", [{"step": steps, "greedy_success_rate": 0.9, "greedy_mean_length": 40,
                                    "greedy_mean_return": 0.9, "sampled_success_rate": 0.8,
                                    "sampled_mean_length": 45, "sampled_mean_return": 0.8}])
    (path / "summary.json").write_text(json.dumps({"steps": steps, "stopped": "finished",
                                                   "final_eval": {"greedy_success_rate": 0.9}}))


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory) -> Path:
    """Four STG1 expert episodes (a few seconds of planning)."""
    return generate_dataset(tmp_path_factory.mktemp("report") / "data", "STG1", 4, seed=0, workers=1, progress=False)


def test_report_is_rebuilt_from_saved_results(tmp_path, tiny_dataset):
    import shutil

    steps = 100_000
    budget = Budget(name="hand-made", tasks=("STG1",), seeds=2, a3c_steps={"STG1": steps}, dataset_task="STG1",
                    dataset_episodes=4, dataset_workers=1, dagger_iterations=3)
    pieces = write_plan(tmp_path, budget)
    shutil.copytree(tiny_dataset, tmp_path / "data")
    # Known crossings (bins of 2.5k steps): A3C at 60k and 70k, pre-trained at 20k and 35k, value
    # reward never (censored at 100k), pre-trained + value at 30k and 35k.
    plain = {0: 60_000, 1: 70_000}
    pre = {0: 20_000, 1: 35_000}
    prevalue = {0: 30_000, 1: 35_000}
    for seed in range(2):
        root = tmp_path / "runs" / "STG1"
        _fake_a3c_run(root / "a3c" / f"seed{seed}", steps, [(0, plain[seed] - 2_500, 0.3),
                                                            (plain[seed] - 2_500, steps, 0.9)])
        _fake_a3c_run(root / "pretrain-a3c" / f"seed{seed}", steps, [(0, pre[seed] - 2_500, 0.5),
                                                                     (pre[seed] - 2_500, steps, 0.95)])
        _fake_a3c_run(root / "a3c-value" / f"seed{seed}", steps, [(0, steps, 0.4)])
        _fake_a3c_run(root / "pretrain-a3c-value" / f"seed{seed}", steps,
                      [(0, prevalue[seed] - 2_500, 0.5), (prevalue[seed] - 2_500, steps, 0.95)])
        dagger = root / "dagger" / f"seed{seed}"
        _write_csv(dagger / "dagger.csv", [{"step": s, "iteration": i, "greedy_success_rate": g,
                                            "greedy_mean_length": 100, "sampled_success_rate": g}
                                           for i, (s, g) in enumerate([(200, 0.1), (900, 0.5), (1800, 0.6)])])
        (dagger / "dagger_state.json").write_text(json.dumps({"iteration": 3, "env_steps": 1800}))
        for kind, summary in (("policy", {"val_accuracy": 0.25 + 0.02 * seed, "val_value_rmse": 0.3,
                                          "policy_eval": {"greedy_success_rate": 0.4, "sampled_success_rate": 0.3}}),
                              ("value", {"val_accuracy": float("nan"), "val_value_rmse": 0.2 + seed / 10})):
            out = tmp_path / "pretrain" / "STG1" / f"{kind}-seed{seed}"
            out.mkdir(parents=True)
            (out / "summary.json").write_text(json.dumps(summary))
            (out / "checkpoint.pt").write_bytes(b"weights")
    assert len(pieces) == 1 + 2 * 2 + 2 * 5

    paths = build_report(tmp_path, resamples=500, seed=3)
    for name in ("fig_curves_STG1.png", "fig_expert_lengths.png", "table_speedup.md", "table_speedup.json",
                 "report.md"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert (tmp_path / "fig_curves_STG1.png").read_bytes()[:4] == b"\x89PNG"
    numbers = json.loads(paths.table_json.read_text())
    stg1 = numbers["tasks"]["STG1"]
    assert stg1["curve_bin_steps"] == steps / CURVE_BINS
    assert stg1["expert_success"] == 1.0  # the seeded expert solves all four episodes
    assert stg1["threshold"] == pytest.approx(0.8)
    algorithms = stg1["algorithms"]
    assert [r["steps_to_threshold"] for r in algorithms["a3c"]["runs"]] == [60_000, 70_000]
    assert [r["steps_to_threshold"] for r in algorithms["pretrain+a3c"]["runs"]] == [20_000, 35_000]
    assert [r["censored_at"] for r in algorithms["a3c+value"]["runs"]] == [steps, steps]
    assert algorithms["a3c+value"]["reached"] == 0
    assert algorithms["pretrain+a3c"]["speedup_vs_a3c"]["estimate"] == pytest.approx(65_000 / 27_500)
    assert algorithms["pretrain+a3c"]["speedup_vs_a3c"]["bound"] == "exact"
    assert algorithms["a3c+value"]["speedup_vs_a3c"]["bound"] == "not reached"
    assert algorithms["pretrain+a3c+value"]["speedup_vs_pretrain+a3c"]["estimate"] == pytest.approx(27_500 / 32_500)
    assert algorithms["dagger"]["final_greedy_success"] == pytest.approx(0.6)
    assert numbers["pretraining"]["STG1"]["val_accuracy_mean"] == pytest.approx(0.26)

    table = paths.table_md.read_text()
    assert "| pre-train + A3C | 2/2 | 2/2 | 20k, 35k | 27.5k | 2.36× [" in table
    assert "| A3C + value reward | 2/2 | 0/2 | > 100k, > 100k | not reached | not reached |" in table
    report = paths.report.read_text()
    assert "Pre-training speeds learning up 2–3×" in report and "STG1: 2.36×" in report
    assert "26.0% (seeds: 25.0%, 27.0%" in report
    assert "STG3 and STG4 are not learned by any method | not measured in this budget" in report
    assert "STG2 and FULL not measured in this budget" in report
    assert "![STG1 learning curves](fig_curves_STG1.png)" in report
    assert "![expert trajectory lengths](fig_expert_lengths.png)" in report

    # The same results and seed give the same numbers; another threshold gives other crossings.
    again = build_report(tmp_path, resamples=500, seed=3)
    assert json.loads(again.table_json.read_text()) == numbers
    lower = json.loads(build_report(tmp_path, threshold_fraction=0.5, resamples=500).table_json.read_text())
    assert lower["tasks"]["STG1"]["algorithms"]["a3c+value"]["reached"] == 0  # 0.4 < 0.5 still
    assert lower["tasks"]["STG1"]["algorithms"]["pretrain+a3c"]["runs"][0]["steps_to_threshold"] == 2_500

    # A piece whose outputs vanish drops out of the report, which says it is incomplete.
    (tmp_path / "runs" / "STG1" / "a3c" / "seed1" / "summary.json").unlink()
    numbers = json.loads(build_report(tmp_path, resamples=200).table_json.read_text())
    assert numbers["tasks"]["STG1"]["algorithms"]["a3c"]["seeds_finished"] == 1
    assert "**Incomplete:** 1 pieces are not finished" in (tmp_path / "report.md").read_text()


def test_report_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError, match="not a reproduction directory .no readable plan.json"):
        build_report(tmp_path)
    write_plan(tmp_path, dataclasses.replace(Budget(), a3c_steps={"STG1": 1000}))
    with pytest.raises(ValueError, match=r"threshold_fraction must be in \(0, 1\], got 1.5"):
        build_report(tmp_path, threshold_fraction=1.5)
    with pytest.raises(ValueError, match="resamples must be an integer >= 1, got 0"):
        build_report(tmp_path, resamples=0)
