"""Figures, statistics and ``report.md`` of a reproduction directory (:mod:`bimgame.experiments.reproduce`),
rebuilt from the saved results alone: ``bimgame report DIR``.

Outputs in DIR:

- ``fig_curves_<TASK>.png`` — the paper's Fig. 2: mean episode return (the task's own reward, also
  for shaped runs) and success rate of the training episodes against environment steps, one line
  per algorithm, the mean over seeds with a bootstrap 95% band. Episodes are binned by the step at
  which they *started* (counting by the end step favours short, successful episodes early on).
  DAgger has no training episodes of its own policy: its line is its greedy evaluation after each
  iteration, against the environment steps it had used by then.
- ``fig_expert_lengths.png`` — the paper's Fig. 1b: lengths of the expert's dataset episodes.
- ``table_speedup.md`` / ``table_speedup.json`` — steps to a success threshold, speed-up over A3C,
  final success, pre-training accuracy and π^s alone.
- ``report.md`` — each claim of the paper next to what this run measured, the figures, the tables
  and the settings with wall times.

**Steps to threshold.** The threshold is ``threshold_fraction`` (default 0.8) × the expert's
success rate on the task, measured on the dataset's episodes relabelled for the task and counted
as successes only within the task's time limit. An A3C run's steps-to-threshold is the right edge
of the first bin (of :data:`CURVE_BINS` equal bins over the run's planned steps) in which the
training episodes that *started* there succeed at least that often, counting only bins with at
least :data:`MIN_EPISODES` episodes (fewer are too noisy to call a crossing). Training episodes,
not the periodic evaluations, because they give a point every few thousand steps instead of every
100k. DAgger's is the environment steps after the first iteration whose greedy evaluation reaches
the threshold.

**Censoring.** A run that never reaches the threshold is *censored*: it is counted at its last step,
a lower bound on its true steps-to-threshold, and shown as "> N". Speed-ups computed with censored
runs are therefore bounds: censored baseline (A3C) runs make the speed-up a lower bound ("≥"),
censored runs of the compared algorithm make it an upper bound ("≤"); with both, no direction is
known and no number is given. An algorithm no seed of which reached the threshold is "not reached".

**Bootstrap.** Speed-up = mean steps-to-threshold of A3C's seeds / mean of the algorithm's seeds.
Its 95% interval is a stratified percentile bootstrap: each algorithm's seeds are resampled with
replacement on their own (seed k of two algorithms share nothing but the number), the ratio
recomputed, and the 2.5% and 97.5% quantiles taken. Curve bands resample the seeds of one
algorithm the same way. This is a few lines of numpy (:func:`stratified_bootstrap`) rather than
rliable, which implements the same resampling but would add scipy, arch and seaborn to the
dependencies for about thirty lines of code. Intervals need at least two seeds per group.
"""

from __future__ import annotations

import dataclasses
import json
import math
import warnings
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from bimgame.learn.curves import binned_means, read_table
from bimgame.sim.figures import save_png
from bimgame.experiments.reproduce import (ALGORITHMS, Budget, Piece, STATUS, format_duration, load_plan, load_status,
                                 piece_done)
from bimgame.util.files import atomic_write_bytes
from bimgame.learn.runs import write_json

__all__ = ["DEFAULT_RESAMPLES", "CURVE_BINS", "MIN_EPISODES", "CONFIDENCE", "PAPER_ACCURACY", "ReportPaths",
           "Crossing", "stratified_bootstrap", "percentile_interval", "bootstrap_mean_band", "binned_means",
           "first_crossing", "run_crossing", "dagger_crossing", "speedup", "expert_success_by_task", "build_report"]

DEFAULT_RESAMPLES = 2000
#: Bins over a run's planned steps for curves and steps-to-threshold.
CURVE_BINS = 40
#: Fewest training episodes in a bin for it to count as a threshold crossing.
MIN_EPISODES = 10
CONFIDENCE = 0.95
#: The paper's held-out action accuracy of pre-training.
PAPER_ACCURACY = 0.275
#: Share of a run's steps whose training episodes give its "final" success rate.
FINAL_SHARE = 0.1
_LABELS = {"a3c": "A3C", "pretrain+a3c": "pre-train + A3C", "a3c+value": "A3C + value reward",
           "pretrain+a3c+value": "pre-train + A3C + value reward", "dagger": "DAgger"}


# ------------------------------------------------------------------------------- statistics
def stratified_bootstrap(samples: Sequence[np.ndarray], statistic: Callable[[list[np.ndarray]], np.ndarray], *,
                         resamples: int = DEFAULT_RESAMPLES, rng: np.random.Generator) -> np.ndarray:
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


def percentile_interval(values: np.ndarray, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """The central ``confidence`` interval of bootstrap values (along the first axis, NaNs ignored)."""
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    tail = (1.0 - confidence) / 2
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        low, high = np.nanquantile(values, [tail, 1.0 - tail], axis=0)
    return low, high


def bootstrap_mean_band(curves: np.ndarray, *, resamples: int = DEFAULT_RESAMPLES, rng: np.random.Generator,
                        confidence: float = CONFIDENCE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean over seeds of curves (seeds, points) with a bootstrap band: seeds are resampled with
    replacement; at each point the seeds without a value (NaN) are left out. Returns (mean, low,
    high); with a single seed the band is that seed's curve."""
    curves = np.atleast_2d(np.asarray(curves, dtype=np.float64))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(curves, axis=0)
        means = stratified_bootstrap([curves], lambda d: np.nanmean(d[0], axis=1), resamples=resamples, rng=rng)
    low, high = percentile_interval(means, confidence)
    return mean, low, high


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


def run_crossing(episodes: dict[str, np.ndarray], edges: np.ndarray, threshold: float, *,
                 min_episodes: int = MIN_EPISODES) -> Crossing:
    """Steps to threshold of an A3C run from its ``episodes.csv`` columns (see the module notes)."""
    if not episodes or len(episodes.get("start_step", ())) == 0:
        return Crossing(float(edges[-1]), False)
    means, _ = binned_means(episodes["start_step"], episodes["success"], edges, min_count=min_episodes)
    crossing = first_crossing(edges[1:], means, threshold)
    return Crossing(crossing, True) if crossing is not None else Crossing(float(edges[-1]), False)


def dagger_crossing(table: dict[str, np.ndarray], threshold: float) -> Crossing:
    """Steps to threshold of a DAgger run from its ``dagger.csv`` (greedy evaluation per iteration)."""
    if not table or len(table.get("step", ())) == 0:
        return Crossing(0.0, False)
    crossing = first_crossing(table["step"], table["greedy_success_rate"], threshold)
    return Crossing(crossing, True) if crossing is not None else Crossing(float(np.nanmax(table["step"])), False)


def speedup(base: Sequence[Crossing], other: Sequence[Crossing], *, resamples: int = DEFAULT_RESAMPLES,
            rng: np.random.Generator, confidence: float = CONFIDENCE) -> dict[str, Any]:
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
        ratios = stratified_bootstrap([a, b], lambda d: d[0].mean(axis=1) / d[1].mean(axis=1),
                                      resamples=resamples, rng=rng)
        low, high = percentile_interval(ratios, confidence)
        ci = [float(low), float(high)]
    return {"estimate": estimate, "ci": ci, "bound": bound}


# ------------------------------------------------------------------------------------ the expert
def _dataset_sequences(data_dir: Path) -> list[dict[str, Any]]:
    from bimgame.expert.datasets import iterate_sequences

    return list(iterate_sequences(data_dir, obs="state"))


def expert_success_by_task(sequences: list[dict[str, Any]], tasks: Sequence[str]) -> dict[str, float]:
    """The expert's success rate on each task: its dataset episodes relabelled for the task
    (:func:`bimgame.pretrain.relabel`), a success being the task's goal reached within the task's
    time limit."""
    from bimgame.sim.tasks import MAX_EPISODE_STEPS
    from bimgame.sim.maze import MazeSpec
    from bimgame.learn.pretrain import relabel
    from bimgame.sim.tasks import parse_task

    spec = MazeSpec.merl()
    rates = {}
    for task in tasks:
        limit = MAX_EPISODE_STEPS[parse_task(task)]
        wins = [s["terminated"] and len(s["actions"]) <= limit
                for s in (relabel(sequence, task, 0.99, spec) for sequence in sequences)]
        rates[task] = float(np.mean(wins)) if wins else float("nan")
    return rates


# --------------------------------------------------------------------------------- collecting
@dataclasses.dataclass
class _Run:
    seed: int
    path: Path
    episodes: dict[str, np.ndarray]
    table: dict[str, np.ndarray]
    """eval.csv (A3C) or dagger.csv (DAgger)."""
    summary: dict[str, Any] | None


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _finished(pieces: list[Piece], out_dir: Path, budget: Budget) -> dict[str, Piece]:
    return {p.id: p for p in pieces if piece_done(p, out_dir, budget)}


def _collect_runs(pieces: dict[str, Piece], out_dir: Path, task: str, algorithm: str) -> list[_Run]:
    runs = []
    for piece in pieces.values():
        if piece.task != task or piece.algorithm != algorithm:
            continue
        path = out_dir / piece.path
        if piece.kind == "dagger":
            runs.append(_Run(piece.seed, path, {}, read_table(path / "dagger.csv"),
                             _read_json(path / "dagger_state.json")))
        else:
            runs.append(_Run(piece.seed, path, read_table(path / "episodes.csv"), read_table(path / "eval.csv"),
                             _read_json(path / "summary.json")))
    return sorted(runs, key=lambda r: r.seed)


def _final_training_success(run: _Run, steps: int) -> float:
    if not run.episodes:
        return float("nan")
    late = run.episodes["start_step"] >= (1.0 - FINAL_SHARE) * steps
    return float(np.mean(run.episodes["success"][late])) if late.any() else float("nan")


def _final_eval(run: _Run, algorithm: str, mode: str = "greedy") -> float:
    """Success rate of a run's last evaluation, acting ``greedy`` or ``sampled``: an A3C run's final
    evaluation (summary.json, else the last row of eval.csv), DAgger's after its last iteration."""
    key = f"{mode}_success_rate"
    final = {} if algorithm == "dagger" else (run.summary or {}).get("final_eval") or {}
    if key in final:
        return float(final[key])
    values = run.table.get(key, np.array([]))
    return float(values[-1]) if len(values) else float("nan")


def _nanmean(values: Sequence[float]) -> float:
    values = [v for v in values if v is not None and not math.isnan(v)]
    return float(np.mean(values)) if values else float("nan")


# ------------------------------------------------------------------------------------ figures
def _save(fig: Any, path: Path) -> Path:
    fig.tight_layout()
    return save_png(fig, path, dpi=120)


def _plot_curves(task: str, runs: dict[str, list[_Run]], edges: np.ndarray, threshold: float | None,
                 fraction: float, path: Path, *, resamples: int, rng: np.random.Generator, budget: Budget) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    centres = (edges[:-1] + edges[1:]) / 2
    fig, (ax_return, ax_success) = plt.subplots(1, 2, figsize=(12, 4.4))
    for index, algorithm in enumerate(ALGORITHMS):
        group = runs.get(algorithm) or []
        if not group:
            continue
        colour = f"C{index}"
        label = f"{_LABELS[algorithm]} ({len(group)} seed{'s' if len(group) != 1 else ''})"
        if algorithm == "dagger":
            _plot_dagger(ax_return, ax_success, task, group, colour, label, resamples=resamples, rng=rng)
            continue
        for axis, key in ((ax_return, "return"), (ax_success, "success")):
            curves = np.array([binned_means(r.episodes["start_step"], r.episodes[key], edges)[0]
                               if r.episodes else np.full(len(centres), np.nan) for r in group])
            mean, low, high = bootstrap_mean_band(curves, resamples=resamples, rng=rng)
            axis.plot(centres, mean, color=colour, label=label)
            axis.fill_between(centres, low, high, color=colour, alpha=0.18, linewidth=0)
    if threshold is not None:
        ax_success.axhline(threshold, color="black", ls="--", lw=0.8,
                           label=f"threshold {threshold:.2f} ({fraction:.0%} of the expert)")
    ax_return.set(xlabel="environment steps", ylabel="mean episode return (task reward)",
                  title="cumulative reward per episode")
    ax_success.set(xlabel="environment steps", ylabel="success rate", title="success rate", ylim=(-0.02, 1.02))
    for axis in (ax_return, ax_success):
        axis.grid(alpha=0.3)
        axis.legend(fontsize=7)
    fig.suptitle(f"{task}, {budget.obs} observations: training episodes by start step, mean over seeds with "
                 f"bootstrap {CONFIDENCE:.0%} band; DAgger: greedy evaluation per iteration", fontsize=9)
    return _save(fig, path)


def _plot_dagger(ax_return: Any, ax_success: Any, task: str, group: list[_Run], colour: str, label: str, *,
                 resamples: int, rng: np.random.Generator) -> None:
    """DAgger's greedy evaluations, aligned by iteration across seeds (x: mean environment steps)."""
    tables = [r.table for r in group if r.table and len(r.table.get("step", ())) > 0]
    if not tables:
        return
    count = max(len(t["step"]) for t in tables)

    def column(key: str) -> np.ndarray:
        out = np.full((len(tables), count), np.nan)
        for row, table in enumerate(tables):
            out[row, :len(table[key])] = table[key]
        return out

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        steps = np.nanmean(column("step"), axis=0)
    success = column("greedy_success_rate")
    if "greedy_mean_return" in tables[0]:
        returns = column("greedy_mean_return")
    elif task != "FULL":
        returns = success  # STGk pays 1 at the goal and 0 elsewhere: return = success
    else:
        returns = None  # dagger.csv has no mean return of FULL's ±1 rewards
    for axis, values in ((ax_success, success), (ax_return, returns)):
        if values is None:
            continue
        mean, low, high = bootstrap_mean_band(values, resamples=resamples, rng=rng)
        axis.plot(steps, mean, "o-", color=colour, label=label + ", greedy eval.", markersize=4)
        axis.fill_between(steps, low, high, color=colour, alpha=0.18, linewidth=0)


def _plot_expert_lengths(sequences: list[dict[str, Any]], task: str, path: Path) -> Path:
    from bimgame.expert.evaluation import EpisodeResult, plot_length_histogram

    results = [EpisodeResult(int(s["id"]), int(s["id"]), bool(s["terminated"]), len(s["actions"]),
                             float(np.sum(s["rewards"])), 0.0) for s in sequences]
    return plot_length_histogram(results, path, title=f"MPC expert dataset, {task}")


# ------------------------------------------------------------------------------------- the report
@dataclasses.dataclass
class ReportPaths:
    report: Path
    table_md: Path
    table_json: Path
    figures: list[Path]

    def all(self) -> list[Path]:
        return [*self.figures, self.table_md, self.table_json, self.report]


def _steps_text(value: float | None) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    if value >= 1e6:
        return f"{value / 1e6:.2f}M"
    if value >= 1e5:
        return f"{value / 1e3:.0f}k"
    if value >= 1e3:
        return f"{value / 1e3:.1f}".rstrip("0").rstrip(".") + "k"
    return f"{value:.0f}"


def _pct(value: float | None) -> str:
    return "–" if value is None or math.isnan(value) else f"{value:.0%}"


def _speedup_text(result: dict[str, Any] | None) -> str:
    if result is None:
        return "–"
    if result["bound"] == "not reached":
        return "not reached"
    if result["bound"] == "unknown":
        return "n/a (both censored)"
    prefix = {"exact": "", "lower": "≥ ", "upper": "≤ "}[result["bound"]]
    text = f"{prefix}{result['estimate']:.2f}×"
    if result["ci"] is not None:
        text += f" [{result['ci'][0]:.2f}, {result['ci'][1]:.2f}]"
    return text


def build_report(out_dir: str | Path, *, threshold_fraction: float | None = None,
                 resamples: int = DEFAULT_RESAMPLES, seed: int = 0) -> ReportPaths:
    """Rebuild every figure, table and ``report.md`` of the reproduction in ``out_dir`` from its
    saved results (finished pieces only; nothing is trained). ``threshold_fraction`` overrides the
    budget's; ``seed`` seeds the bootstrap's generator, so the same results give the same report."""
    out_dir = Path(out_dir)
    budget, pieces = load_plan(out_dir)
    if threshold_fraction is None:
        threshold_fraction = budget.threshold_fraction
    if not (isinstance(threshold_fraction, (int, float)) and 0.0 < threshold_fraction <= 1.0):
        raise ValueError(f"threshold_fraction must be in (0, 1], got {threshold_fraction!r}")
    if not isinstance(resamples, int) or resamples < 1:
        raise ValueError(f"resamples must be an integer >= 1, got {resamples!r}")
    rng = np.random.default_rng(seed)
    finished = _finished(pieces, out_dir, budget)
    status = load_status(out_dir)
    figures: list[Path] = []

    dataset: dict[str, Any] | None = None
    expert: dict[str, float] = {}
    if "data" in finished:
        from bimgame.expert.datasets import dataset_summary

        sequences = _dataset_sequences(out_dir / "data")
        expert = expert_success_by_task(sequences, budget.tasks)
        dataset = dataset_summary(out_dir / "data")
        figures.append(_plot_expert_lengths(sequences, budget.dataset_task, out_dir / "fig_expert_lengths.png"))

    tasks: dict[str, Any] = {}
    for task in budget.tasks:
        steps = budget.steps_for(task) if task in budget.a3c_steps else 0
        edges = np.linspace(0.0, float(steps), CURVE_BINS + 1) if steps else np.array([0.0, 1.0])
        # No threshold without an expert that succeeds: 0 × anything would be "reached" at once.
        threshold = threshold_fraction * expert[task] if expert.get(task, 0.0) > 0 else None
        runs = {a: _collect_runs(finished, out_dir, task, a) for a in budget.algorithms}
        crossings: dict[str, list[Crossing]] = {}
        entry: dict[str, Any] = {"expert_success": expert.get(task), "threshold": threshold,
                                 "a3c_steps": steps, "curve_bin_steps": float(edges[1] - edges[0]),
                                 "min_episodes_per_bin": MIN_EPISODES, "algorithms": {}}
        for algorithm, group in runs.items():
            planned = sum(1 for p in pieces if p.task == task and p.algorithm == algorithm)
            rows = []
            for run in group:
                if threshold is None:
                    crossing = None
                elif algorithm == "dagger":
                    crossing = dagger_crossing(run.table, threshold)
                else:
                    crossing = run_crossing(run.episodes, edges, threshold)
                if crossing is not None:
                    crossings.setdefault(algorithm, []).append(crossing)
                rows.append({"seed": run.seed, "dir": str(run.path.relative_to(out_dir)),
                             "steps_to_threshold": crossing.steps if crossing and crossing.reached else None,
                             "censored_at": crossing.steps if crossing and not crossing.reached else None,
                             "final_success_training": None if algorithm == "dagger" else
                             _final_training_success(run, steps),
                             "final_greedy_success": _final_eval(run, algorithm, "greedy"),
                             "final_sampled_success": _final_eval(run, algorithm, "sampled"),
                             "env_steps": float(run.table["step"][-1]) if algorithm == "dagger" and run.table
                             else (run.summary or {}).get("steps")})
            group_crossings = crossings.get(algorithm, [])
            entry["algorithms"][algorithm] = {
                "runs": rows, "seeds_finished": len(group), "seeds_planned": planned,
                "reached": sum(c.reached for c in group_crossings),
                "mean_steps_censored_at_last": float(np.mean([c.steps for c in group_crossings]))
                if group_crossings else None,
                "final_success_training": _nanmean([r["final_success_training"] for r in rows])
                if algorithm != "dagger" else None,
                "final_greedy_success": _nanmean([r["final_greedy_success"] for r in rows]),
                "final_sampled_success": _nanmean([r["final_sampled_success"] for r in rows])}
        for algorithm, group_crossings in crossings.items():
            if algorithm != "a3c" and crossings.get("a3c"):
                entry["algorithms"][algorithm]["speedup_vs_a3c"] = speedup(
                    crossings["a3c"], group_crossings, resamples=resamples, rng=rng)
        for base, other in (("a3c", "a3c+value"), ("pretrain+a3c", "pretrain+a3c+value")):
            if crossings.get(base) and crossings.get(other):
                entry["algorithms"][other][f"speedup_vs_{base}"] = speedup(
                    crossings[base], crossings[other], resamples=resamples, rng=rng)
        if any(runs.values()):
            figures.append(_plot_curves(task, runs, edges, threshold, threshold_fraction,
                                        out_dir / f"fig_curves_{task}.png", resamples=resamples, rng=rng,
                                        budget=budget))
            entry["figure"] = f"fig_curves_{task}.png"
        tasks[task] = entry

    pretraining = _pretraining(finished, out_dir, budget)
    numbers = {"threshold_fraction": threshold_fraction, "bootstrap": {"resamples": resamples, "seed": seed,
                                                                       "confidence": CONFIDENCE},
               "expert": {"dataset": dataset, "success_by_task": expert}, "tasks": tasks, "pretraining": pretraining}
    table_json = write_json(out_dir / "table_speedup.json", _without_nan(numbers))
    table_text = _tables_markdown(numbers, budget)
    table_md = atomic_write_bytes(out_dir / "table_speedup.md", table_text.encode())
    report = atomic_write_bytes(out_dir / "report.md",
                                _report_markdown(numbers, table_text, budget, pieces, finished, status).encode())
    return ReportPaths(report, table_md, table_json, figures)


def _without_nan(value: Any) -> Any:
    """NaN → None throughout, so the JSON is standard (NaN is not JSON)."""
    if isinstance(value, dict):
        return {k: _without_nan(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_without_nan(v) for v in value]
    if isinstance(value, float) and math.isnan(value):
        return None
    return value


def _pretraining(finished: dict[str, Piece], out_dir: Path, budget: Budget) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for task in budget.tasks:
        policy = [(p.seed, _read_json(out_dir / p.path / "summary.json")) for p in finished.values()
                  if p.kind == "pretrain-policy" and p.task == task]
        value = [(p.seed, _read_json(out_dir / p.path / "summary.json")) for p in finished.values()
                 if p.kind == "pretrain-value" and p.task == task]
        if not policy and not value:
            continue
        policy = sorted((s, v) for s, v in policy if v)
        value = sorted((s, v) for s, v in value if v)
        evals = [v.get("policy_eval") or {} for _, v in policy]
        out[task] = {
            "seeds": [s for s, _ in policy],
            "val_accuracy": [v.get("val_accuracy") for _, v in policy],
            "val_accuracy_mean": _nanmean([v.get("val_accuracy") for _, v in policy]),
            "chance_accuracy": 0.2,
            "policy_greedy_success": [e.get("greedy_success_rate") for e in evals],
            "policy_sampled_success": [e.get("sampled_success_rate") for e in evals],
            "policy_eval_episodes": budget.pretrain_eval_episodes,
            "value_rmse": [v.get("val_value_rmse") for _, v in value],
        }
    return out


def _tables_markdown(numbers: dict[str, Any], budget: Budget) -> str:
    lines = ["# Steps to threshold and speed-up over A3C", ""]
    for task, entry in numbers["tasks"].items():
        lines.append(f"## {task}")
        lines.append("")
        if entry["threshold"] is None:
            lines += ["No threshold: no finished expert dataset, or the expert never solved this task in it.", ""]
        else:
            lines.append(f"Threshold: success rate {entry['threshold']:.2f} = {numbers['threshold_fraction']:.0%} of "
                         f"the expert's {entry['expert_success']:.0%} on {task}. A3C runs: training episodes by start "
                         f"step in bins of {_steps_text(entry['curve_bin_steps'])} steps (at least "
                         f"{entry['min_episodes_per_bin']} episodes); DAgger: greedy evaluation per iteration. "
                         f"\"> N\": not reached by its last step N (censored).")
            lines.append("")
        seeds = [a["seeds_finished"] for a in entry["algorithms"].values() if a["seeds_finished"]]
        if seeds and min(seeds) < 5:
            lines += [f"With {min(seeds)} seed(s) per algorithm the bootstrap intervals are rough: resampling "
                      f"{min(seeds)} values can only give a handful of distinct means, so the intervals understate "
                      f"the uncertainty. Use more seeds (`--seeds`) for firm conclusions.", ""]
        lines.append("| algorithm | seeds | reached | steps to threshold, per seed | mean | speed-up vs A3C [95% CI] "
                     "| final success: training episodes | greedy evaluation | sampled evaluation |")
        lines.append("|---|---:|---:|---|---:|---|---:|---:|---:|")
        for algorithm, a in entry["algorithms"].items():
            per_seed = ", ".join(_steps_text(r["steps_to_threshold"]) if r["steps_to_threshold"] is not None
                                 else f"> {_steps_text(r['censored_at'])}" if r["censored_at"] is not None else "–"
                                 for r in a["runs"]) or "–"
            reached = a["reached"]
            mean = a["mean_steps_censored_at_last"]
            if mean is None:
                mean_text = "–"
            elif reached == 0:
                mean_text = "not reached"
            else:
                mean_text = ("≥ " if reached < len(a["runs"]) else "") + _steps_text(mean)
            speed = "1 (baseline)" if algorithm == "a3c" and a["runs"] else _speedup_text(a.get("speedup_vs_a3c"))
            training = a["final_success_training"]
            lines.append(f"| {_LABELS[algorithm]} | {a['seeds_finished']}/{a['seeds_planned']} | "
                         f"{reached if entry['threshold'] is not None else '–'}/{len(a['runs'])} | {per_seed} | "
                         f"{mean_text} | {speed} | {'–' if training is None else _pct(training)} | "
                         f"{_pct(a['final_greedy_success'])} | {_pct(a['final_sampled_success'])} |")
        lines.append("")
        extra = [(o, b, entry["algorithms"][o].get(f"speedup_vs_{b}")) for b, o in
                 (("a3c", "a3c+value"), ("pretrain+a3c", "pretrain+a3c+value")) if o in entry["algorithms"]]
        extra = [(o, b, s) for o, b, s in extra if s is not None]
        if extra:
            lines.append("Value reward against the same start without it: " + "; ".join(
                f"{_LABELS[o]} vs {_LABELS[b]}: {_speedup_text(s)}" for o, b, s in extra) + ".")
            lines.append("")
    lines += ["# Pre-training", ""]
    if not numbers["pretraining"]:
        lines += ["No finished pre-training.", ""]
    else:
        lines.append(f"| task | π^s held-out accuracy (paper: {PAPER_ACCURACY:.1%}; chance 20%) | per seed | "
                     f"π^s alone, greedy success | π^s alone, sampled success | V̂ held-out RMSE |")
        lines.append("|---|---:|---|---|---|---|")
        for task, p in numbers["pretraining"].items():
            seeds = ", ".join(_pct1(v) for v in p["val_accuracy"]) or "–"
            lines.append(f"| {task} | {_pct1(p['val_accuracy_mean'])} | {seeds} | "
                         f"{', '.join(_pct(v) for v in p['policy_greedy_success']) or '–'} | "
                         f"{', '.join(_pct(v) for v in p['policy_sampled_success']) or '–'} | "
                         f"{', '.join(f'{v:.3f}' for v in p['value_rmse'] if v is not None) or '–'} |")
        lines.append("")
        lines.append(f"π^s alone: {budget.pretrain_eval_episodes} greedy and {budget.pretrain_eval_episodes} sampled "
                     f"episodes per seed, before any A3C update.")
        lines.append("")
    return "\n".join(lines)


def _pct1(value: float | None) -> str:
    return "–" if value is None or math.isnan(value) else f"{value:.1%}"


def _verdict(result: dict[str, Any] | None) -> str:
    if result is None:
        return "not measured"
    if result["bound"] in ("not reached", "unknown"):
        return {"not reached": "the compared runs did not reach the threshold",
                "unknown": "neither reached the threshold in every seed"}[result["bound"]]
    if result["ci"] is None:
        return "one seed: no interval"
    low, high = result["ci"]
    if low > 1:
        return "faster (interval above 1)"
    if high < 1:
        return "slower (interval below 1)"
    return "no clear difference (interval includes 1)"


def _claims(numbers: dict[str, Any]) -> list[tuple[str, str]]:
    tasks = numbers["tasks"]
    claims = []

    measured = []
    for task, entry in tasks.items():
        result = entry["algorithms"].get("pretrain+a3c", {}).get("speedup_vs_a3c")
        if result is not None:
            inside = ""
            if result["ci"] is not None and result["bound"] == "exact":
                inside = "; 2–3× lies inside the interval" if result["ci"][0] <= 3 and result["ci"][1] >= 2 else \
                    "; 2–3× lies outside the interval"
            measured.append(f"{task}: {_speedup_text(result)} — {_verdict(result)}{inside}")
    claims.append(("Pre-training speeds learning up 2–3×",
                   "; ".join(measured) or "not measured in this budget"))

    measured = [f"{task}: {_pct1(p['val_accuracy_mean'])} (seeds: {', '.join(_pct1(v) for v in p['val_accuracy'])}; "
                f"chance 20%)" for task, p in numbers["pretraining"].items() if p["val_accuracy"]]
    claims.append((f"Pre-training reaches {PAPER_ACCURACY:.1%} held-out action accuracy",
                   "; ".join(measured) or "not measured in this budget"))

    def final(entry: dict[str, Any], algorithm: str) -> float:
        a = entry["algorithms"].get(algorithm)
        return float("nan") if a is None or not a["runs"] else max(a["final_greedy_success"],
                                                                   a["final_sampled_success"])

    measured = []
    for task in ("STG2", "FULL", "STG1"):
        entry = tasks.get(task)
        if entry is None or "dagger" not in entry["algorithms"] or not entry["algorithms"]["dagger"]["runs"]:
            continue
        dagger = entry["algorithms"]["dagger"]
        steps = _nanmean([r["env_steps"] for r in dagger["runs"]])
        others = {a: final(entry, a) for a in ("a3c", "pretrain+a3c", "a3c+value", "pretrain+a3c+value")
                  if not math.isnan(final(entry, a))}
        best = max(others, key=others.get) if others else None
        text = (f"{task}: DAgger final success {_pct(dagger['final_greedy_success'])} greedy, "
                f"{_pct(dagger['final_sampled_success'])} sampled, after {_steps_text(steps)} env steps")
        if best is not None:
            b = entry["algorithms"][best]
            text += (f"; best A3C variant ({_LABELS[best]}) {_pct(b['final_greedy_success'])} greedy, "
                     f"{_pct(b['final_sampled_success'])} sampled, after {_steps_text(entry['a3c_steps'])}")
        measured.append(text + (" (context: the claim is about STG2 and FULL)" if task == "STG1" else ""))
    if not any(t in tasks for t in ("STG2", "FULL")):
        measured.insert(0, "STG2 and FULL not measured in this budget")
    claims.append(("DAgger is much worse on STG2 and FULL", "; ".join(measured) or "not measured in this budget"))

    measured = []
    for task, entry in tasks.items():
        for base, other in (("a3c", "a3c+value"), ("pretrain+a3c", "pretrain+a3c+value")):
            result = entry["algorithms"].get(other, {}).get(f"speedup_vs_{base}")
            if result is not None:
                measured.append(f"{task}, {_LABELS[other]} vs {_LABELS[base]}: {_speedup_text(result)} — "
                                f"{_verdict(result)}")
    claims.append(("The value function as a reward does not help much",
                   "; ".join(measured) or "not measured in this budget"))

    measured = []
    for task in ("STG3", "STG4"):
        entry = tasks.get(task)
        if entry is None:
            continue
        finals = {a: final(entry, a) for a in entry["algorithms"] if not math.isnan(final(entry, a))}
        if finals:
            best = max(finals, key=finals.get)
            reached = [a for a, v in entry["algorithms"].items() if v["reached"]]
            verdict = (f"reached the threshold ({_pct(entry['threshold'])}): {', '.join(_LABELS[a] for a in reached)}"
                       if reached else f"no run reached the threshold ({_pct(entry['threshold'])})")
            measured.append(f"{task}: best final success {_pct(finals[best])} ({_LABELS[best]}, the better of greedy "
                            f"and sampled evaluation); {verdict}")
    claims.append(("STG3 and STG4 are not learned by any method",
                   "; ".join(measured) or "not measured in this budget"))
    return claims


def _report_markdown(numbers: dict[str, Any], tables: str, budget: Budget, pieces: list[Piece],
                     finished: dict[str, Piece], status: dict[str, Any]) -> str:
    import datetime as dt

    lines = ["# Reproduction: Trajectory-based Learning for Ball-in-Maze Games", "",
             f"Budget **{budget.name}**: tasks {', '.join(budget.tasks)}; algorithms "
             f"{', '.join(_LABELS[a] for a in budget.algorithms)}; {budget.seeds} seeds; {budget.obs} observations. "
             f"{len(finished)} of {len(pieces)} pieces finished. Report built "
             f"{dt.datetime.now().astimezone().isoformat(timespec='seconds')} by `bimgame report`.", ""]
    if len(finished) < len(pieces):
        lines += [f"**Incomplete:** {len(pieces) - len(finished)} pieces are not finished; the numbers below use the "
                  f"finished ones. Continue with `bimgame reproduce --out DIR`.", ""]
    lines += ["## The paper's claims and this run", "", "| paper | this run |", "|---|---|"]
    for claim, measured in _claims(numbers):
        lines.append(f"| {claim} | {measured} |")
    lines.append("")
    lines += ["## Learning curves", ""]
    for task, entry in numbers["tasks"].items():
        if "figure" in entry:
            lines += [f"![{task} learning curves]({entry['figure']})", ""]
        else:
            lines += [f"{task}: no finished run yet.", ""]
    lines += ["## Expert", ""]
    expert = numbers["expert"]
    if expert["dataset"] is not None:
        d = expert["dataset"]
        lines += ["![expert trajectory lengths](fig_expert_lengths.png)", "",
                  f"Dataset: {d['episodes']} {budget.dataset_task} episodes, {d['steps']:,} steps, expert success "
                  f"{d['success_rate']:.0%}, mean length {d['mean_length']:.0f} steps. Success relabelled per task "
                  f"(within the task's time limit): " + ", ".join(f"{t} {_pct(v)}" for t, v in
                                                                  expert["success_by_task"].items()) + ".", ""]
    else:
        lines += ["No finished expert dataset.", ""]
    lines += ["#" + line if line.startswith("#") else line for line in tables.splitlines()]
    lines.append("")
    lines += ["## Settings", "", "| setting | value |", "|---|---|"]
    for key, value in budget.to_dict().items():
        if isinstance(value, dict):
            value = ", ".join(f"{k} {_steps_text(v) if key == 'a3c_steps' else v}" for k, v in value.items()
                              if key != "a3c_steps" or k in budget.tasks)
        elif isinstance(value, (list, tuple)):
            value = ", ".join(map(str, value))
        lines.append(f"| {key} | {value} |")
    lines += ["", "## Wall time", "", "| piece | state | wall time |", "|---|---|---:|"]
    entries = status.get("pieces", {})
    total = 0.0
    for piece in pieces:
        entry = entries.get(piece.id, {})
        seconds = entry.get("seconds")
        total += seconds or 0.0
        state = "done" if piece.id in finished else entry.get("state", "pending")
        lines.append(f"| {piece.id} | {state} | {format_duration(seconds) if seconds is not None else '–'} |")
    invocations = status.get("invocations", [])
    elapsed = sum(i.get("seconds", 0.0) for i in invocations)
    lines += [f"| **total** | | **{format_duration(total)}** |", "",
              f"Wall times are from `{STATUS}` (all attempts of a piece, on this machine, with whatever else ran "
              f"on it). The reproduction ran in {len(invocations)} invocation(s) of `bimgame reproduce` taking "
              f"{format_duration(elapsed)} in all.", ""]
    lines += ["## How the numbers are computed", "", _METHODS, ""]
    return "\n".join(lines)


_METHODS = (
    "Curves: training episodes binned by the step they started at, the task's own reward (also for shaped runs), "
    "mean over seeds with a 95% percentile bootstrap band over seeds. DAgger: greedy evaluation after each "
    "iteration against the environment steps used so far (expert planning is counted separately in its dagger.csv). "
    "Threshold: a fraction of the expert's success rate on the task (its dataset episodes relabelled for the task). "
    "Steps to threshold: the right edge of the first bin whose training episodes reach the threshold (DAgger: the "
    "first evaluation that does). Runs that never reach it are censored at their last step; speed-ups with censored "
    "runs are bounds (≥ when A3C was censored, ≤ when the compared algorithm was). Speed-up: ratio of mean steps, "
    "95% interval from a stratified bootstrap over seeds (each algorithm's seeds resampled on their own). Final "
    "success: training episodes that started in the last 10% of a run's steps; greedy: the run's final evaluation.")
