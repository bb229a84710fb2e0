"""The report's tables in Markdown: ``table_speedup.md`` (steps to threshold, speed-ups, final
success, pre-training; :func:`tables_markdown`) and the section beyond the paper
(:func:`beyond_markdown`: success and forgetting per seed with means over seeds), written from the
numbers :func:`bimgame.experiments.report.build_report` assembles; also how the report writes steps,
success rates and speed-ups, which its text (:mod:`bimgame.experiments.report_text`) shares.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from bimgame.experiments.algorithms import BASELINE, LABELS, registered
from bimgame.experiments.budgets import Budget

__all__ = [
    "PAPER_ACCURACY",
    "VS_BASELINE",
    "tables_markdown",
    "beyond_markdown",
    "value_pairs",
    "steps_text",
    "pct",
    "pct1",
    "speedup_text",
]

#: The paper's held-out action accuracy of pre-training.
PAPER_ACCURACY = 0.275
#: Where an algorithm's speed-up over the baseline is in its numbers.
VS_BASELINE = f"speedup_vs_{BASELINE.name}"


def value_pairs() -> list[tuple[str, str]]:
    """(algorithm without the value reward, the same with it), for every value-reward algorithm."""
    return [(a.without_value_reward, a.name) for a in registered() if a.without_value_reward is not None]


def steps_text(value: float | None) -> str:
    """A number of steps, short: ``1.25M``, ``250k``, ``2.5k``, ``800``; ``–`` when unknown."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    if value >= 1e6:
        return f"{value / 1e6:.2f}M"
    if value >= 1e5:
        return f"{value / 1e3:.0f}k"
    if value >= 1e3:
        return f"{value / 1e3:.1f}".rstrip("0").rstrip(".") + "k"
    return f"{value:.0f}"


def pct(value: float | None) -> str:
    """A success rate in whole percent; ``–`` when unknown."""
    return "–" if value is None or math.isnan(value) else f"{value:.0%}"


def pct1(value: float | None) -> str:
    """A rate in percent to one decimal (accuracies); ``–`` when unknown."""
    return "–" if value is None or math.isnan(value) else f"{value:.1%}"


def speedup_text(result: dict[str, Any] | None) -> str:
    """A :func:`~bimgame.experiments.statistics.speedup` result: the estimate with its bound's sign
    and its interval, or why there is none."""
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


def _per_seed_steps(runs: list[dict[str, Any]], key: str) -> str:
    """Every run's steps to ``key`` (its threshold or target), ``> N`` for a run censored at N."""
    return (
        ", ".join(
            steps_text(r[key])
            if r[key] is not None
            else f"> {steps_text(r['censored_at'])}"
            if r["censored_at"] is not None
            else "–"
            for r in runs
        )
        or "–"
    )


def tables_markdown(numbers: dict[str, Any], budget: Budget) -> str:
    """``table_speedup.md``: per task, steps to threshold and speed-ups per algorithm; then pre-training."""
    lines = ["# Steps to threshold and speed-up over A3C", ""]
    if BASELINE.name not in budget.algorithms:
        lines += [
            (
                "A3C from random weights is not in this grid: there is no baseline, so no speed-up over it is "
                "given (add it with `--algorithms`)."
            ),
            "",
        ]
    for task, entry in numbers["tasks"].items():
        lines += _task_tables(task, entry, numbers["threshold_fraction"])
    lines += _pretraining_table(numbers["pretraining"], budget)
    return "\n".join(lines)


def _task_tables(task: str, entry: dict[str, Any], threshold_fraction: float) -> list[str]:
    """A task's section of ``table_speedup.md``: its threshold, the table of algorithms and notes."""
    lines = [f"## {task}", ""]
    lines += _threshold_note(task, entry, threshold_fraction)
    lines += _few_seeds_note(entry)
    lines.append(
        "| algorithm | seeds | reached | steps to threshold, per seed | mean | speed-up vs A3C [95% CI] "
        "| final success: training episodes | greedy evaluation | sampled evaluation |"
    )
    lines.append("|---|---:|---:|---|---:|---|---:|---:|---:|")
    for algorithm, a in entry["algorithms"].items():
        lines.append(_algorithm_row(algorithm, a, threshold_known=entry["threshold"] is not None))
    lines.append("")
    lines += _curriculum_note(entry)
    lines += _value_reward_note(entry)
    return lines


def _threshold_note(task: str, entry: dict[str, Any], threshold_fraction: float) -> list[str]:
    """What the task's threshold is and how steps to it are counted (or why there is none)."""
    if entry["threshold"] is None:
        return ["No threshold: no finished expert dataset, or the expert never solved this task in it.", ""]
    return [
        (
            f"Threshold: success rate {entry['threshold']:.2f} = {threshold_fraction:.0%} of "
            f"the expert's {entry['expert_success']:.0%} on {task}. A3C and PPO runs: training episodes by start "
            f"step in bins of {steps_text(entry['curve_bin_steps'])} steps (at least "
            f"{entry['min_episodes_per_bin']} episodes); DAgger: greedy evaluation per iteration. "
            f'"> N": not reached by step N, up to which all its training episodes had ended (censored).'
        ),
        "",
    ]


def _few_seeds_note(entry: dict[str, Any]) -> list[str]:
    """A warning when fewer than five seeds make the bootstrap intervals rough."""
    seeds = [a["seeds_finished"] for a in entry["algorithms"].values() if a["seeds_finished"]]
    if not seeds or min(seeds) >= 5:
        return []
    return [
        (
            f"With {min(seeds)} seed(s) per algorithm the bootstrap intervals are rough: resampling "
            f"{min(seeds)} values can only give a handful of distinct means, so the intervals understate "
            f"the uncertainty. Use more seeds (`--seeds`) for firm conclusions."
        ),
        "",
    ]


def _mean_steps_text(a: dict[str, Any]) -> str:
    """An algorithm's mean steps to threshold, ``≥`` when some of its runs are censored."""
    reached = a["reached"]
    mean = a["mean_steps_censored_at_last"]
    if mean is None:
        return "–"
    if reached == 0:
        return "not reached"
    return ("≥ " if reached < len(a["runs"]) else "") + steps_text(mean)


def _algorithm_row(algorithm: str, a: dict[str, Any], *, threshold_known: bool) -> str:
    """An algorithm's row of a task's table."""
    speed = "1 (baseline)" if algorithm == BASELINE.name and a["runs"] else speedup_text(a.get(VS_BASELINE))
    training = a["final_success_training"]
    return (
        f"| {LABELS[algorithm]} | {a['seeds_finished']}/{a['seeds_planned']} | "
        f"{a['reached'] if threshold_known else '–'}/{len(a['runs'])} | "
        f"{_per_seed_steps(a['runs'], 'steps_to_threshold')} | "
        f"{_mean_steps_text(a)} | {speed} | {'–' if training is None else pct(training)} | "
        f"{pct(a['final_greedy_success'])} | {pct(a['final_sampled_success'])} |"
    )


def _curriculum_note(entry: dict[str, Any]) -> list[str]:
    """Why the algorithms with a start curriculum have no steps to threshold."""
    curricula = [a for a, v in entry["algorithms"].items() if v.get("start_curriculum")]
    if not curricula:
        return []
    return [
        (
            f"{', '.join(LABELS[a] for a in curricula)}: no steps to threshold or training "
            f"success — with a start curriculum the training episodes start nearer the goal than the "
            f"task's; see the evaluations beyond the paper."
        ),
        "",
    ]


def _value_reward_note(entry: dict[str, Any]) -> list[str]:
    """The speed-ups of the value-reward algorithms over the same start without the value reward."""
    extra = [
        (o, b, entry["algorithms"][o].get(f"speedup_vs_{b}")) for b, o in value_pairs() if o in entry["algorithms"]
    ]
    extra = [(o, b, s) for o, b, s in extra if s is not None]
    if not extra:
        return []
    return [
        "Value reward against the same start without it: "
        + "; ".join(f"{LABELS[o]} vs {LABELS[b]}: {speedup_text(s)}" for o, b, s in extra)
        + ".",
        "",
    ]


def _pretraining_table(pretraining: dict[str, Any], budget: Budget) -> list[str]:
    """The pre-training section: π^s's held-out accuracy and success alone, V̂'s error, per task."""
    lines = ["# Pre-training", ""]
    if not pretraining:
        return lines + ["No finished pre-training.", ""]
    lines.append(
        f"| task | π^s held-out accuracy (paper: {PAPER_ACCURACY:.1%}; chance 20%) | per seed | "
        f"π^s alone, greedy success | π^s alone, sampled success | V̂ held-out RMSE |"
    )
    lines.append("|---|---:|---|---|---|---|")
    for task, p in pretraining.items():
        per_seed = ", ".join(pct1(v) for v in p["val_accuracy"]) or "–"
        lines.append(
            f"| {task} | {pct1(p['val_accuracy_mean'])} | {per_seed} | "
            f"{', '.join(pct(v) for v in p['policy_greedy_success']) or '–'} | "
            f"{', '.join(pct(v) for v in p['policy_sampled_success']) or '–'} | "
            f"{', '.join(f'{v:.3f}' for v in p['value_rmse'] if v is not None) or '–'} |"
        )
    lines.append("")
    lines.append(
        f"π^s alone: {budget.pretrain.eval_episodes} greedy and {budget.pretrain.eval_episodes} sampled "
        f"episodes per seed, before any A3C update."
    )
    lines.append("")
    return lines


def _mean_text(summary: dict[str, Any], show: Callable[[Any], str]) -> str:
    """``mean [low, high]`` of a :func:`~bimgame.experiments.beyond.mean_ci` summary."""
    if summary["n"] == 0:
        return "–"
    text = f"**{show(summary['mean'])}**"
    return text + (f" [{show(summary['ci'][0])}, {show(summary['ci'][1])}]" if summary["ci"] is not None else "")


def _points(value: float | None) -> str:
    """A difference of success rates in percentage points."""
    return "–" if value is None or math.isnan(value) else f"{100 * value:.0f} pts"


def _cell(a: dict[str, Any], name: str, show: Callable[[Any], str], step: str | None = None) -> str:
    """Every seed's value of ``name`` (with the step it was at), then the mean over seeds and its interval."""
    values = [show(r[name]) + (f" @ {steps_text(r[step])}" if step and r[step] is not None else "") for r in a["runs"]]
    return f"{', '.join(values) or '–'}; mean {_mean_text(a[name], show)}"


def _target_cell(a: dict[str, Any]) -> str:
    """Steps to the target: per seed ("> N": not reached by the last evaluation, at N), then the mean."""
    per_seed = _per_seed_steps(a["runs"], "steps_to_target")
    s = a["steps_to_target"]
    if s["bound"] is None:
        mean = "–"
    elif s["bound"] == "not reached":
        mean = "not reached"
    else:
        mean = ("≥ " if s["bound"] == "lower" else "") + f"**{steps_text(s['mean'])}**"
        if s["ci"] is not None:
            mean += f" [{steps_text(s['ci'][0])}, {steps_text(s['ci'][1])}]"
    return f"{per_seed}; mean {mean} ({s['reached']}/{len(a['runs'])} reached)"


def beyond_markdown(beyond: dict[str, Any], budget: Budget) -> str:
    """The report's section beyond the paper: per task, the evaluations' figure and two tables —
    success (step 0, final, steps to the target) and forgetting (the dip after step 0) — with every
    seed's value and the mean over seeds with its bootstrap interval."""
    target = beyond["target"]
    lines = _beyond_introduction(target, budget)
    for task, entry in beyond["tasks"].items():
        lines += _beyond_task(task, entry, target)
    return "\n".join(lines).rstrip("\n")


def _beyond_introduction(target: float, budget: Budget) -> list[str]:
    """The section's heading and what its cells hold."""
    every = f"every {steps_text(budget.a3c.eval_every)} steps" if budget.a3c.eval_every else "at the end only"
    episodes = budget.a3c.eval_episodes
    lines = [
        "## Beyond the paper: fine-tuning that keeps π^s",
        "",
        (
            f"From each A3C and PPO run's evaluations ({episodes} greedy and {episodes} sampled "
            f"episodes from the task's own starts, {every}; step 0 is the policy the run started from — π^s for "
            f"the pre-trained starts — and the last evaluation the final one). Each cell: every seed's value, then "
            f"the mean over seeds with its 95% percentile-bootstrap interval over seeds (never the best seed). "
            f"Dip: the lowest success after step 0 (@ the step it was at) and how far it fell below step 0's. "
            f"Steps to {target:.0%}: the first evaluation with greedy success ≥ {target:.0%} (0: the starting "
            f'policy already was; "> N": not reached by the last evaluation, at N, and the mean is then a '
            f"lower bound). DAgger has no such evaluations and is left out."
        ),
        "",
    ]
    if budget.seeds < 5:
        lines += [f"With {budget.seeds} seed(s) the intervals are rough (a handful of distinct resampled means).", ""]
    return lines


def _beyond_task(task: str, entry: dict[str, Any], target: float) -> list[str]:
    """A task's part of the section: its figure, the success and forgetting tables and a summary."""
    lines = [f"### {task}", ""]
    groups = {a: v for a, v in entry["algorithms"].items() if v["runs"]}
    if not groups:
        return lines + ["No finished A3C or PPO run yet.", ""]
    if "figure" in entry:
        lines += [f"![{task} evaluations]({entry['figure']})", ""]
    lines += [
        (
            f"| algorithm | seeds | step 0, greedy | step 0, sampled | final greedy | final sampled | "
            f"steps to {target:.0%} greedy |"
        ),
        "|---|---:|---|---|---|---|---|",
    ]
    for algorithm, a in groups.items():
        lines.append(
            f"| {LABELS[algorithm]} | {a['seeds_finished']}/{a['seeds_planned']} | "
            f"{_cell(a, 'start_greedy', pct)} | {_cell(a, 'start_sampled', pct)} | "
            f"{_cell(a, 'final_greedy', pct)} | {_cell(a, 'final_sampled', pct)} | {_target_cell(a)} |"
        )
    lines += [
        "",
        (
            "| algorithm | dip: lowest greedy after step 0 | greedy drop below step 0 | "
            "dip: lowest sampled after step 0 | sampled drop below step 0 |"
        ),
        "|---|---|---|---|---|",
    ]
    for algorithm, a in groups.items():
        lines.append(
            f"| {LABELS[algorithm]} | {_cell(a, 'lowest_greedy', pct, 'lowest_greedy_step')} | "
            f"{_cell(a, 'drop_greedy', _points)} | "
            f"{_cell(a, 'lowest_sampled', pct, 'lowest_sampled_step')} | "
            f"{_cell(a, 'drop_sampled', _points)} |"
        )
    lines.append("")
    lines += [_beyond_summary(groups), ""]
    return lines


def _beyond_summary(groups: dict[str, dict[str, Any]]) -> str:
    """One line per task: the algorithm with the highest mean final greedy success and the one that
    fell furthest below its start."""

    def best(name: str) -> tuple[str, float] | None:
        means = {a: v[name]["mean"] for a, v in groups.items() if v[name]["n"]}
        return max(means.items(), key=lambda item: item[1]) if means else None

    parts = []
    final = best("final_greedy")
    if final is not None:
        parts.append(f"highest mean final greedy success: {LABELS[final[0]]} ({pct(final[1])})")
    drop = best("drop_greedy")
    if drop is not None:
        parts.append(
            f"largest mean greedy drop below step 0: {LABELS[drop[0]]} ({_points(drop[1])})"
            if drop[1] > 0
            else "no run's greedy success fell below its step 0"
        )
    return ("In short: " + "; ".join(parts) + ".") if parts else ""
