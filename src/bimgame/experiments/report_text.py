"""The report's text: ``report.md`` — each claim of the paper next to what this run measured, the
figures, the tables (:mod:`bimgame.experiments.report_tables`), the section beyond the paper, the
settings and wall times, and how the numbers are computed — written from the numbers
:func:`bimgame.experiments.report.build_report` assembles.
"""

from __future__ import annotations

import math
from typing import Any

from bimgame.experiments.algorithms import DAGGER, LABELS, PRETRAIN_A3C, Learner, registered
from bimgame.experiments.budgets import Budget
from bimgame.experiments.costs import format_duration
from bimgame.experiments.grid import Piece
from bimgame.experiments.plan import STATUS, timestamp
from bimgame.experiments.report_tables import (
    PAPER_ACCURACY,
    VS_BASELINE,
    beyond_markdown,
    pct,
    pct1,
    speedup_text,
    steps_text,
    value_pairs,
)
from bimgame.experiments.statistics import nanmean

__all__ = ["report_markdown"]

#: What a claim's cell says when the budget measured nothing for it.
_NOT_MEASURED = "not measured in this budget"


def report_markdown(
    numbers: dict[str, Any],
    tables: str,
    budget: Budget,
    pieces: list[Piece],
    finished: dict[str, Piece],
    status: dict[str, Any],
) -> str:
    """``report.md``: the paper's claims against this run, figures, ``tables`` (from
    :func:`~bimgame.experiments.report_tables.tables_markdown`), settings, wall times and the methods."""
    lines = _heading(budget, pieces, finished)
    lines += _claims_section(numbers)
    lines += _curves_section(numbers)
    lines += _expert_section(numbers, budget)
    lines += ["#" + line if line.startswith("#") else line for line in tables.splitlines()]
    lines.append("")
    if numbers.get("beyond") is not None:
        lines += [beyond_markdown(numbers["beyond"], budget), ""]
    lines += _settings_section(budget)
    lines += _wall_time_section(pieces, finished, status)
    lines += ["## How the numbers are computed", "", _METHODS, ""]
    if numbers.get("beyond") is not None:
        lines += [_METHODS_BEYOND, ""]
    return "\n".join(lines)


def _heading(budget: Budget, pieces: list[Piece], finished: dict[str, Piece]) -> list[str]:
    """The title, what the budget covers and how much of it is finished."""
    lines = [
        "# Reproduction: Trajectory-based Learning for Ball-in-Maze Games",
        "",
        (
            f"Budget **{budget.name}**: tasks {', '.join(budget.tasks)}; algorithms "
            f"{', '.join(LABELS[a] for a in budget.algorithms)}; {budget.seeds} seeds; {budget.obs} observations. "
            f"{len(finished)} of {len(pieces)} pieces finished. Report built "
            f"{timestamp()} by `bimgame report`."
        ),
        "",
    ]
    if len(finished) < len(pieces):
        lines += [
            (
                f"**Incomplete:** {len(pieces) - len(finished)} pieces are not finished; the numbers below use the "
                f"finished ones. Continue with `bimgame reproduce --out DIR`."
            ),
            "",
        ]
    return lines


def _claims_section(numbers: dict[str, Any]) -> list[str]:
    """A table of the paper's claims, each next to what this run measured."""
    lines = ["## The paper's claims and this run", "", "| paper | this run |", "|---|---|"]
    for claim, measured in _claims(numbers):
        lines.append(f"| {claim} | {measured} |")
    lines.append("")
    return lines


def _curves_section(numbers: dict[str, Any]) -> list[str]:
    """The learning-curve figure of every task."""
    lines = ["## Learning curves", ""]
    for task, entry in numbers["tasks"].items():
        if "figure" in entry:
            lines += [f"![{task} learning curves]({entry['figure']})", ""]
        else:
            lines += [f"{task}: no finished run yet.", ""]
    return lines


def _expert_section(numbers: dict[str, Any], budget: Budget) -> list[str]:
    """The expert dataset: its lengths' figure, size and success, relabelled per task."""
    lines = ["## Expert", ""]
    expert = numbers["expert"]
    if expert["dataset"] is None:
        return lines + ["No finished expert dataset.", ""]
    d = expert["dataset"]
    return lines + [
        "![expert trajectory lengths](fig_expert_lengths.png)",
        "",
        f"Dataset: {d['episodes']} {budget.dataset.task} episodes, {d['steps']:,} steps, expert success "
        f"{d['success_rate']:.0%}, mean length {d['mean_length']:.0f} steps. Success relabelled per task "
        f"(within the task's time limit): "
        + ", ".join(f"{t} {pct(v)}" for t, v in expert["success_by_task"].items())
        + ".",
        "",
    ]


def _settings_section(budget: Budget) -> list[str]:
    """Every setting of the budget, one row each."""
    lines = ["## Settings", "", "| setting | value |", "|---|---|"]
    for key, value in budget.settings_by_path().items():
        lines.append(f"| {key} | {_setting_text(key, value, budget)} |")
    return lines


def _setting_text(key: str, value: object, budget: Budget) -> object:
    """A setting's cell: a per-task setting as ``TASK value`` pairs (the steps of the budget's tasks
    only), a list comma-separated."""
    if isinstance(value, dict):
        return ", ".join(
            f"{k} {steps_text(v) if key == 'a3c.steps' else v}"
            for k, v in value.items()
            if key != "a3c.steps" or k in budget.tasks
        )
    if isinstance(value, (list, tuple)):
        return ", ".join(map(str, value))
    return value


def _wall_time_section(pieces: list[Piece], finished: dict[str, Piece], status: dict[str, Any]) -> list[str]:
    """Every piece's state and wall time from ``status.json``, their total and the invocations'."""
    lines = ["", "## Wall time", "", "| piece | state | wall time |", "|---|---|---:|"]
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
    return lines + [
        f"| **total** | | **{format_duration(total)}** |",
        "",
        (
            f"Wall times are from `{STATUS}` (all attempts of a piece, on this machine, with whatever else ran "
            f"on it). The reproduction ran in {len(invocations)} invocation(s) of `bimgame reproduce` taking "
            f"{format_duration(elapsed)} in all."
        ),
        "",
    ]


def _verdict(result: dict[str, Any] | None) -> str:
    """What a speed-up's interval says: faster, slower or no clear difference."""
    if result is None:
        return "not measured"
    if result["bound"] in ("not reached", "unknown"):
        return {
            "not reached": "the compared runs did not reach the threshold",
            "unknown": "neither reached the threshold in every seed",
        }[result["bound"]]
    if result["ci"] is None:
        return "one seed: no interval"
    low, high = result["ci"]
    if low > 1:
        return "faster (interval above 1)"
    if high < 1:
        return "slower (interval below 1)"
    return "no clear difference (interval includes 1)"


def _claims(numbers: dict[str, Any]) -> list[tuple[str, str]]:
    """(the paper's claim, what this run measured) for each claim the report checks."""
    tasks = numbers["tasks"]
    return [
        ("Pre-training speeds learning up 2–3×", _joined(_pretraining_speedups(tasks))),
        (
            f"Pre-training reaches {PAPER_ACCURACY:.1%} held-out action accuracy",
            _joined(_pretraining_accuracies(numbers["pretraining"])),
        ),
        ("DAgger is much worse on STG2 and FULL", _joined(_dagger_against_a3c(tasks))),
        ("The value function as a reward does not help much", _joined(_value_reward_speedups(tasks))),
        ("STG3 and STG4 are not learned by any method", _joined(_hard_stages(tasks))),
    ]


def _joined(measured: list[str]) -> str:
    """A claim's measurements, or that there are none."""
    return "; ".join(measured) or _NOT_MEASURED


def _pretraining_speedups(tasks: dict[str, Any]) -> list[str]:
    """Per task: the speed-up of A3C from π^s over A3C, and whether 2–3× lies in its interval."""
    measured = []
    for task, entry in tasks.items():
        result = entry["algorithms"].get(PRETRAIN_A3C.name, {}).get(VS_BASELINE)
        if result is not None:
            inside = ""
            if result["ci"] is not None and result["bound"] == "exact":
                inside = (
                    "; 2–3× lies inside the interval"
                    if result["ci"][0] <= 3 and result["ci"][1] >= 2
                    else "; 2–3× lies outside the interval"
                )
            measured.append(f"{task}: {speedup_text(result)} — {_verdict(result)}{inside}")
    return measured


def _pretraining_accuracies(pretraining: dict[str, Any]) -> list[str]:
    """Per task: π^s's held-out action accuracy, mean and per seed."""
    return [
        f"{task}: {pct1(p['val_accuracy_mean'])} (seeds: {', '.join(pct1(v) for v in p['val_accuracy'])}; chance 20%)"
        for task, p in pretraining.items()
        if p["val_accuracy"]
    ]


def _final_success(entry: dict[str, Any], algorithm: str) -> float:
    """An algorithm's final success on a task, the better of greedy and sampled (NaN without runs)."""
    a = entry["algorithms"].get(algorithm)
    return float("nan") if a is None or not a["runs"] else max(a["final_greedy_success"], a["final_sampled_success"])


def _dagger_against_a3c(tasks: dict[str, Any]) -> list[str]:
    """On STG2, FULL and STG1 (for context): DAgger's final success against the best A3C variant's."""
    measured = []
    paper_a3c = [a.name for a in registered() if a.paper and a.learner is Learner.A3C]
    for task in ("STG2", "FULL", "STG1"):
        entry = tasks.get(task)
        if entry is None or DAGGER.name not in entry["algorithms"] or not entry["algorithms"][DAGGER.name]["runs"]:
            continue
        text = _dagger_text(task, entry, paper_a3c)
        measured.append(text + (" (context: the claim is about STG2 and FULL)" if task == "STG1" else ""))
    if not any(t in tasks for t in ("STG2", "FULL")):
        measured.insert(0, "STG2 and FULL not measured in this budget")
    return measured


def _dagger_text(task: str, entry: dict[str, Any], paper_a3c: list[str]) -> str:
    """DAgger's final success on a task and its steps, then the best of the paper's A3C variants."""
    dagger = entry["algorithms"][DAGGER.name]
    steps = nanmean([r["env_steps"] for r in dagger["runs"]])
    others = {a: _final_success(entry, a) for a in paper_a3c if not math.isnan(_final_success(entry, a))}
    best = max(others, key=others.__getitem__) if others else None
    text = (
        f"{task}: DAgger final success {pct(dagger['final_greedy_success'])} greedy, "
        f"{pct(dagger['final_sampled_success'])} sampled, after {steps_text(steps)} env steps"
    )
    if best is not None:
        b = entry["algorithms"][best]
        text += (
            f"; best A3C variant ({LABELS[best]}) {pct(b['final_greedy_success'])} greedy, "
            f"{pct(b['final_sampled_success'])} sampled, after {steps_text(entry['a3c_steps'])}"
        )
    return text


def _value_reward_speedups(tasks: dict[str, Any]) -> list[str]:
    """Per task: each value-reward algorithm's speed-up over the same start without it."""
    measured = []
    for task, entry in tasks.items():
        for base, other in value_pairs():
            result = entry["algorithms"].get(other, {}).get(f"speedup_vs_{base}")
            if result is not None:
                measured.append(
                    f"{task}, {LABELS[other]} vs {LABELS[base]}: {speedup_text(result)} — {_verdict(result)}"
                )
    return measured


def _hard_stages(tasks: dict[str, Any]) -> list[str]:
    """On STG3 and STG4: the best final success of any algorithm and which runs reached the threshold."""
    measured = []
    for task in ("STG3", "STG4"):
        entry = tasks.get(task)
        if entry is None:
            continue
        finals = {a: _final_success(entry, a) for a in entry["algorithms"] if not math.isnan(_final_success(entry, a))}
        if finals:
            best = max(finals, key=finals.__getitem__)
            reached = [a for a, v in entry["algorithms"].items() if v["reached"]]
            verdict = (
                f"reached the threshold ({pct(entry['threshold'])}): {', '.join(LABELS[a] for a in reached)}"
                if reached
                else f"no run reached the threshold ({pct(entry['threshold'])})"
            )
            measured.append(
                f"{task}: best final success {pct(finals[best])} ({LABELS[best]}, the better of greedy "
                f"and sampled evaluation); {verdict}"
            )
    return measured


_METHODS = (
    "Curves: training episodes binned by the step they started at, the task's own reward (also for shaped runs), "
    "up to one episode's time limit (in all environments' steps) before the last logged episode ended: later "
    "bins would hold only the episodes that had already ended, the short and successful ones; "
    "mean over seeds with a 95% percentile bootstrap band over seeds. DAgger: greedy evaluation after each "
    "iteration against the environment steps used so far (expert planning is counted separately in its dagger.csv). "
    "Threshold: a fraction of the expert's success rate on the task (its dataset episodes relabelled for the task). "
    "Steps to threshold: the right edge of the first bin whose training episodes reach the threshold (DAgger: the "
    "first evaluation that does). Runs that never reach it are censored at their last complete bin; "
    "speed-ups with censored "
    "runs are bounds (≥ when A3C was censored, ≤ when the compared algorithm was). Speed-up: ratio of mean steps, "
    "95% interval from a stratified bootstrap over seeds (each algorithm's seeds resampled on their own). Final "
    "success: training episodes that started in the last 10% of a run's steps before that cut; greedy: the run's final "
    "evaluation."
)

_METHODS_BEYOND = (
    "Beyond the paper: from each A3C and PPO run's periodic evaluations (eval.csv, the task's own starts, also for "
    "start-curriculum runs), step 0 being the starting policy and the last row the final evaluation; dip = the lowest "
    "success after step 0, drop = step 0's success minus the dip (0 when it never fell); steps to 80% = the first "
    "evaluation step with greedy success ≥ 80%, unreached runs counted at their last evaluation (a lower bound). "
    "Means over seeds with a 95% percentile-bootstrap interval over seeds (their own seeded generator)."
)
