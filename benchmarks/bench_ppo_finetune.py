"""PPO fine-tuning π^s on STG3 and STG4, scored greedily and sampling on the protocol's episodes.

Issue goal: from π^s, PPO (with the best fine-tuning setting) ends with greedy *and* sampled success
both ≥ 90% on STG3 and STG4, with evaluations large enough (≥ 50 episodes) to tell 10-point
differences apart. The in-run evaluations of a reproduction have 20 episodes; this benchmark scores
each run's final network with the benchmark protocol (:func:`bimgame.experiments.protocol.score`,
``--episodes`` episodes, 100 by default, greedy and sampled), and so its best iterate by the in-run
evaluations (``best.pt``, :mod:`bimgame.learn.best_iterate`: chosen on the run's 20 evaluation
episodes a mode, scored on the protocol's others).

Every run has the ``beyond`` budget's settings, as ``bimgame reproduce --budget beyond --algorithms
pretrain+ppo+keep`` trains them (:func:`~bimgame.experiments.runners.ppo_config_for`: its network,
PPO group, 500k steps and evaluations every 50k steps), starts from that seed's π^s (pre-trained here
with the budget's settings, :func:`~bimgame.experiments.runners.pretrain_config_for`, on the FULL
dataset ``DATA``) and changes only the settings given with ``--set`` (a variant: one invocation per
variant, the same steps for each). Across seeds: means with percentile-bootstrap 95% intervals
(seeds resampled); per-seed numbers in the JSON; π^s's own scores beside them.

Runs are kept in ``--out`` (a rerun reuses finished pre-trainings, runs and scores). Every π^s is
pre-trained before any run starts; start a second variant in the same ``--out`` once the first has
printed "pre-trained every π^s".

Usage: bimgame generate --task FULL --episodes 80 --out DATA
       python benchmarks/bench_ppo_finetune.py --data DATA [--tasks STG3 STG4] [--seeds 3] [--jobs 3]
       [--episodes 100] [--out runs/ppo-finetune] [--set NAME=VALUE ...] [--results FILE] [--figure FILE]
       [--scores-dir docs/scores]   (the final networks' protocol scores, as bimgame score --out writes them)
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from bench_learners import _settings

from bimgame.experiments.budgets import BUDGETS
from bimgame.experiments.protocol import score
from bimgame.experiments.run_progress import completed_with_progress, training_progress
from bimgame.experiments.runners import ppo_config_for, pretrain_config_for
from bimgame.experiments.statistics import mean_interval
from bimgame.learn.best_iterate import read_best
from bimgame.learn.checkpoints import load_checkpoint
from bimgame.learn.curves import read_table
from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.learn.pretrain import pretrain
from bimgame.learn.run_dir import BEST
from bimgame.learn.runs import torch_threads
from bimgame.util.files import atomic_write_bytes, read_json, write_json
from bimgame.util.images import save_png, subplots
from bimgame.util.processes import exit_when_parent_dies

ROOT = Path(__file__).resolve().parents[1]
BUDGET = BUDGETS["beyond"]
ALGORITHM = "pretrain+ppo+keep"
MODES = ("greedy", "sampled")


def _pretrained(out: Path, data: Path, task: str, seed: int) -> Path:
    """That task's and seed's π^s, pre-trained with the budget's settings unless already there."""
    path = out / "pi-s" / task / f"seed{seed}"
    if (path / "summary.json").is_file():
        return path
    if path.exists():  # an unfinished pre-training cannot resume: start it again
        raise SystemExit(f"{path} is an unfinished pre-training; remove it and run again")
    pretrain(pretrain_config_for(BUDGET, task, seed, "policy"), data, path, progress=False)
    return path


def _scores(source: Path, task: str, episodes: int) -> dict[str, Any]:
    """Greedy and sampled success and mean return of ``source`` (a run's final network, or a
    checkpoint file such as its ``best.pt``) on ``episodes`` protocol episodes, with the protocol's
    whole summary per mode (what ``bimgame score --out`` writes); cached beside it per checkpoint step."""
    if source.is_file():
        weights, cache = source, source.with_name(f"{source.stem}_protocol_scores.json")
    else:
        weights, cache = source / "checkpoint.pt", source / "protocol_scores.json"
    step = load_checkpoint(weights)["step"] if weights.is_file() else 0
    cached = read_json(cache)
    if (
        cached is not None
        and (cached.get("episodes"), cached.get("step")) == (episodes, step)
        and "summaries" in cached
    ):
        return cached
    out: dict[str, Any] = {"episodes": episodes, "step": step, "summaries": {}}
    for mode in MODES:
        summary = score(str(source), task, obs="state", episodes=episodes, sampled=mode == "sampled")
        out[f"{mode}_success"] = summary["success_rate"]
        out[f"{mode}_mean_return"] = summary["mean_return"]
        out["summaries"][mode] = {"policy": str(source), **summary}
    atomic_write_bytes(cache, json.dumps(out, indent=2).encode())
    return out


def _write_score_files(directory: Path, name: str, done: dict[tuple[str, int], dict[str, Any]]) -> list[Path]:
    """Every final network's protocol summaries as the score pages' files:
    ``TASK-state-NAME[-sampled]-seedS.json`` in ``directory``, one per run and mode."""
    paths = []
    for (task, seed), run in sorted(done.items()):
        for mode in MODES:
            infix = "-sampled" if mode == "sampled" else ""
            path = directory / f"{task}-state-{name}{infix}-seed{seed}.json"
            summary = run["final"]["summaries"][mode]
            source = Path(summary["policy"])
            shown = source.relative_to(ROOT) if source.is_relative_to(ROOT) else source
            paths.append(write_json(path, {**summary, "policy": str(shown)}))
    return paths


def _pretrain_job(task: str, seed: int, args: argparse.Namespace) -> Path:
    """Pre-train one task's and seed's π^s with one torch thread (unless already there)."""
    with torch_threads(1):
        return _pretrained(args.out, args.data, task, seed)


def _job(task: str, seed: int, args: argparse.Namespace, run_dir: Path) -> dict[str, Any]:
    """Fine-tune and score one task and seed with one torch thread."""
    with torch_threads(1):
        pi_s = _pretrained(args.out, args.data, task, seed)
        summary = read_json(run_dir / "summary.json")
        if summary is None or summary.get("stopped") != "finished":
            config = _config(task, seed, args)
            resume = (run_dir / "config.json").is_file()
            train_ppo(config, run_dir, resume=resume, init=None if resume else pi_s, progress=False)
            summary = read_json(run_dir / "summary.json") or {}
        best = run_dir / BEST
        return {
            "pi_s": _scores(pi_s, task, args.episodes),
            "final": _scores(run_dir, task, args.episodes),
            **({"best": {**_scores(best, task, args.episodes), "chosen_at": read_best(best)}} if best.exists() else {}),
            "train_minutes": float(summary.get("seconds", 0.0)) / 60,
            "evaluations": _evaluations(run_dir),
        }


def _config(task: str, seed: int, args: argparse.Namespace) -> PPOConfig:
    """The PPO settings of one task and seed: the budget's, with ``--set``'s changes."""
    return ppo_config_for(BUDGET, task, seed, ALGORITHM, args.data).with_flat(**args.settings)


def _evaluations(run_dir: Path) -> list[dict[str, float]]:
    """The run's in-run evaluations (step, greedy and sampled success), for the figure."""
    table = read_table(run_dir / "eval.csv")
    if not table:
        return []
    columns = zip(table["step"], table["greedy_success_rate"], table["sampled_success_rate"], strict=True)
    return [
        {"step": float(step), "greedy_success": float(greedy), "sampled_success": float(sampled)}
        for step, greedy, sampled in columns
    ]


def _aggregate(per_seed: list[dict[str, Any]], rng: np.random.Generator) -> dict[str, Any]:
    """Mean over seeds of ``per_seed[i][source][metric]`` for every source and metric, with intervals."""
    out: dict[str, Any] = {}
    sources = ("pi_s", "final", "best") if all("best" in run for run in per_seed) else ("pi_s", "final")
    for source in sources:
        for metric in ("greedy_success", "sampled_success", "greedy_mean_return", "sampled_mean_return"):
            values = np.array([run[source][metric] for run in per_seed])
            low, high = mean_interval(values, rng=rng)
            out[f"{source}_{metric}"] = {
                "mean": float(values.mean()),
                "interval": [low, high],
                "per_seed": values.tolist(),
            }
    return out


def _plot(results: dict[str, Any], path: Path, title: str) -> Path:
    """Per task: in-run greedy and sampled success against steps, one line per seed, and the final
    protocol scores as points at the end."""
    tasks = list(results["tasks"])
    fig, axes = subplots(1, len(tasks), figsize=(5.5 * len(tasks), 4), layout="constrained", squeeze=False)
    colours = {"greedy": "tab:blue", "sampled": "tab:orange"}
    for axis, task in zip(axes[0], tasks, strict=True):
        entry = results["tasks"][task]
        end = results["steps"] / 1e3
        for k, run in enumerate(entry["runs"]):
            for mode in MODES:
                points = [e for e in run["evaluations"] if f"{mode}_success" in e]
                axis.plot(
                    [e["step"] / 1e3 for e in points],
                    [100 * e[f"{mode}_success"] for e in points],
                    color=colours[mode],
                    alpha=0.6,
                    label=f"{mode} (20 episodes)" if k == 0 else None,
                )
                axis.scatter(
                    [end * 1.03],
                    [100 * run["final"][f"{mode}_success"]],
                    color=colours[mode],
                    marker="D",
                    label=f"{mode}, final ({results['episodes']} episodes)" if k == 0 else None,
                )
                if "best" in run:
                    axis.scatter(
                        [end * 1.06],
                        [100 * run["best"][f"{mode}_success"]],
                        facecolors="none",
                        edgecolors=colours[mode],
                        marker="o",
                        label=f"{mode}, best.pt ({results['episodes']} episodes)" if k == 0 else None,
                    )
        axis.axhline(90, color="k", linestyle=":", label="goal 90%")
        axis.set(title=task, xlabel="steps (k)", ylabel="success (%)", ylim=(-3, 103))
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8, loc="lower right")
    fig.suptitle(title, fontsize=10)
    return save_png(fig, path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="a FULL expert dataset (bimgame generate)")
    parser.add_argument("--tasks", nargs="+", choices=("STG2", "STG3", "STG4", "FULL"), default=["STG3", "STG4"])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=100, help="protocol episodes per mode (default 100)")
    parser.add_argument("--jobs", type=int, default=3, help="runs trained at once, one thread each (default 3)")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "ppo-finetune")
    parser.add_argument("--set", nargs="+", default=[], metavar="NAME=VALUE", help="PPO settings of this variant")
    parser.add_argument("--results", type=Path, default=None, help="default benchmarks/results/ppo_finetune[-SET].json")
    parser.add_argument("--figure", type=Path, default=None, help="default docs/ppo/finetune[-SET].png")
    parser.add_argument(
        "--scores-dir",
        type=Path,
        default=None,
        help="also write the final networks' protocol scores here, one file per run and mode",
    )
    args = parser.parse_args(argv)
    if not (args.data / "COMPLETE").is_file():
        parser.error(f"--data {args.data} is not a finished dataset (no COMPLETE marker): run bimgame generate")
    args.data = args.data.absolute()
    args.out = args.out.absolute()
    args.settings = _settings(args.set, parser)
    suffix = "".join(f"-{key.replace('_', '-')}{value}" for key, value in sorted(args.settings.items()))
    results_path = args.results or ROOT / "benchmarks" / "results" / f"ppo_finetune{suffix.replace('-', '_')}.json"
    figure_path = args.figure or ROOT / "docs" / "ppo" / f"finetune{suffix}.png"
    jobs = {(t, s): args.out / f"keep{suffix}" / t / f"seed{s}" for t in args.tasks for s in range(args.seeds)}
    done: dict[tuple[str, int], dict[str, Any]] = {}
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=args.jobs, mp_context=context, initializer=exit_when_parent_dies) as pool:
        # Every π^s first: runs of two variants started together would otherwise pre-train one twice.
        list(pool.map(_pretrain_job, *zip(*[(t, s, args) for t, s in jobs], strict=True)))
        print("pre-trained every π^s", flush=True)
        futures = {pool.submit(_job, t, s, args, run_dir): (t, s) for (t, s), run_dir in jobs.items()}
        steps = {key: _config(*key, args).schedule.steps for key in jobs}
        for future in completed_with_progress(
            futures, lambda key: training_progress(jobs[key], steps[key]), name=lambda key: f"{key[0]} seed {key[1]}"
        ):
            key = futures[future]
            done[key] = run = future.result()
            best = (
                f"; best.pt (step {run['best']['chosen_at']['step']:,}) greedy {run['best']['greedy_success']:.0%} "
                f"sampled {run['best']['sampled_success']:.0%}"
                if "best" in run
                else ""
            )
            print(
                f"{key[0]} seed {key[1]}: greedy {run['final']['greedy_success']:.0%} "
                f"sampled {run['final']['sampled_success']:.0%}{best} (π^s {run['pi_s']['greedy_success']:.0%} · "
                f"{run['pi_s']['sampled_success']:.0%}; {run['train_minutes']:.1f} min)",
                flush=True,
            )
    rng = np.random.default_rng(0)
    first = ppo_config_for(BUDGET, args.tasks[0], 0, ALGORITHM, args.data).with_flat(**args.settings)
    results: dict[str, Any] = {
        "algorithm": ALGORITHM,
        "budget": BUDGET.name,
        "steps": first.schedule.steps,
        "settings": args.settings,
        "finetuning": None if first.finetuning is None else dataclasses.asdict(first.finetuning),
        "seeds": args.seeds,
        "episodes": args.episodes,
        "data": str(args.data),
        "tasks": {},
    }
    for task in args.tasks:
        runs = [done[(task, s)] for s in range(args.seeds)]
        results["tasks"][task] = {**_aggregate(runs, rng), "runs": runs}
    results_path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(results_path, json.dumps(results, indent=2).encode())
    if args.scores_dir is not None:
        written = _write_score_files(args.scores_dir, f"pretrain-ppo-keep{suffix}", done)
        print(f"wrote {len(written)} score files in {args.scores_dir}")
    shown = "".join(f", {key} {value}" for key, value in sorted(args.settings.items())) or ", keep's KL"
    title = f"PPO from π^s{shown}, {first.schedule.steps:,} steps, {args.seeds} seeds"
    print(f"wrote {results_path} and {_plot(results, figure_path, title)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
