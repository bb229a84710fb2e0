"""The model-based learner on CyberRunner's labyrinth: how many environment steps it needs, and how
often what it learned completes the layout.

Per seed: :func:`bimgame.learn.model_based.learn_model_based` (random exploration, then rounds of
fitting the marble's law and playing episodes with the MPC planning through it), then the fitted law
scored on the labyrinth protocol's starts (:func:`bimgame.experiments.labyrinth_protocol.protocol_starts`,
the starts ``bimgame score`` plays; ``--score-episodes`` of them, the planner's generator seeded per
start) with the env's defaults, summarised as ``bimgame score`` summarises
(:func:`~bimgame.experiments.labyrinth_protocol.summarise_labyrinth`: success with a bootstrap interval
over episodes, completion times against CyberRunner's 14.48 s and the human record's 15.41 s on hard,
endings, progress). Across seeds: per-seed success and the mean with a 95% percentile-bootstrap
interval over seeds.

Seeds run on ``--workers`` spawned single-threaded processes; each finished seed is written into
``--results`` at once (atomically), so an interrupted run keeps what it measured.

Usage: ``python benchmarks/bench_labyrinth_model_based.py [--layout hard] [--seeds 0 1 2]
[--explore-steps 5000] [--iterations 4] [--episodes 4] [--score-episodes 20] [--workers 2]
[--results PATH] [--figure PATH] [--laws DIR] [--no-progress]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.experiments.labyrinth_protocol import protocol_starts, summarise_labyrinth
from bimgame.experiments.statistics import mean_interval
from bimgame.learn.actor import EvalResult
from bimgame.learn.model_based import ModelBasedSettings, learn_model_based
from bimgame.learn.model_based.agent import ModelBasedAgent, play_episode
from bimgame.sim.labyrinth_layouts import LAYOUT_NAMES
from bimgame.util.files import read_json, write_json
from bimgame.util.images import save_png, subplots
from bimgame.util.processes import results_as_they_finish

RESULTS = Path(__file__).parent / "results" / "labyrinth_model_based.json"
#: CyberRunner's 3000-step limit at 55 Hz (the protocol's).
TIME_LIMIT = 3000


def run_seed(job: dict[str, Any]) -> dict[str, Any]:
    """Learn with one seed, then score the law on the protocol's starts (a worker's job)."""
    began = time.time()
    settings = ModelBasedSettings(
        explore_steps=job["explore_steps"], iterations=job["iterations"], episodes_per_iteration=job["episodes"]
    )
    run = learn_model_based(job["layout"], settings, seed=job["seed"], progress=False)
    if job["laws"]:
        run.law.save(Path(job["laws"]) / f"{job['layout']}-seed{job['seed']}.json")
    learned = time.time()
    env = LabyrinthEnv(job["layout"])
    starts = protocol_starts(job["score_episodes"])
    result = EvalResult([], [], [])
    episodes = []
    try:
        for start in starts:
            agent = ModelBasedAgent.for_env(env, run.law, rng=np.random.default_rng([start, 1]))
            episode = play_episode(env, agent, seed=start, max_steps=TIME_LIMIT)
            episodes.append(episode)
            result.successes.append(episode["success"])
            result.lengths.append(episode["steps"] if episode["ending"] != "time" else TIME_LIMIT)
            result.returns.append(episode["return"])
            result.holes.append(episode["ending"] == "hole")
    finally:
        env.close()
    task = f"LABYRINTH-{job['layout'].upper()}"
    return {
        "seed": job["seed"],
        "env_steps": run.env_steps,
        "law": {
            "free_transitions": run.law.free_transitions,
            "r2": [round(float(v), 5) for v in run.law.r2],
            "acceleration_per_rad": round(run.law.acceleration_per_tilt(env.control_hz), 4),
        },
        "iterations": run.iterations,
        "score": summarise_labyrinth(result, task, starts, time_limit=TIME_LIMIT),
        "minutes_learning": round((learned - began) / 60, 2),
        "minutes_scoring": round((time.time() - learned) / 60, 2),
    }


def aggregate(seeds: list[dict[str, Any]]) -> dict[str, Any]:
    """Per-seed success, return and steps, with means and bootstrap intervals over the seeds."""
    ordered = sorted(seeds, key=lambda s: s["seed"])
    success = np.array([s["score"]["success_rate"] for s in ordered])
    returns = np.array([s["score"]["mean_return"] for s in ordered])
    rng = np.random.default_rng(0)
    return {
        "seeds": [s["seed"] for s in ordered],
        "success_per_seed": success.round(4).tolist(),
        "success_mean": round(float(success.mean()), 4),
        "success_interval": [round(v, 4) for v in mean_interval(success, rng=rng)],
        "return_per_seed": returns.round(4).tolist(),
        "return_mean": round(float(returns.mean()), 4),
        "return_interval": [round(v, 4) for v in mean_interval(returns, rng=rng)],
        "env_steps_per_seed": [s["env_steps"] for s in ordered],
        "median_time_s_per_seed": [(s["score"]["completion_time_s"] or {}).get("median") for s in ordered],
        "best_time_s_per_seed": [(s["score"]["completion_time_s"] or {}).get("best") for s in ordered],
    }


def plot(row: dict[str, Any], path: Path) -> None:
    """Per seed: each played episode's progress against the env steps before its round, and the
    scored success."""
    figure, (left, right) = subplots(1, 2, figsize=(10, 3.8), constrained_layout=True)
    for entry in sorted(row["per_seed"].values(), key=lambda s: s["seed"]):
        steps, progress = [], []
        for record in entry["iterations"]:
            for episode in record["episodes"]:
                steps.append(record["env_steps_before"])
                progress.append(episode["progress_fraction"])
        left.plot(steps, progress, "o", alpha=0.6, label=f"seed {entry['seed']}")
    left.set(xlabel="environment steps before the round", ylabel="fraction of the path reached", ylim=(0, 1.05))
    left.set_title("episodes played while learning")
    left.legend()
    summary = row["summary"]
    scores = [row["per_seed"][str(seed)]["score"] for seed in summary["seeds"]]
    rates = np.array(summary["success_per_seed"])
    low, high = (np.array([score["success_rate_ci"][i] for score in scores]) for i in (0, 1))
    right.bar([str(s) for s in summary["seeds"]], rates, color="tab:green", yerr=[rates - low, high - rates], capsize=6)
    right.set(xlabel="seed (bars: 95% bootstrap interval over its episodes)", ylabel="success on the protocol's starts")
    right.set_ylim(0, 1.05)
    right.set_title(f"scored: mean {summary['success_mean']:.0%} over {len(rates)} seeds")
    figure.suptitle(f"model-based learner, {row['layout']} labyrinth")
    save_png(figure, path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--layout", choices=LAYOUT_NAMES, default="hard")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--explore-steps", type=int, default=5000)
    parser.add_argument("--iterations", type=int, default=4)
    parser.add_argument("--episodes", type=int, default=4, help="episodes played with each fitted law")
    parser.add_argument("--score-episodes", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--results", type=Path, default=RESULTS)
    parser.add_argument("--figure", type=Path, default=None)
    parser.add_argument("--laws", type=Path, default=None, help="directory to save each seed's fitted law (JSON)")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args()
    for name in ("explore_steps", "iterations", "episodes", "score_episodes", "workers"):
        if getattr(args, name) < (0 if name == "iterations" else 1):
            parser.error(f"--{name.replace('_', '-')} must be a positive integer, got {getattr(args, name)}")
    ModelBasedSettings(
        explore_steps=args.explore_steps, iterations=args.iterations, episodes_per_iteration=args.episodes
    )
    key = f"{args.layout}_explore{args.explore_steps}_it{args.iterations}x{args.episodes}_score{args.score_episodes}"
    results = read_json(args.results) or {}
    row = results.get(key) or {"layout": args.layout, "per_seed": {}}
    jobs = [
        {
            "layout": args.layout,
            "seed": seed,
            "explore_steps": args.explore_steps,
            "iterations": args.iterations,
            "episodes": args.episodes,
            "score_episodes": args.score_episodes,
            "laws": str(args.laws) if args.laws else None,
        }
        for seed in args.seeds
    ]
    for finished in results_as_they_finish(run_seed, jobs, args.workers):
        row["per_seed"][str(finished["seed"])] = finished
        row["summary"] = aggregate(list(row["per_seed"].values()))
        results = read_json(args.results) or {}  # again: rows another run wrote meanwhile are kept
        results[key] = row
        write_json(args.results, results)
        score = finished["score"]
        if not args.no_progress:
            print(
                f"seed {finished['seed']}: {finished['env_steps']} env steps, success {score['success_rate']:.0%}, "
                f"completion times {score['completion_time_s']}, mean return {score['mean_return']:.3f}",
                flush=True,
            )
    summary = row["summary"]
    print(
        f"{key}: success per seed {summary['success_per_seed']}, mean {summary['success_mean']:.2%} "
        f"{summary['success_interval']}; env steps {summary['env_steps_per_seed']}"
    )
    if args.figure:
        plot(row, args.figure)


if __name__ == "__main__":
    main()
