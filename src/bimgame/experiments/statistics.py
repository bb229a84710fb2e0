"""The report's statistics, in plain numpy: steps to a success threshold, censoring, speed-ups and
bootstrap intervals over seeds.

**Steps to threshold.** An A3C run's steps-to-threshold is the right edge of the first bin (of
:data:`CURVE_BINS` equal bins over the run's planned steps) in which the training episodes that
*started* there succeed at least as often as the threshold, counting only bins with at least
:data:`MIN_EPISODES` episodes (fewer are too noisy to call a crossing), and only bins all of whose
episodes have ended and are in the log (:func:`bimgame.learn.curves.complete_until`: of the episodes
that started later, the short, successful ones are logged but the long ones were still running when
the run stopped, so those bins look better than they were). Training episodes, not the periodic
evaluations, because they give a point every few thousand steps instead of every 100k; binned by
start step, because counting by the end step favours short, successful episodes early on. DAgger's
is the environment steps after the first iteration whose greedy evaluation reaches the threshold.
(The threshold itself, a fraction of the expert's success rate, is chosen by
:mod:`bimgame.experiments.report`.)

**Censoring.** A run that never reaches the threshold is *censored*: it is counted at the last step
it was observed at — the right edge of its last complete bin, about one time limit (in all its
environments' steps) before its end — a lower bound on its true steps-to-threshold, and shown as
"> N". Speed-ups computed with censored runs are therefore bounds: censored baseline (A3C) runs make
the speed-up a lower bound ("≥"), censored runs of the compared algorithm make it an upper bound
("≤"); with both, no direction is known and no number is given. An algorithm no seed of which
reached the threshold is "not reached".

**Bootstrap.** Speed-up = mean steps-to-threshold of A3C's seeds / mean of the algorithm's seeds.
Its 95% interval is a stratified percentile bootstrap: each algorithm's seeds are resampled with
replacement on their own (seed k of two algorithms share nothing but the number), the ratio
recomputed, and the 2.5% and 97.5% quantiles taken. Curve bands resample the seeds of one
algorithm the same way. This is a few lines of numpy (:func:`stratified_bootstrap`) rather than
rliable, which implements the same resampling but would add scipy, arch, statsmodels, pandas and
seaborn to the dependencies (and rliable 1.2.0's arch fails to import beside pandas 3) for about
thirty lines of code. Measured (``benchmarks/bench_rliable.py``,
``benchmarks/results/rliable_comparison.json``): on all 126 per-seed results the benchmarks saved
(3 seeds each), the mean's 95% interval here and rliable's stratified percentile bootstrap agree
exactly, 50,000 resamples each; rliable's interquartile mean equals the mean for every one of them
(with 3 runs it trims nothing). rliable gives the same statistics here, not better ones; its IQM and
performance profiles pay off with many runs and tasks. Intervals need at least two seeds per group.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Sequence
from typing import Any, TypeAlias

import numpy as np

from bimgame.learn.curves import binned_means, complete_until, episode_span

__all__ = [
    "DEFAULT_RESAMPLES",
    "CURVE_BINS",
    "MIN_EPISODES",
    "CONFIDENCE",
    "Crossing",
    "stratified_bootstrap",
    "percentile_interval",
    "bootstrap_mean_band",
    "first_crossing",
    "run_crossing",
    "dagger_crossing",
    "speedup",
    "nanmean",
]

DEFAULT_RESAMPLES = 2000
#: Bins over a run's planned steps for curves and steps-to-threshold.
CURVE_BINS = 40
#: Fewest training episodes in a bin for it to count as a threshold crossing.
MIN_EPISODES = 10
CONFIDENCE = 0.95

#: An interval's bound: a number for 1-D bootstrap values, an array over the remaining axes otherwise.
Bound: TypeAlias = float | np.ndarray


def stratified_bootstrap(
    samples: Sequence[np.ndarray],
    statistic: Callable[[list[np.ndarray]], np.ndarray],
    *,
    resamples: int = DEFAULT_RESAMPLES,
    rng: np.random.Generator,
) -> np.ndarray:
    """The statistic over ``resamples`` stratified bootstrap resamples.

    Each stratum (array in ``samples``, its first axis the units, e.g. seeds) is resampled with
    replacement on its own and keeps its size. ``statistic`` is vectorised: it receives one array
    per stratum of shape (resamples, n_i, …) and returns (resamples, …)."""
    if not isinstance(resamples, int) or resamples < 1:
        raise ValueError(f"resamples must be an integer >= 1, got {resamples!r}")
    drawn = []
    for index, sample in enumerate(samples):
        sample = np.asarray(sample, dtype=np.float64)
        if sample.ndim == 0 or len(sample) == 0:
            raise ValueError(f"stratum {index} is empty: every stratum needs at least one unit")
        drawn.append(sample[rng.integers(0, len(sample), size=(resamples, len(sample)))])
    return np.asarray(statistic(drawn))


def percentile_interval(values: np.ndarray, confidence: float = CONFIDENCE) -> tuple[Bound, Bound]:
    """The central ``confidence`` interval of bootstrap values (along the first axis, NaNs ignored):
    numbers for 1-D ``values``, arrays over the remaining axes for more."""
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    tail = (1.0 - confidence) / 2
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        low, high = np.nanquantile(values, [tail, 1.0 - tail], axis=0)
    return low, high


def mean_interval(
    values: np.ndarray, *, resamples: int = DEFAULT_RESAMPLES, rng: np.random.Generator, confidence: float = CONFIDENCE
) -> tuple[float, float]:
    """Percentile-bootstrap interval of the mean of ``values`` (its units resampled with replacement)."""
    low, high = percentile_interval(
        stratified_bootstrap([values], lambda drawn: drawn[0].mean(axis=1), resamples=resamples, rng=rng), confidence
    )
    return float(low), float(high)


def bootstrap_mean_band(
    curves: np.ndarray, *, resamples: int = DEFAULT_RESAMPLES, rng: np.random.Generator, confidence: float = CONFIDENCE
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean over seeds of curves (seeds, points) with a bootstrap band: seeds are resampled with
    replacement; at each point the seeds without a value (NaN) are left out. Returns (mean, low,
    high); with a single seed the band is that seed's curve."""
    curves = np.atleast_2d(np.asarray(curves, dtype=np.float64))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(curves, axis=0)
        means = stratified_bootstrap([curves], lambda d: np.nanmean(d[0], axis=1), resamples=resamples, rng=rng)
    low, high = percentile_interval(means, confidence)
    return mean, np.asarray(low), np.asarray(high)


def first_crossing(steps: np.ndarray, values: np.ndarray, threshold: float) -> float | None:
    """The first ``steps[i]`` (in order) with ``values[i] >= threshold``; NaN values never cross;
    None if no value does."""
    values = np.asarray(values, dtype=np.float64)
    hits = np.flatnonzero(np.nan_to_num(values, nan=-np.inf) >= threshold)
    return float(np.asarray(steps)[hits[0]]) if len(hits) else None


@dataclasses.dataclass(frozen=True)
class Crossing:
    """A run's steps to threshold: ``steps`` is the crossing when ``reached``, else the last step
    the run was observed at (censored)."""

    steps: float
    reached: bool


def run_crossing(
    episodes: dict[str, np.ndarray],
    edges: np.ndarray,
    threshold: float,
    *,
    min_episodes: int = MIN_EPISODES,
    until: float | None = None,
) -> Crossing:
    """Steps to threshold of an A3C run from its ``episodes.csv`` columns (see the module notes),
    counting the bins that end by ``until`` (:func:`bimgame.learn.curves.complete_until`; by default
    from the longest episode in the log, :attr:`bimgame.experiments.results.RunResults.until` also
    knows the run's settings)."""
    if not episodes or len(episodes.get("start_step", ())) == 0:
        return Crossing(float(edges[-1]), False)
    if until is None:
        until = complete_until(episodes, episode_span(episodes))
    means, _ = binned_means(episodes["start_step"], episodes["success"], edges, min_count=min_episodes, until=until)
    crossing = first_crossing(edges[1:], means, threshold)
    if crossing is not None:
        return Crossing(crossing, True)
    observed = edges[edges <= until]  # the right edge of the last complete bin
    return Crossing(float(observed[-1]) if len(observed) else float(edges[0]), False)


def dagger_crossing(table: dict[str, np.ndarray], threshold: float) -> Crossing:
    """Steps to threshold of a DAgger run from its ``dagger.csv`` (greedy evaluation per iteration)."""
    if not table or len(table.get("step", ())) == 0:
        return Crossing(0.0, False)
    crossing = first_crossing(table["step"], table["greedy_success_rate"], threshold)
    return Crossing(crossing, True) if crossing is not None else Crossing(float(np.nanmax(table["step"])), False)


def speedup(
    base: Sequence[Crossing],
    other: Sequence[Crossing],
    *,
    resamples: int = DEFAULT_RESAMPLES,
    rng: np.random.Generator,
    confidence: float = CONFIDENCE,
) -> dict[str, Any]:
    """Speed-up of ``other`` over ``base`` = mean steps of base / mean steps of other, with a
    stratified bootstrap interval and the censoring bound (see the module notes). Returns
    ``estimate`` (None when not defined), ``ci`` ([low, high] or None), ``bound`` (``exact``,
    ``lower``, ``upper``, ``not reached`` or ``unknown``)."""
    if not base or not other:
        raise ValueError("speedup needs at least one run in each group")
    if not any(c.reached for c in other):
        return {"estimate": None, "ci": None, "bound": "not reached"}
    base_censored = not all(c.reached for c in base)
    other_censored = not all(c.reached for c in other)
    if base_censored and other_censored:
        return {"estimate": None, "ci": None, "bound": "unknown"}
    bound = "lower" if base_censored else "upper" if other_censored else "exact"
    a = np.array([c.steps for c in base], dtype=np.float64)
    b = np.array([c.steps for c in other], dtype=np.float64)
    estimate = float(a.mean() / b.mean())
    ci = None
    if len(a) >= 2 and len(b) >= 2:
        ratios = stratified_bootstrap(
            [a, b], lambda d: d[0].mean(axis=1) / d[1].mean(axis=1), resamples=resamples, rng=rng
        )
        low, high = percentile_interval(ratios, confidence)
        ci = [float(low), float(high)]
    return {"estimate": estimate, "ci": ci, "bound": bound}


def nanmean(values: Sequence[float | None]) -> float:
    """The mean of the values that are neither None nor NaN (NaN when there are none)."""
    present = [v for v in values if v is not None and not math.isnan(v)]
    return float(np.mean(present)) if present else float("nan")
