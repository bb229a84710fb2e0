"""The report's statistics on hand-made numbers: bootstrap, binning, steps to threshold, censoring
and speed-ups."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.experiments.statistics import (
    MIN_EPISODES,
    Crossing,
    bootstrap_mean_band,
    dagger_crossing,
    first_crossing,
    percentile_interval,
    run_crossing,
    speedup,
    stratified_bootstrap,
)
from bimgame.learn import curves
from bimgame.learn.curves import binned_means


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


def test_run_crossing_is_the_right_edge_of_the_first_bin_reaching_the_threshold(training_episodes):
    edges = np.linspace(0, 100_000, 11)  # bins of 10k
    episodes = training_episodes([(0, 30_000, 0.2), (30_000, 40_000, 0.6), (40_000, 50_000, 0.85),
                                  (50_000, 100_000, 0.95)], 10_000)
    assert run_crossing(episodes, edges, 0.8) == Crossing(50_000.0, True)
    assert run_crossing(episodes, edges, 0.9) == Crossing(60_000.0, True)
    assert run_crossing(episodes, edges, 0.99) == Crossing(100_000.0, False)  # censored at the run's end
    assert run_crossing({}, edges, 0.5) == Crossing(100_000.0, False)  # no finished episode at all
    # A bin with too few episodes cannot cross, however good it looks.
    thin = training_episodes([(0, 10_000, 1.0)], 10_000, MIN_EPISODES - 1)
    full = training_episodes([(10_000, 20_000, 0.9)], 10_000, MIN_EPISODES)
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


def test_run_crossing_ignores_bins_whose_episodes_may_still_be_running(running_log):
    # 50% success throughout; in the last 200 × 64 steps only the short, successful episodes had
    # ended when the log stopped, so the last bin looked like 100% and "reached" 80% at 400k.
    episodes = running_log(400_000)
    edges = np.linspace(0, 400_000, 41)  # bins of 10k
    last = episodes["start_step"] >= 390_000
    assert episodes["success"][last].mean() > 0.95
    # Episodes that started after 400k − 12.8k may be missing: censored at the last complete bin.
    assert run_crossing(episodes, edges, 0.8) == Crossing(380_000.0, False)
    # The run's settings can say an episode may take longer than any logged one did.
    until = curves.complete_until(episodes, 25_000)
    assert run_crossing(episodes, edges, 0.8, until=until) == Crossing(370_000.0, False)
    # Without end steps nothing can be cut (the old reading).
    no_end = {k: v for k, v in episodes.items() if k != "step"}
    assert run_crossing(no_end, edges, 0.8) == Crossing(400_000.0, True)
