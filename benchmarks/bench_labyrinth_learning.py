"""Learning CyberRunner's labyrinth: PPO with CyberRunner's continuous actions, trained from the
layout's start (``none``), with the start curriculum along the printed path (``reverse``,
:class:`~bimgame.learn.path_starts.PathStartCurriculum`) and from the expert's states (``demo``,
:class:`~bimgame.learn.path_starts.DemoPathStarts`, with ``--expert-data``) or from all of them at once
(``demo-uniform``), the same step budget for each, several seeds.

Each run's final network is scored from the layout's own start, greedily and sampling, on
``--episodes`` episodes with the labyrinth's scoring protocol
(:func:`~bimgame.experiments.labyrinth_protocol.score_labyrinth`); completion times are the
successful episodes' lengths at 55 Hz, against
CyberRunner's 14.48 s and the human record 15.41 s (hard layout). Across seeds: means with
percentile-bootstrap 95% intervals (seeds resampled); per seed numbers are in the JSON. Runs are kept
in ``--out`` (a rerun reuses finished runs and their scores and resumes interrupted ones).

Writes ``--results`` (default benchmarks/results/labyrinth_learning.json) and ``--figure`` (default
docs/labyrinth/learning.png): success from the layout's start during training (training episodes,
the curriculum's excluded) and the curriculum's reach (metres of path before the goal) against steps.

Usage: python benchmarks/bench_labyrinth_learning.py [--layout easy] [--obs state|cyberrunner|pixels]
       [--steps 1000000] [--seeds 3] [--curricula reverse none] [--jobs 3] [--episodes 100]
       [--out runs/labyrinth-learning] [--set NAME=VALUE ...]   (other PPO settings, e.g. entropy_coef=0)
       [--init PI_S]   (every run starts from a pre-trained π^s: bimgame pretrain on a labyrinth dataset)
       [--expert-data DATA]   (the demo curriculum's expert dataset: bimgame generate --task LABYRINTH-…)
       [--kl-teacher 'STATE_RUNS/seed{seed}/checkpoint.pt']   (the KL pulls towards a state policy, not π^s;
       with --set kl_coef=…)
"""

from __future__ import annotations

import argparse
import csv
import json
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from bench_learners import _settings

from bimgame.envs.puzzles import puzzle
from bimgame.experiments.labyrinth_protocol import CYBERRUNNER_RECORD_S, HUMAN_RECORD_S, score_labyrinth
from bimgame.experiments.run_progress import completed_with_progress, training_progress
from bimgame.experiments.statistics import mean_interval
from bimgame.learn.checkpoints import load_checkpoint
from bimgame.learn.common import read_run
from bimgame.learn.learner_settings import DEMONSTRATION_STARTS
from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.learn.runs import CHECKPOINT, torch_threads
from bimgame.util.files import atomic_write_bytes, read_json
from bimgame.util.images import save_png, subplots
from bimgame.util.processes import exit_when_parent_dies

ROOT = Path(__file__).resolve().parents[1]
CURRICULA = ("reverse", "none", "demo", "demo-uniform")
MODES = ("greedy", "sampled")
#: Evaluation seed of the scores (the same start noise for every run).
SCORE_SEED = 12345
#: Steps per point of the training curves.
CURVE_BIN = 25_000


def _train(
    run_dir: Path,
    *,
    layout: str,
    obs: str,
    steps: int,
    seed: int,
    curriculum: str,
    settings: dict[str, Any],
    init: Path | None = None,
    expert_data: Path | None = None,
) -> float:
    """Train one run unless ``run_dir`` holds a finished one, resuming an interrupted one from its last
    checkpoint (long runs, such as pixels', span several sittings); the wall-clock seconds this call's
    training took (a reused run's as its summary recorded them)."""
    summary = read_json(run_dir / "summary.json")
    if summary is not None and summary.get("stopped") == "finished":
        return float(summary.get("seconds", 0.0))
    config = PPOConfig.from_flat(
        dict(
            task=f"LABYRINTH-{layout.upper()}",
            obs=obs,
            action_type="continuous",
            steps=steps,
            seed=seed,
            eval_every=0,
            eval_episodes=20,
            start_curriculum=curriculum,
            **({"expert_data": str(expert_data)} if curriculum in DEMONSTRATION_STARTS else {}),
            **settings,
        )
    )
    start = time.perf_counter()
    resume = (run_dir / CHECKPOINT).exists()  # written first: the run started, so it continues
    train_ppo(config, run_dir, resume=resume, init=None if resume else init, progress=False)
    return time.perf_counter() - start


def _score(source: Path, episodes: int) -> dict[str, Any]:
    """Success, median completion time and mean return of a run's network from the layout's own
    start, greedy and sampled: the labyrinth's scoring protocol (:func:`score_labyrinth`) on
    ``episodes`` episodes from :data:`SCORE_SEED`. ``source`` is the run directory (its final network)
    or a checkpoint file in it (such as DAgger's ``best.pt``); cached in the run directory per source
    and checkpoint step."""
    run_dir = source.parent if source.is_file() else source
    scores_file = run_dir / ("labyrinth_scores.json" if source.is_dir() else f"labyrinth_scores_{source.stem}.json")
    step = load_checkpoint(source)["step"]
    cached = read_json(scores_file)
    if cached is not None and cached.get("episodes") == episodes and cached.get("step") == step:
        return cached
    scores: dict[str, Any] = {"episodes": episodes, "step": step}
    task = read_run(run_dir).task
    for mode in MODES:
        summary = score_labyrinth(
            source, task, episodes=episodes, sampled=mode == "sampled", seed=SCORE_SEED, progress=False
        )
        scores[f"{mode}_success"] = summary["success_rate"]
        scores[f"{mode}_median_seconds"] = summary["completion_time_s"]["median"]
        scores[f"{mode}_mean_return"] = summary["mean_return"]
    atomic_write_bytes(scores_file, json.dumps(scores, indent=2).encode())
    return scores


def _for_seed(path: str | Path, seed: int) -> Path:
    """``path`` with ``{seed}`` replaced by the run's seed (``--init``'s and ``--kl-teacher``'s)."""
    return Path(str(path).replace("{seed}", str(seed)))


def _init_for(init: Path | None, seed: int) -> Path | None:
    """The weights seed ``seed`` starts from: ``--init`` with ``{seed}`` replaced by the seed (one
    starting network per seed, e.g. each DAgger seed's ``best.pt``), or the same for every seed."""
    return None if init is None else _for_seed(init, seed)


def _init_scores(args: argparse.Namespace) -> list[dict[str, Any]] | dict[str, Any] | None:
    """The starting networks' own scores: one per seed when ``--init`` names one per seed
    (``{seed}``), else the one every seed starts from (None without ``--init``)."""
    if args.init is None:
        return None
    starts = [_init_for(args.init, seed) for seed in range(args.seeds)] if "{seed}" in str(args.init) else [args.init]
    entries = [{"run": str(start), "scores": _score(start, args.episodes)} for start in starts]
    return entries if "{seed}" in str(args.init) else entries[0]


def _job(run_dir: Path, curriculum: str, seed: int, args: argparse.Namespace) -> tuple[float, dict[str, Any]]:
    """Train and score one run with one torch thread: a job of ``--jobs``."""
    with torch_threads(1):
        teacher = {} if args.kl_teacher is None else {"kl_teacher": str(_for_seed(args.kl_teacher, seed).absolute())}
        seconds = _train(
            run_dir,
            layout=args.layout,
            obs=args.obs,
            steps=args.steps,
            seed=seed,
            curriculum=curriculum,
            settings={**args.settings, **teacher},
            init=_init_for(args.init, seed),
            expert_data=args.expert_data,
        )
        return seconds, _score(run_dir, args.episodes)


def _curve(run_dir: Path, steps: int) -> dict[str, list[float]]:
    """Per ``CURVE_BIN`` steps: the success rate and mean return of training episodes from the
    layout's own start, and the curriculum's reach (m of path before the goal; NaN without a
    curriculum)."""
    edges = np.arange(CURVE_BIN, steps + CURVE_BIN, CURVE_BIN)
    with (run_dir / "episodes.csv").open(newline="") as handle:
        episodes = [row for row in csv.DictReader(handle) if row["true_start"] != "False"]
    ends = np.array([float(row["step"]) for row in episodes])
    wins = np.array([row["success"] == "True" for row in episodes])
    returns = np.array([float(row["return"]) for row in episodes])
    bins = [(ends > e - CURVE_BIN) & (ends <= e) for e in edges]
    success = [float(wins[b].mean()) if b.any() else float("nan") for b in bins]
    mean_return = [float(returns[b].mean()) if b.any() else float("nan") for b in bins]
    with (run_dir / "updates.csv").open(newline="") as handle:
        updates = list(csv.DictReader(handle))
    reach = []
    for edge in edges:
        rows = [row for row in updates if float(row["step"]) <= edge and row.get("curriculum_start_distance")]
        reach.append(float(rows[-1]["curriculum_start_distance"]) if rows else float("nan"))
    return {"step": edges.tolist(), "success": success, "return": mean_return, "curriculum_reach": reach}


def _aggregate(per_seed: list[dict[str, Any]], rng: np.random.Generator) -> dict[str, Any]:
    """Means over seeds with bootstrap intervals; median times pooled over the seeds that finished."""
    out: dict[str, Any] = {}
    for key in ("greedy_success", "sampled_success", "greedy_mean_return", "sampled_mean_return"):
        array = np.array([scores[key] for scores in per_seed])
        low, high = mean_interval(array, rng=rng)
        out[key] = {"mean": float(array.mean()), "interval": [low, high], "per_seed": array.tolist()}
    for mode in MODES:
        out[f"{mode}_median_seconds_per_seed"] = [scores[f"{mode}_median_seconds"] for scores in per_seed]
    return out


def _plot(results: dict[str, Any], path: Path, title: str) -> Path:
    """Success and mean return of training episodes from the layout's start against steps (the
    return shows how far runs that complete nothing get) and, when a run had a curriculum, its reach."""
    with_reach = any(curriculum != "none" for curriculum in results["curricula"])
    columns = 3 if with_reach else 2
    fig, axes = subplots(1, columns, figsize=(5.5 * columns, 4), layout="constrained")
    success_axis, return_axis = axes[0], axes[1]
    reach_axis = axes[2] if with_reach else None
    colours = {"reverse": "tab:blue", "none": "tab:gray", "demo": "tab:green", "demo-uniform": "tab:olive"}
    for curriculum, entry in results["curricula"].items():
        for k, curve in enumerate(entry["curves"]):
            label = curriculum if k == 0 else None
            steps = np.array(curve["step"]) / 1e3
            style = {"color": colours[curriculum], "alpha": 0.8, "label": label}
            success_axis.plot(steps, 100 * np.array(curve["success"]), **style)
            if "return" in curve:  # results written before the return was kept have none
                return_axis.plot(steps, curve["return"], **style)
            if reach_axis is not None and curriculum != "none":
                reach_axis.plot(steps, curve["curriculum_reach"], **style)
    success_axis.set(xlabel="steps (k)", ylabel="success from the layout's start (%)", ylim=(-3, 103))
    return_axis.set(xlabel="steps (k)", ylabel="mean return (1.25 per m of path)")
    if reach_axis is not None:
        reach_axis.set(xlabel="steps (k)", ylabel="curriculum's reach (m of path before the goal)")
        reach_axis.axhline(results["path_length"], color="k", linestyle=":", label="whole path")
    for axis in (success_axis, return_axis, reach_axis):
        if axis is not None:
            axis.grid(alpha=0.3)
            axis.legend(fontsize=8)
    fig.suptitle(title, fontsize=9, wrap=True)
    return save_png(fig, path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layout", choices=("easy", "medium", "hard"), default="easy")
    parser.add_argument("--obs", choices=("state", "cyberrunner", "pixels"), default="state")
    parser.add_argument("--steps", type=int, default=1_000_000)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--curricula", nargs="+", choices=CURRICULA, default=list(CURRICULA))
    parser.add_argument("--episodes", type=int, default=100, help="scoring episodes per mode (default 100)")
    parser.add_argument("--jobs", type=int, default=3, help="runs trained at once, one thread each (default 3)")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "labyrinth-learning")
    parser.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results" / "labyrinth_learning.json")
    parser.add_argument("--figure", type=Path, default=ROOT / "docs" / "labyrinth" / "learning.png")
    parser.add_argument("--set", nargs="+", default=[], metavar="NAME=VALUE", help="other PPO settings")
    parser.add_argument(
        "--init",
        type=Path,
        default=None,
        help="start every run from this π^s (bimgame pretrain) or checkpoint; {seed} in it stands for the run's seed",
    )
    parser.add_argument("--expert-data", type=Path, default=None, help="the layout's expert dataset (for demo)")
    parser.add_argument(
        "--kl-teacher",
        default=None,
        help="the KL term's teacher: a policy trained on the layout's state (run or checkpoint; {seed} stands for "
        "the run's seed), instead of π^s; give kl_coef with --set",
    )
    args = parser.parse_args(argv)
    if set(DEMONSTRATION_STARTS) & set(args.curricula) and args.expert_data is None:
        parser.error(
            "--curricula demo and demo-uniform need --expert-data (the layout's expert dataset: bimgame generate)"
        )
    if args.expert_data is not None:
        args.expert_data = args.expert_data.absolute()
    context = {"task": f"LABYRINTH-{args.layout.upper()}", "obs": args.obs, "action_type": "continuous"}
    args.settings = _settings(args.set, parser, context)
    if args.init is not None:
        args.init = args.init.absolute()
    suffix = "".join(f"-{key.replace('_', '-')}{value}" for key, value in sorted(args.settings.items()))
    suffix += "-init" if args.init is not None else ""
    suffix += "-stateteacher" if args.kl_teacher is not None else ""
    jobs = {
        (curriculum, seed): args.out / f"{args.layout}-{args.obs}-{curriculum}{suffix}" / f"seed{seed}"
        for curriculum in args.curricula
        for seed in range(args.seeds)
    }
    done: dict[tuple[str, int], tuple[float, dict[str, Any]]] = {}
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=args.jobs, mp_context=context, initializer=exit_when_parent_dies) as pool:
        futures = {pool.submit(_job, run_dir, c, s, args): (c, s) for (c, s), run_dir in jobs.items()}
        for future in completed_with_progress(
            futures, lambda key: training_progress(jobs[key], args.steps), name=lambda key: f"{key[0]} seed {key[1]}"
        ):
            key = futures[future]
            done[key] = future.result()
            scores = done[key][1]
            print(
                f"{key[0]} seed {key[1]}: greedy {scores['greedy_success']:.0%}  "
                f"sampled {scores['sampled_success']:.0%}"
                f"  median time sampled {scores['sampled_median_seconds']}  ({done[key][0] / 60:.1f} min)",
                flush=True,
            )
    rng = np.random.default_rng(0)
    results: dict[str, Any] = {
        "layout": args.layout,
        "obs": args.obs,
        "action_type": "continuous",
        "steps": args.steps,
        "seeds": args.seeds,
        "episodes": args.episodes,
        "path_length": puzzle(f"LABYRINTH-{args.layout.upper()}").spec.path.length,
        "reference_seconds": {"cyberrunner": CYBERRUNNER_RECORD_S, "human_record": HUMAN_RECORD_S},
        "settings": args.settings,
        "init": _init_scores(args),
        "kl_teacher": args.kl_teacher,
        "curricula": {},
    }
    for curriculum in args.curricula:
        seeds = range(args.seeds)
        per_seed = [done[(curriculum, s)][1] for s in seeds]
        results["curricula"][curriculum] = {
            **_aggregate(per_seed, rng),
            "train_minutes": [done[(curriculum, s)][0] / 60 for s in seeds],
            "curves": [_curve(jobs[(curriculum, s)], args.steps) for s in seeds],
        }
    args.results.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(args.results, json.dumps(results, indent=2).encode())
    shown = "".join(f", {key} {value}" for key, value in sorted(args.settings.items()))
    shown += ", from --init (π^s or a DAgger iterate)" if args.init is not None else ""
    shown += ", KL to a state policy" if args.kl_teacher is not None else ""
    title = f"PPO on the {args.layout} labyrinth from {args.obs}{shown}, {args.steps:,} steps, {args.seeds} seeds"
    print(f"wrote {args.results} and {_plot(results, args.figure, title)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
