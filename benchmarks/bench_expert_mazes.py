"""The MPC expert on random held-out mazes: success and trajectory lengths per task.

Runs the random-shooting expert (:func:`bimgame.expert.mpc.run_expert_episode`, the project's
default :class:`~bimgame.expert.mpc.MPCConfig` — the one its datasets are generated with — unless
flags change it) on test mazes ``0 … N-1`` (:func:`bimgame.sim.maze_sets.maze_number` with
``split="test"``), ``--episodes-per-maze`` episodes each, within each task's time limit
(:data:`~bimgame.sim.tasks.MAX_EPISODE_STEPS`). Episode ``e`` of maze ``i`` on a task starts from
``reset(seed=s)`` with ``s`` derived from ``(--seed, task, i, e)`` alone, and the expert's own
generator is seeded with ``s`` too, so results depend neither on the number of workers nor on the
order in which episodes finish. ``--sources merl`` runs as many episodes on MERL's maze.

``--derive-stg`` runs one FULL episode per maze (seeded as FULL's) and reads off it every task the
expert plans the same for: all of STG1 … STG4 with the radial reward (its plans do not depend on the
task), STG4 with the geodesic one (the same goal, the centre). An STGk episode *is* the FULL episode
of the same seed cut where the marble first passes the k-th wall (same actions and physics states;
tests/expert/test_expert_mazes.py checks it), so this is exact and about 5× cheaper — but the tasks'
numbers then come from the same episodes (nested), not independent ones.

Reported per task: success rate with a 95% percentile-bootstrap interval over episodes
(:func:`bimgame.experiments.statistics.mean_interval`; it collapses to a point at 0% or 100%, so a
Wilson score interval is given too), median, 90th percentile and longest length of the successful
episodes, and the failed mazes (index, channel reached, gates of the maze in degrees).

Episodes run on ``--workers`` spawned processes (default 2), each single-threaded (MuJoCo rollouts
with ``nthread=1``; BLAS/OpenMP/torch threads 1).

Usage: ``python benchmarks/bench_expert_mazes.py [--tasks STG1 … FULL] [--mazes 100] [--maze-indices I …]
[--sources test merl] [--derive-stg] [-K 10 -H 20 --sampling hold --planning-reward radial --hold-min 3
--hold-max 5] [--max-steps N] [--workers 2] [--seed 0]``; merges its rows, keyed by the expert's setting
and the mazes, into ``benchmarks/results/expert_mazes.json`` (after every completed task). On a 2-core
machine shared with another job, ``--mazes 100 --derive-stg`` took 17 min (radial) and 23 min
(geodesic); all five tasks run independently take about five times the radial one.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.expert.mpc import MPCConfig, run_expert_episode
from bimgame.sim.maze import MazeSpec
from bimgame.sim.maze_sets import maze_number
from bimgame.sim.tasks import Task, parse_task
from bimgame.util.processes import results_as_they_finish

RESULTS = Path(__file__).parent / "results" / "expert_mazes.json"
TASKS = ("STG1", "STG2", "STG3", "STG4", "FULL")
#: Maze sources: held-out random test mazes, or MERL's maze (``maze=None``).
SOURCES = ("test", "merl")


@dataclasses.dataclass(frozen=True)
class Job:
    task: str
    source: str
    maze_index: int
    episode: int
    seed: int
    config: MPCConfig
    max_steps: int | None


def episode_seed(run_seed: int, task: str, maze_index: int, episode: int) -> int:
    """The reset (and expert) seed of one episode: a function of (run seed, task, maze, episode)."""
    task_number = list(Task).index(parse_task(task))
    words = [int(run_seed), task_number, int(maze_index), int(episode)]
    return int(np.random.SeedSequence(words).generate_state(1, dtype=np.uint32)[0])


def maze_of(source: str, index: int) -> MazeSpec | None:
    return maze_number(index, "test") if source == "test" else None


def gates_deg(spec: MazeSpec | None) -> list[list[tuple[float, float]]]:
    """Per wall (innermost first), its gates as (centre angle, width) in degrees."""
    spec = spec if spec is not None else MazeSpec.merl()
    return [
        [(round(math.degrees(g.angle), 1), round(math.degrees(g.width), 1)) for g in wall.gates] for wall in spec.walls
    ]


def run_job(job: Job) -> dict[str, Any]:
    """One expert episode; what the summary needs, plus where the marble got to."""
    start = time.perf_counter()
    maze = maze_of(job.source, job.maze_index)
    episode = run_expert_episode(job.task, job.seed, job.config, maze=maze, max_steps=job.max_steps)
    channels = episode["channels"][:, 0]
    # First step at which the marble was in channel c or deeper (None: never), c = 0 … outermost.
    within = {int(c): (int(np.argmax(channels <= c)) if (channels <= c).any() else None) for c in range(5)}
    changes = np.flatnonzero(np.diff(channels)) + 1
    transitions = [(0, int(channels[0]))] + [(int(t), int(channels[t])) for t in changes]
    x, y = (float(v) for v in episode["observations"][-1][:2])
    return {
        "task": job.task,
        "source": job.source,
        "maze": job.maze_index,
        "episode": job.episode,
        "seed": job.seed,
        "success": bool(episode["success"]),
        "length": len(episode["actions"]),
        "return": float(episode["rewards"].sum()),
        "final_channel": int(channels[-1]),
        "deepest_channel": int(channels.min()),
        "first_step_within": within,
        "transitions": transitions,
        "final_xy_mm": [round(1e3 * x, 2), round(1e3 * y, 2)],
        "final_angle_deg": round(math.degrees(math.atan2(y, x)), 1),
        "seconds": time.perf_counter() - start,
    }


def plan_group(task: str, config: MPCConfig) -> str:
    """The task whose episodes contain ``task``'s (same seed): FULL for every task with the radial
    reward (its plans do not depend on the task) and for STG4 (the same goal, the centre) with the
    geodesic one; the task itself otherwise."""
    same_goal = parse_task(task).goal_channel(MazeSpec.merl()) == 0
    return "FULL" if config.reward == "radial" or same_goal else parse_task(task).value


def derived(record: dict[str, Any], task: str, limit: int) -> dict[str, Any]:
    """The STGk (or FULL) episode contained in a FULL episode of the same seed: with the radial
    planning reward the expert's plans do not depend on the task, so an STGk episode is exactly the
    FULL episode cut where the marble first passes the k-th wall (the same actions and physics
    states: tests/expert/test_expert_mazes.py checks it)."""
    goal = parse_task(task).goal_channel(MazeSpec.merl())
    step = record["first_step_within"][goal]
    success = step is not None and step <= limit
    length = step if success else min(limit, record["length"])
    channels = [c for t, c in record["transitions"] if t <= length]
    seconds = record["seconds"] * length / max(record["length"], 1)  # its share of the FULL episode's time
    return record | {
        "task": task,
        "steps_to_goal": step,
        "success": success,
        "length": length,
        "final_channel": channels[-1],
        "deepest_channel": min(channels),
        "final_angle_deg": record["final_angle_deg"] if length == record["length"] else None,
        "seconds": seconds,
    }


def wilson_interval(successes: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (not degenerate at 0% or 100%)."""
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def summarise(episodes: list[dict[str, Any]], seed: int) -> dict[str, Any]:
    from bimgame.experiments.statistics import mean_interval  # not needed by the workers

    episodes = sorted(episodes, key=lambda e: (e["maze"], e["episode"]))
    success = np.array([e["success"] for e in episodes], dtype=np.float64)
    solved = np.array([e["length"] for e in episodes if e["success"]])
    low, high = mean_interval(success, rng=np.random.default_rng(seed))
    wilson = wilson_interval(int(success.sum()), len(success))
    seconds = sum(e["seconds"] for e in episodes)
    steps = sum(e["length"] for e in episodes)
    failed = [e for e in episodes if not e["success"]]
    return {
        "episodes": len(episodes),
        "successes": int(success.sum()),
        "success_rate": float(success.mean()),
        "bootstrap_95": [low, high],
        "wilson_95": list(wilson),
        "median_length_solved": float(np.median(solved)) if len(solved) else None,
        "p90_length_solved": float(np.percentile(solved, 90)) if len(solved) else None,
        "max_length_solved": int(solved.max()) if len(solved) else None,
        "failed_mazes": sorted({e["maze"] for e in failed}),
        "failures": [
            {k: e[k] for k in ("maze", "episode", "seed", "final_channel", "deepest_channel", "final_angle_deg")}
            | {"gates_deg": gates_deg(maze_of(e["source"], e["maze"]))}
            for e in failed
        ],
        "cpu_seconds": seconds,
        "ms_per_decision": 1e3 * seconds / max(steps, 1),
        "mazes": [e["maze"] for e in episodes],
        "lengths": [e["length"] for e in episodes],
        # Steps until the marble first reached the task's goal in the episode as run (derived: in the
        # FULL episode, up to its limit), None if never: success under other time limits.
        "steps_to_goal": [e["steps_to_goal"] for e in episodes],
    }


def setting_name(config: MPCConfig, max_steps: int | None) -> str:
    default = " (default)" if dataclasses.replace(config, nthread=1) == MPCConfig(nthread=1) else ""
    name = (
        f"K={config.n_samples} H={config.horizon} {config.sampling}"
        f"{f' {config.hold_min}-{config.hold_max}' if config.sampling == 'hold' else ''} {config.reward}{default}"
    )
    return name + (f", max_steps {max_steps}" if max_steps is not None else "")


def parse_args() -> argparse.Namespace:
    from bimgame.cli.argtypes import positive_int
    from bimgame.cli.expert import add_mpc_arguments

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(TASKS), type=lambda t: parse_task(t).value)
    parser.add_argument("--mazes", type=positive_int, default=100, help="test mazes 0..N-1 (default 100)")
    parser.add_argument(
        "--maze-indices", type=int, nargs="+", default=None, help="only these test mazes (instead of 0..N-1)"
    )
    parser.add_argument("--episodes-per-maze", type=positive_int, default=1)
    parser.add_argument("--workers", type=positive_int, default=2, help="processes, one thread each (default 2)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--sources",
        nargs="+",
        choices=SOURCES,
        default=["test"],
        help="test: the random test mazes; merl: as many episodes on MERL's maze (default: test)",
    )
    parser.add_argument("--max-steps", type=positive_int, default=None, help="default: each task's time limit")
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument(
        "--derive-stg",
        action="store_true",
        help="run FULL episodes (seeded as FULL's) and read off them the tasks the expert plans the same for: "
        "STG1-STG4 with the radial reward (its plans do not depend on the task), STG4 with the geodesic one "
        "(exact: the same actions and states until the goal; 1 episode per maze instead of one per task)",
    )
    add_mpc_arguments(parser)
    group = parser.add_argument_group("held actions")
    group.add_argument("--hold-min", type=positive_int, default=MPCConfig().hold_min)
    group.add_argument("--hold-max", type=positive_int, default=MPCConfig().hold_max)
    return parser.parse_args()


def print_table(title: str, rows: dict[str, dict[str, dict[str, Any]]]) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=title)
    columns = ("task", "mazes", "episodes", "success", "bootstrap 95%", "Wilson 95%", "median", "p90", "max")
    for column in columns + ("ms/dec", "failed mazes"):
        table.add_column(column, justify="left" if column in ("task", "mazes", "failed mazes") else "right")
    for source, tasks in rows.items():
        for task, s in tasks.items():
            table.add_row(
                task,
                source,
                str(s["episodes"]),
                f"{s['success_rate']:.0%}",
                f"[{s['bootstrap_95'][0]:.0%}, {s['bootstrap_95'][1]:.0%}]",
                f"[{s['wilson_95'][0]:.0%}, {s['wilson_95'][1]:.0%}]",
                *("-" if s[k] is None else f"{s[k]:.0f}" for k in ("median_length_solved", "p90_length_solved")),
                "-" if s["max_length_solved"] is None else str(s["max_length_solved"]),
                f"{s['ms_per_decision']:.1f}",
                " ".join(map(str, s["failed_mazes"])) or "-",
            )
    Console(width=max(160, Console().width)).print(table)


def main() -> None:
    from bimgame.cli.expert import mpc_config_from
    from bimgame.util.files import atomic_write_bytes
    from bimgame.util.progress import ProgressBar

    args = parse_args()
    config = dataclasses.replace(
        mpc_config_from(args), hold_min=args.hold_min, hold_max=args.hold_max, nthread=1
    )  # validated by MPCConfig
    indices = args.maze_indices if args.maze_indices is not None else list(range(args.mazes))
    for index in indices:
        maze_number(index, "test")  # fail on a bad index before starting workers
    sources = list(dict.fromkeys(args.sources))
    limits = {task: args.max_steps or parse_task(task).time_limit for task in args.tasks}
    # Which episodes to run: with --derive-stg, one per group of tasks the expert plans the same for.
    groups: dict[str, list[str]] = {}
    for task in args.tasks:
        groups.setdefault(plan_group(task, config) if args.derive_stg else task, []).append(task)
    jobs = []
    for source in sources:
        for run_task, served in groups.items():
            for position, index in enumerate(indices):
                for episode in range(args.episodes_per_maze):
                    # MERL's maze: episode k (k = maze position) gets the seed test maze k's would.
                    maze_index = index if source == "test" else position
                    seed = episode_seed(args.seed, run_task, maze_index, episode)
                    steps = max(limits[t] for t in served)
                    jobs.append(Job(run_task, source, maze_index, episode, seed, config, steps))

    derivations = [f"{' '.join(ts)} from {t}" for t, ts in groups.items() if ts != [t]]
    name = setting_name(config, args.max_steps) + (f", derived: {'; '.join(derivations)}" if derivations else "")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    result = json.loads(args.out.read_text()) if args.out.exists() else {}
    done: dict[tuple[str, str], list[dict[str, Any]]] = {(s, t): [] for s in sources for t in args.tasks}
    per_task = len(indices) * args.episodes_per_maze
    rows: dict[str, dict[str, dict[str, Any]]] = {}
    start = time.perf_counter()
    with ProgressBar(
        f"expert, {len(indices)} mazes", len(jobs), enabled=not args.no_progress, eta=True, info="success -"
    ) as bar:
        for record in results_as_they_finish(run_job, jobs, args.workers):
            tasks = groups[record["task"]]
            for task in tasks:
                done[(record["source"], task)].append(derived(record, task, limits[task]))
            bar.update(
                advance=1,
                info=" ".join(
                    f"{t}{'*' if s == 'merl' else ''} {sum(e['success'] for e in es)}/{len(es)}"
                    for (s, t), es in done.items()
                    if es
                ),
            )
            complete = [(record["source"], t) for t in tasks if len(done[(record["source"], t)]) == per_task]
            for source, task in complete:  # save every task as soon as it is complete
                rows.setdefault(source, {})[task] = summarise(done[(source, task)], args.seed) | {
                    "episodes_per_maze": args.episodes_per_maze,
                    "seed": args.seed,
                    "time_limit": limits[task],
                }
            if complete:
                entry = result.setdefault("settings", {}).setdefault(name, {})
                entry |= {"config": dataclasses.asdict(config), "max_steps": args.max_steps}
                entry["derive_stg"] = args.derive_stg
                for source, summaries in rows.items():
                    label = "merl" if source == "merl" else f"test mazes {_describe(indices)}"
                    entry.setdefault(label, {}).update(summaries)
                    entry.setdefault("runs", {})[label] = {
                        "tasks": list(summaries),
                        "wall_seconds": time.perf_counter() - start,
                        "workers": args.workers,
                        "time": time.strftime("%Y-%m-%dT%H:%M:%S"),
                        "command": " ".join(["python", "benchmarks/bench_expert_mazes.py", *sys.argv[1:]]),
                    }
                atomic_write_bytes(args.out, json.dumps(result, indent=1).encode())
    wall = time.perf_counter() - start
    print_table(f"MPC expert: {name}, seed {args.seed}, {wall:.0f} s wall", rows)
    print(f"wrote {args.out}")


def _describe(indices: list[int]) -> str:
    if indices == list(range(len(indices))):
        return f"0..{len(indices) - 1}"
    return " ".join(map(str, indices))


if __name__ == "__main__":
    main()
