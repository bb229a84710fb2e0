"""The report's text: ``table_speedup.md`` (steps to threshold, speed-ups, final success, pre-training)
and ``report.md`` (each claim of the paper next to what this run measured, the figures, the tables,
the section beyond the paper (:func:`beyond_markdown`), the settings and wall times, and how the
numbers are computed), written from the numbers :func:`bimgame.experiments.report.build_report`
assembles.
"""

from __future__ import annotations

import math
from typing import Any

from bimgame.experiments.algorithms import BASELINE, DAGGER, LABELS, PRETRAIN_A3C, Learner, registered
from bimgame.experiments.budgets import Budget
from bimgame.experiments.costs import format_duration
from bimgame.experiments.grid import Piece
from bimgame.experiments.plan import STATUS, timestamp
from bimgame.experiments.statistics import nanmean

__all__ = ["PAPER_ACCURACY", "tables_markdown", "beyond_markdown", "report_markdown"]

#: The paper's held-out action accuracy of pre-training.
PAPER_ACCURACY = 0.275
#: Where an algorithm's speed-up over the baseline is in its numbers.
_VS_BASELINE = f"speedup_vs_{BASELINE.name}"


def _value_pairs() -> list[tuple[str, str]]:
    """(algorithm without the value reward, the same with it), for every value-reward algorithm."""
    return [(a.without_value_reward, a.name) for a in registered() if a.without_value_reward is not None]


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


def _pct1(value: float | None) -> str:
    return "–" if value is None or math.isnan(value) else f"{value:.1%}"


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


def tables_markdown(numbers: dict[str, Any], budget: Budget) -> str:
    """``table_speedup.md``: per task, steps to threshold and speed-ups per algorithm; then pre-training."""
    lines = ["# Steps to threshold and speed-up over A3C", ""]
    if BASELINE.name not in budget.algorithms:
        lines += [("A3C from random weights is not in this grid: there is no baseline, so no speed-up over it is "
                  "given (add it with `--algorithms`)."), ""]
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
                         f"\"> N\": not reached by step N, up to which all its training episodes had ended (censored).")
            lines.append("")
        seeds = [a["seeds_finished"] for a in entry["algorithms"].values() if a["seeds_finished"]]
        if seeds and min(seeds) < 5:
            lines += [(f"With {min(seeds)} seed(s) per algorithm the bootstrap intervals are rough: resampling "
                      f"{min(seeds)} values can only give a handful of distinct means, so the intervals understate "
                      f"the uncertainty. Use more seeds (`--seeds`) for firm conclusions."), ""]
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
            speed = ("1 (baseline)" if algorithm == BASELINE.name and a["runs"]
                     else _speedup_text(a.get(_VS_BASELINE)))
            training = a["final_success_training"]
            lines.append(f"| {LABELS[algorithm]} | {a['seeds_finished']}/{a['seeds_planned']} | "
                         f"{reached if entry['threshold'] is not None else '–'}/{len(a['runs'])} | {per_seed} | "
                         f"{mean_text} | {speed} | {'–' if training is None else _pct(training)} | "
                         f"{_pct(a['final_greedy_success'])} | {_pct(a['final_sampled_success'])} |")
        lines.append("")
        curricula = [a for a, v in entry["algorithms"].items() if v.get("start_curriculum")]
        if curricula:
            lines += [(f"{', '.join(LABELS[a] for a in curricula)}: no steps to threshold or training "
                      f"success — with a start curriculum the training episodes start nearer the goal than the "
                      f"task's; see the evaluations beyond the paper."), ""]
        extra = [(o, b, entry["algorithms"][o].get(f"speedup_vs_{b}")) for b, o in _value_pairs()
                 if o in entry["algorithms"]]
        extra = [(o, b, s) for o, b, s in extra if s is not None]
        if extra:
            lines.append("Value reward against the same start without it: " + "; ".join(
                f"{LABELS[o]} vs {LABELS[b]}: {_speedup_text(s)}" for o, b, s in extra) + ".")
            lines.append("")
    lines += ["# Pre-training", ""]
    if not numbers["pretraining"]:
        lines += ["No finished pre-training.", ""]
    else:
        lines.append(f"| task | π^s held-out accuracy (paper: {PAPER_ACCURACY:.1%}; chance 20%) | per seed | "
                     f"π^s alone, greedy success | π^s alone, sampled success | V̂ held-out RMSE |")
        lines.append("|---|---:|---|---|---|---|")
        for task, p in numbers["pretraining"].items():
            per_seed = ", ".join(_pct1(v) for v in p["val_accuracy"]) or "–"
            lines.append(f"| {task} | {_pct1(p['val_accuracy_mean'])} | {per_seed} | "
                         f"{', '.join(_pct(v) for v in p['policy_greedy_success']) or '–'} | "
                         f"{', '.join(_pct(v) for v in p['policy_sampled_success']) or '–'} | "
                         f"{', '.join(f'{v:.3f}' for v in p['value_rmse'] if v is not None) or '–'} |")
        lines.append("")
        lines.append(f"π^s alone: {budget.pretrain_eval_episodes} greedy and {budget.pretrain_eval_episodes} sampled "
                     f"episodes per seed, before any A3C update.")
        lines.append("")
    return "\n".join(lines)


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
        result = entry["algorithms"].get(PRETRAIN_A3C.name, {}).get(_VS_BASELINE)
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
    paper_a3c = [a.name for a in registered() if a.paper and a.learner is Learner.A3C]
    for task in ("STG2", "FULL", "STG1"):
        entry = tasks.get(task)
        if entry is None or DAGGER.name not in entry["algorithms"] or not entry["algorithms"][DAGGER.name]["runs"]:
            continue
        dagger = entry["algorithms"][DAGGER.name]
        steps = nanmean([r["env_steps"] for r in dagger["runs"]])
        others = {a: final(entry, a) for a in paper_a3c if not math.isnan(final(entry, a))}
        best = max(others, key=others.__getitem__) if others else None
        text = (f"{task}: DAgger final success {_pct(dagger['final_greedy_success'])} greedy, "
                f"{_pct(dagger['final_sampled_success'])} sampled, after {_steps_text(steps)} env steps")
        if best is not None:
            b = entry["algorithms"][best]
            text += (f"; best A3C variant ({LABELS[best]}) {_pct(b['final_greedy_success'])} greedy, "
                     f"{_pct(b['final_sampled_success'])} sampled, after {_steps_text(entry['a3c_steps'])}")
        measured.append(text + (" (context: the claim is about STG2 and FULL)" if task == "STG1" else ""))
    if not any(t in tasks for t in ("STG2", "FULL")):
        measured.insert(0, "STG2 and FULL not measured in this budget")
    claims.append(("DAgger is much worse on STG2 and FULL", "; ".join(measured) or "not measured in this budget"))

    measured = []
    for task, entry in tasks.items():
        for base, other in _value_pairs():
            result = entry["algorithms"].get(other, {}).get(f"speedup_vs_{base}")
            if result is not None:
                measured.append(f"{task}, {LABELS[other]} vs {LABELS[base]}: {_speedup_text(result)} — "
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
            best = max(finals, key=finals.__getitem__)
            reached = [a for a, v in entry["algorithms"].items() if v["reached"]]
            verdict = (f"reached the threshold ({_pct(entry['threshold'])}): {', '.join(LABELS[a] for a in reached)}"
                       if reached else f"no run reached the threshold ({_pct(entry['threshold'])})")
            measured.append(f"{task}: best final success {_pct(finals[best])} ({LABELS[best]}, the better of greedy "
                            f"and sampled evaluation); {verdict}")
    claims.append(("STG3 and STG4 are not learned by any method",
                   "; ".join(measured) or "not measured in this budget"))
    return claims


def report_markdown(numbers: dict[str, Any], tables: str, budget: Budget, pieces: list[Piece],
                     finished: dict[str, Piece], status: dict[str, Any]) -> str:
    """``report.md``: the paper's claims against this run, figures, ``tables`` (from
    :func:`tables_markdown`), settings, wall times and the methods."""
    lines = ["# Reproduction: Trajectory-based Learning for Ball-in-Maze Games", "",
             (f"Budget **{budget.name}**: tasks {', '.join(budget.tasks)}; algorithms "
             f"{', '.join(LABELS[a] for a in budget.algorithms)}; {budget.seeds} seeds; {budget.obs} observations. "
             f"{len(finished)} of {len(pieces)} pieces finished. Report built "
             f"{timestamp()} by `bimgame report`."), ""]
    if len(finished) < len(pieces):
        lines += [(f"**Incomplete:** {len(pieces) - len(finished)} pieces are not finished; the numbers below use the "
                  f"finished ones. Continue with `bimgame reproduce --out DIR`."), ""]
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
    if numbers.get("beyond") is not None:
        lines += [beyond_markdown(numbers["beyond"], budget), ""]
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
              (f"Wall times are from `{STATUS}` (all attempts of a piece, on this machine, with whatever else ran "
              f"on it). The reproduction ran in {len(invocations)} invocation(s) of `bimgame reproduce` taking "
              f"{format_duration(elapsed)} in all."), ""]
    lines += ["## How the numbers are computed", "", _METHODS, ""]
    if numbers.get("beyond") is not None:
        lines += [_METHODS_BEYOND, ""]
    return "\n".join(lines)


def _mean_text(summary: dict[str, Any], show: Any) -> str:
    """``mean [low, high]`` of a :func:`~bimgame.experiments.beyond.mean_ci` summary."""
    if summary["n"] == 0:
        return "–"
    text = f"**{show(summary['mean'])}**"
    return text + (f" [{show(summary['ci'][0])}, {show(summary['ci'][1])}]" if summary["ci"] is not None else "")


def _points(value: float | None) -> str:
    """A difference of success rates in percentage points."""
    return "–" if value is None or math.isnan(value) else f"{100 * value:.0f} pts"


def _cell(a: dict[str, Any], name: str, show: Any, step: str | None = None) -> str:
    """Every seed's value of ``name`` (with the step it was at), then the mean over seeds and its interval."""
    values = [show(r[name]) + (f" @ {_steps_text(r[step])}" if step and r[step] is not None else "")
              for r in a["runs"]]
    return f"{', '.join(values) or '–'}; mean {_mean_text(a[name], show)}"


def _target_cell(a: dict[str, Any]) -> str:
    """Steps to the target: per seed ("> N": not reached by the last evaluation, at N), then the mean."""
    per_seed = ", ".join(_steps_text(r["steps_to_target"]) if r["steps_to_target"] is not None
                         else f"> {_steps_text(r['censored_at'])}" if r["censored_at"] is not None else "–"
                         for r in a["runs"]) or "–"
    s = a["steps_to_target"]
    if s["bound"] is None:
        mean = "–"
    elif s["bound"] == "not reached":
        mean = "not reached"
    else:
        mean = ("≥ " if s["bound"] == "lower" else "") + f"**{_steps_text(s['mean'])}**"
        if s["ci"] is not None:
            mean += f" [{_steps_text(s['ci'][0])}, {_steps_text(s['ci'][1])}]"
    return f"{per_seed}; mean {mean} ({s['reached']}/{len(a['runs'])} reached)"


def beyond_markdown(beyond: dict[str, Any], budget: Budget) -> str:
    """The report's section beyond the paper: per task, the evaluations' figure and two tables —
    success (step 0, final, steps to the target) and forgetting (the dip after step 0) — with every
    seed's value and the mean over seeds with its bootstrap interval."""
    target = beyond["target"]
    every = f"every {_steps_text(budget.eval_every)} steps" if budget.eval_every else "at the end only"
    lines = ["## Beyond the paper: fine-tuning that keeps π^s", "",
             (f"From each A3C run's evaluations ({budget.eval_episodes} greedy and {budget.eval_episodes} sampled "
             f"episodes from the task's own starts, {every}; step 0 is the policy the run started from — π^s for "
             f"the pre-trained starts — and the last evaluation the final one). Each cell: every seed's value, then "
             f"the mean over seeds with its 95% percentile-bootstrap interval over seeds (never the best seed). "
             f"Dip: the lowest success after step 0 (@ the step it was at) and how far it fell below step 0's. "
             f"Steps to {target:.0%}: the first evaluation with greedy success ≥ {target:.0%} (0: the starting "
             f"policy already was; \"> N\": not reached by the last evaluation, at N, and the mean is then a "
             f"lower bound). DAgger has no such evaluations and is left out."), ""]
    if budget.seeds < 5:
        lines += [f"With {budget.seeds} seed(s) the intervals are rough (a handful of distinct resampled means).", ""]
    for task, entry in beyond["tasks"].items():
        lines += [f"### {task}", ""]
        groups = {a: v for a, v in entry["algorithms"].items() if v["runs"]}
        if not groups:
            lines += ["No finished A3C run yet.", ""]
            continue
        if "figure" in entry:
            lines += [f"![{task} evaluations]({entry['figure']})", ""]
        lines += [(f"| algorithm | seeds | step 0, greedy | step 0, sampled | final greedy | final sampled | "
                  f"steps to {target:.0%} greedy |"), "|---|---:|---|---|---|---|---|"]
        for algorithm, a in groups.items():
            lines.append(f"| {LABELS[algorithm]} | {a['seeds_finished']}/{a['seeds_planned']} | "
                         f"{_cell(a, 'start_greedy', _pct)} | {_cell(a, 'start_sampled', _pct)} | "
                         f"{_cell(a, 'final_greedy', _pct)} | {_cell(a, 'final_sampled', _pct)} | {_target_cell(a)} |")
        lines += ["", ("| algorithm | dip: lowest greedy after step 0 | greedy drop below step 0 | "
                      "dip: lowest sampled after step 0 | sampled drop below step 0 |"), "|---|---|---|---|---|"]
        for algorithm, a in groups.items():
            lines.append(f"| {LABELS[algorithm]} | {_cell(a, 'lowest_greedy', _pct, 'lowest_greedy_step')} | "
                         f"{_cell(a, 'drop_greedy', _points)} | "
                         f"{_cell(a, 'lowest_sampled', _pct, 'lowest_sampled_step')} | "
                         f"{_cell(a, 'drop_sampled', _points)} |")
        lines.append("")
        lines += [_beyond_summary(groups), ""]
    return "\n".join(lines).rstrip("\n")


def _beyond_summary(groups: dict[str, dict[str, Any]]) -> str:
    """One line per task: the algorithm with the highest mean final greedy success and the one that
    fell furthest below its start."""
    def best(name: str) -> tuple[str, float] | None:
        means = {a: v[name]["mean"] for a, v in groups.items() if v[name]["n"]}
        return max(means.items(), key=lambda item: item[1]) if means else None

    parts = []
    final = best("final_greedy")
    if final is not None:
        parts.append(f"highest mean final greedy success: {LABELS[final[0]]} ({_pct(final[1])})")
    drop = best("drop_greedy")
    if drop is not None:
        parts.append(f"largest mean greedy drop below step 0: {LABELS[drop[0]]} ({_points(drop[1])})"
                     if drop[1] > 0 else "no run's greedy success fell below its step 0")
    return ("In short: " + "; ".join(parts) + ".") if parts else ""


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
    "evaluation.")

_METHODS_BEYOND = (
    "Beyond the paper: from each A3C run's periodic evaluations (eval.csv, the task's own starts, also for start-"
    "curriculum runs), step 0 being the starting policy and the last row the final evaluation; dip = the lowest "
    "success after step 0, drop = step 0's success minus the dip (0 when it never fell); steps to 80% = the first "
    "evaluation step with greedy success ≥ 80%, unreached runs counted at their last evaluation (a lower bound). "
    "Means over seeds with a 95% percentile-bootstrap interval over seeds (their own seeded generator).")
