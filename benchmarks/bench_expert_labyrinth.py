"""The MPC expert on CyberRunner's labyrinth: success and completion time per layout.

Runs :class:`~bimgame.expert.labyrinth_mpc.LabyrinthMPC` (the default
:class:`~bimgame.expert.labyrinth_mpc.LabyrinthMPCConfig` unless flags change it) on
``BiMGame/Labyrinth-{Easy,Medium,Hard}-v0``'s env (55 Hz, continuous tilt-rate actions capped at
30°/s, CyberRunner's 3000-step limit), ``--episodes`` episodes per layout. Episode ``e`` of a layout
starts from ``reset(seed=s)`` with ``s`` derived from ``(--seed, layout, e)`` alone, and the expert's
generator is seeded with ``s`` too, so results depend neither on the number of workers nor on the
order in which episodes finish.

Reported per layout: success rate with a 95% percentile-bootstrap interval over episodes
(:func:`bimgame.experiments.statistics.mean_interval`; it collapses to a point at 0% or 100%, so a
Wilson score interval is given too), median and quartiles of the completion time (s) of the
successful episodes against CyberRunner's record on the hard layout (14.48 s) and the human record
(15.41 s), how the others failed (hole, off the path, time), mean progress, the planner's cost
(ms per decision) and the machine's load average while it ran.

Episodes run on ``--workers`` spawned processes (default 2), each single-threaded (MuJoCo rollouts with
``nthread=1``). Rows are keyed by layout and expert setting and merged into
``benchmarks/results/expert_labyrinth.json`` after every finished episode, so an interrupted run keeps
what it measured (its row says ``complete: false``).

Usage: ``python benchmarks/bench_expert_labyrinth.py [--layouts easy medium hard] [--episodes 20]
[-K 16 -P 1 -H 30 --sampling hold|uniform|mppi --noise-std 0.5 --temperature 0.005 --hold-min 5 --hold-max 15
--rate-levels 5 --hole-margin 0 --path-weight 5]
[--action-type continuous] [--action-noise 0] [--workers 2] [--seed 0] [--no-progress]``.

``--action-noise σ`` adds Gaussian noise of standard deviation σ (in tilt-rate units, actions in
[-1, 1]) to every action the expert takes, clipped to the action space, drawn from a generator seeded
by the episode: the expert as the mean of a Gaussian policy sampled with σ, which measures how
precisely a layout must be played (what a learner sampling its actions with σ can complete).
"""

from __future__ import annotations

import argparse
import dataclasses
import fcntl
import json
import math
import os
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.expert.labyrinth_mpc import (
    LABYRINTH_SAMPLINGS,
    LabyrinthMPC,
    LabyrinthMPCConfig,
    run_labyrinth_expert_episode,
)
from bimgame.sim.labyrinth_layouts import LAYOUT_NAMES
from bimgame.util.processes import results_as_they_finish

RESULTS = Path(__file__).parent / "results" / "expert_labyrinth.json"
#: CyberRunner's time on the hard layout and the human record it beat (s; Bi & D'Andrea 2023).
CYBERRUNNER_RECORD_S, HUMAN_RECORD_S = 14.48, 15.41


@dataclasses.dataclass(frozen=True)
class Job:
    layout: str
    episode: int
    seed: int
    config: LabyrinthMPCConfig
    action_type: str
    action_noise: float = 0.0


class NoisyActions(gym.ActionWrapper):
    """Every action plus Gaussian noise of standard deviation ``std``, clipped to [-1, 1] (continuous
    tilt-rate actions), from ``rng``."""

    def __init__(self, env: gym.Env, std: float, rng: np.random.Generator) -> None:
        super().__init__(env)
        self.std, self.rng = std, rng

    def action(self, action: Any) -> np.ndarray:
        noisy = np.asarray(action, dtype=np.float64) + self.rng.normal(0.0, self.std, 2)
        return np.clip(noisy, -1.0, 1.0).astype(np.float32)


def episode_seed(run_seed: int, layout: str, episode: int) -> int:
    """The reset (and expert) seed of one episode: a function of (run seed, layout, episode)."""
    words = [int(run_seed), LAYOUT_NAMES.index(layout), int(episode)]
    return int(np.random.SeedSequence(words).generate_state(1, dtype=np.uint32)[0])


def run_job(job: Job) -> dict[str, Any]:
    """One expert episode and its wall-clock cost."""
    start = time.perf_counter()
    inner = LabyrinthEnv(job.layout, action_type=job.action_type)
    expert = LabyrinthMPC.for_env(inner, job.config, rng=np.random.default_rng(job.seed))
    env = NoisyActions(inner, job.action_noise, np.random.default_rng([job.seed, 2])) if job.action_noise else inner
    result = run_labyrinth_expert_episode(env, expert, seed=job.seed, max_steps=3000)
    expert.close()
    env.close()
    seconds = time.perf_counter() - start
    return result | {
        "layout": job.layout,
        "episode": job.episode,
        "seed": job.seed,
        "wall_s": round(seconds, 1),
        "ms_per_decision": round(1e3 * seconds / max(result["steps"], 1), 1),
    }


def wilson_interval(successes: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (not degenerate at 0% or 100%)."""
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def summarise(records: list[dict[str, Any]], n_planned: int) -> dict[str, Any]:
    """Success with intervals, completion-time quartiles and failures of one layout's episodes."""
    from bimgame.experiments.statistics import mean_interval

    records = sorted(records, key=lambda r: r["episode"])
    success = np.array([r["success"] for r in records], dtype=np.float64)
    times = np.array([r["time_s"] for r in records if r["success"]])
    low, high = mean_interval(success, rng=np.random.default_rng(0))
    quartiles = np.percentile(times, [25, 50, 75]).round(2).tolist() if len(times) else [None] * 3
    failures = [r["failure"] for r in records if not r["success"]]
    median = quartiles[1]
    detail = ("episode", "seed", "success", "failure", "steps", "time_s", "progress_fraction", "wall_s")
    return {
        "episodes": len(records),
        "complete": len(records) == n_planned,
        "success_rate": float(success.mean()),
        "success_bootstrap_95": [low, high],
        "success_wilson_95": list(wilson_interval(int(success.sum()), len(records))),
        "completion_time_s": {"q25": quartiles[0], "median": quartiles[1], "q75": quartiles[2]},
        "median_over_cyberrunner_record": None if median is None else round(median / CYBERRUNNER_RECORD_S, 3),
        "median_over_human_record": None if median is None else round(median / HUMAN_RECORD_S, 3),
        "failures": {kind: failures.count(kind) for kind in ("hole", "off_path", "time")},
        "mean_progress_fraction": round(float(np.mean([r["progress_fraction"] for r in records])), 4),
        "ms_per_decision_median": float(np.median([r["ms_per_decision"] for r in records])),
        "episodes_detail": [{k: r[k] for k in detail} for r in records],
    }


def row_key(layout: str, config: LabyrinthMPCConfig, action_type: str, action_noise: float = 0.0) -> str:
    c = config
    return (
        f"{layout} K={c.n_samples} H={c.horizon} {c.sampling} hold={c.hold_min}-{c.hold_max} "
        f"levels={c.rate_levels} keep_best={c.keep_best} margin={c.hole_margin:g} path_weight={c.path_weight:g} "
        f"{action_type}{f' P={c.n_plans}' if c.n_plans != 1 else ''}"
        f"{f' std={c.noise_std:g} λ={c.temperature:g}' if c.sampling == 'mppi' else ''}"
        f"{f' action_noise={action_noise:g}' if action_noise else ''}"
    )


def save(path: Path, key: str, row: dict[str, Any]) -> None:
    """Merge ``row`` under ``key`` into the results file (others' rows kept), under a lock file so
    that several runs (a sweep's settings side by side) can share one results file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+") as lock:  # the results file itself is the lock (created empty if new)
        fcntl.flock(lock, fcntl.LOCK_EX)
        text = path.read_text()
        data = json.loads(text) if text.strip() else {}
        data.setdefault("references", {"cyberrunner_hard_s": CYBERRUNNER_RECORD_S, "human_hard_s": HUMAN_RECORD_S})
        data.setdefault("rows", {})[key] = row
        path.write_text(json.dumps(data, indent=1) + "\n")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    defaults = LabyrinthMPCConfig()
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--layouts", nargs="+", choices=LAYOUT_NAMES, default=list(LAYOUT_NAMES))
    parser.add_argument("--episodes", type=int, default=20, help="episodes per layout (default 20)")
    parser.add_argument("-K", "--n-samples", type=int, default=defaults.n_samples)
    parser.add_argument("-H", "--horizon", type=int, default=defaults.horizon)
    parser.add_argument(
        "-P", "--n-plans", type=int, default=defaults.n_plans, help="searches whose first actions are averaged"
    )
    parser.add_argument("--sampling", choices=LABYRINTH_SAMPLINGS, default=defaults.sampling)
    parser.add_argument("--noise-std", type=float, default=defaults.noise_std, help="mppi: the plan's perturbations")
    parser.add_argument("--temperature", type=float, default=defaults.temperature, help="mppi: λ of the weights")
    parser.add_argument("--hold-min", type=int, default=defaults.hold_min)
    parser.add_argument("--hold-max", type=int, default=defaults.hold_max)
    parser.add_argument("--rate-levels", type=int, default=defaults.rate_levels)
    parser.add_argument("--hole-margin", type=float, default=defaults.hole_margin)
    parser.add_argument("--path-weight", type=float, default=defaults.path_weight)
    parser.add_argument("--no-keep-best", action="store_true", help="redraw all K sequences every decision")
    parser.add_argument("--action-type", choices=("continuous", "discrete"), default="continuous")
    parser.add_argument(
        "--action-noise", type=float, default=0.0, help="σ of Gaussian noise added to every action (module notes)"
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--results", type=Path, default=RESULTS)
    parser.add_argument("--no-progress", action="store_true")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if not (math.isfinite(args.action_noise) and args.action_noise >= 0):
        raise SystemExit(f"--action-noise must be a finite number >= 0, got {args.action_noise}")
    if args.action_noise and args.action_type != "continuous":
        raise SystemExit("--action-noise perturbs continuous tilt rates; use --action-type continuous")
    config = LabyrinthMPCConfig(
        n_samples=args.n_samples,
        n_plans=args.n_plans,
        horizon=args.horizon,
        sampling=args.sampling,
        hold_min=args.hold_min,
        hold_max=args.hold_max,
        rate_levels=args.rate_levels,
        hole_margin=args.hole_margin,
        path_weight=args.path_weight,
        keep_best=not args.no_keep_best,
        noise_std=args.noise_std,
        temperature=args.temperature,
    )
    from bimgame.util.progress import ProgressBar

    # Interleaved by episode so that every layout has some episodes early (an interrupted run still reports all).
    jobs = [
        Job(layout, e, episode_seed(args.seed, layout, e), config, args.action_type, args.action_noise)
        for e in range(args.episodes)
        for layout in args.layouts
    ]
    records: dict[str, list[dict[str, Any]]] = {layout: [] for layout in args.layouts}
    loads = [os.getloadavg()[0]]
    started = time.time()
    with ProgressBar(
        f"labyrinth expert, {', '.join(args.layouts)}", len(jobs), enabled=not args.no_progress, eta=True
    ) as bar:
        for record in results_as_they_finish(run_job, jobs, args.workers):
            layout = record["layout"]
            records[layout].append(record)
            loads.append(os.getloadavg()[0])
            row = summarise(records[layout], args.episodes) | {
                "layout": layout,
                "action_type": args.action_type,
                "action_noise": args.action_noise,
                "config": dataclasses.asdict(config),
                "seed": args.seed,
                "workers": args.workers,
                "load_average_1min": {"min": min(loads), "max": max(loads), "mean": round(float(np.mean(loads)), 2)},
                "cpu_count": os.cpu_count(),
                "wall_minutes": round((time.time() - started) / 60, 1),
            }
            save(args.results, row_key(layout, config, args.action_type, args.action_noise), row)
            done = {k: f"{sum(r['success'] for r in v)}/{len(v)}" for k, v in records.items() if v}
            bar.update(advance=1, info=" ".join(f"{k} {v}" for k, v in done.items()))
    for layout in args.layouts:
        row = summarise(records[layout], args.episodes)
        print(
            f"{layout:6s} success {row['success_rate']:.0%} (bootstrap 95% {row['success_bootstrap_95']}, "
            f"Wilson {np.round(row['success_wilson_95'], 2).tolist()}) of {row['episodes']}; completion time "
            f"median {row['completion_time_s']['median']} s (q25 {row['completion_time_s']['q25']}, "
            f"q75 {row['completion_time_s']['q75']}) vs {CYBERRUNNER_RECORD_S} s CyberRunner / {HUMAN_RECORD_S} s "
            f"human; failures {row['failures']}; {row['ms_per_decision_median']} ms/decision"
        )


if __name__ == "__main__":
    main()
