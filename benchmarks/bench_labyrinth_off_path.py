"""What the labyrinth's off-path rule costs a trained network: the scoring protocol's episodes
(:func:`~bimgame.experiments.labyrinth_protocol.score_labyrinth`'s starts and draws, the 54.5 s limit,
one torch thread) played three times: with the env's rule (an episode ends when the marble leaves the
path by the 25 mm tolerance: the default and the protocol's), with CyberRunner's own test
(``off_path_rule="cyberrunner"``: no path point in the marble's free box,
:mod:`bimgame.sim.labyrinth_box_sight`), and with episodes that leave the path going on
(``end_off_path=False``; holes still end them, progress stays frozen while off the path).

Why: the env's path tolerance (25 mm, :mod:`bimgame.sim.labyrinth`) is a chosen value, stricter on
open floor than CyberRunner's test; an episode a later pass solves and the first does not is one the
rule ended, not the marble. The first pass is the protocol's score (the same numbers as ``bimgame
score RUN --task … --sampled``); the others are what-ifs, never scores.

Writes ``--out`` (JSON: success, holes and time-outs per pass, the per-episode successes) and prints
the passes. Usage: python benchmarks/bench_labyrinth_off_path.py RUN [--greedy] [--episodes 100]
[--out benchmarks/results/labyrinth_off_path.json]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from bimgame.envs.puzzles import puzzle
from bimgame.experiments.labyrinth_protocol import (
    LABYRINTH_PROTOCOL_SEED,
    SCORE_THREADS,
    protocol_starts,
    summarise_labyrinth,
)
from bimgame.learn.actor import evaluate_network
from bimgame.learn.common import load_run_network
from bimgame.learn.maze_runs import network_env_options
from bimgame.learn.runs import torch_threads
from bimgame.util.files import write_json

#: The passes: (name, env options).
PASSES: tuple[tuple[str, dict[str, Any]], ...] = (
    ("tolerance", {}),
    ("cyberrunner", {"off_path_rule": "cyberrunner"}),
    ("never", {"end_off_path": False}),
)


def _pass(net: Any, run: Any, *, rule: str, options: dict[str, Any], episodes: int, greedy: bool) -> dict[str, Any]:
    """The protocol's episodes of ``run``'s network with the env ``options`` of off-path ``rule``,
    counted as the protocol counts them (:func:`summarise_labyrinth`)."""
    started = time.perf_counter()
    limit = puzzle(run.task).time_limit
    result = evaluate_network(
        net,
        task=run.task,
        obs_mode=run.network.obs,
        episodes=episodes,
        seed=LABYRINTH_PROTOCOL_SEED,
        greedy=greedy,
        max_episode_steps=limit,
        mazes={**(network_env_options(run.network) or {}), **options},
    )
    summary = summarise_labyrinth(result, run.task, protocol_starts(episodes), time_limit=limit)
    return {
        "off_path_rule": rule,
        "success_rate": summary["success_rate"],
        "holes": summary["ended_by"]["hole"],
        "time_limit": summary["ended_by"]["time"],
        "successes": summary["successes"],
        "seconds": time.perf_counter() - started,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", help="a bimgame run directory or checkpoint trained on a labyrinth task")
    parser.add_argument("--greedy", action="store_true", help="greedy actions (default: sampled)")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/labyrinth_off_path.json"))
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error(f"--episodes must be at least 1, got {args.episodes}")
    net, run, step = load_run_network(args.run)
    if puzzle(run.task).is_maze:
        parser.error(f"{args.run} is a run on {run.task}, the circular maze; this measures the labyrinth's rule")
    with torch_threads(SCORE_THREADS):  # as the protocol scores (its first pass is the protocol's score)
        passes = [_pass(net.eval(), run, rule=rule, options=options, episodes=args.episodes, greedy=args.greedy)
                  for rule, options in PASSES]  # fmt: skip
    ruled = passes[0]["successes"]
    gained = {p["off_path_rule"]: sum(o and not r for r, o in zip(ruled, p["successes"], strict=True)) for p in passes}
    lost = {p["off_path_rule"]: sum(r and not o for r, o in zip(ruled, p["successes"], strict=True)) for p in passes}
    summary = {
        "run": str(args.run),
        "task": run.task,
        "step": step,
        "mode": "greedy" if args.greedy else "sampled",
        "episodes": args.episodes,
        "protocol_seed": LABYRINTH_PROTOCOL_SEED,
        "passes": passes,
        "solved_not_by_the_tolerance_rule": gained,
        "solved_only_by_the_tolerance_rule": lost,
    }
    for result in passes:
        print(
            f"off the path ends it: {result['off_path_rule']:<11} success {result['success_rate']:.0%}, "
            f"holes {result['holes']}, time limit {result['time_limit']}, solved that the tolerance rule failed "
            f"{gained[result['off_path_rule']]}, failed that it solved {lost[result['off_path_rule']]} "
            f"({result['seconds']:.0f} s)"
        )
    print(f"wrote {write_json(args.out, summary)}")


if __name__ == "__main__":
    main()
