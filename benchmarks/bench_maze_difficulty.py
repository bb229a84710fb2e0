"""Which held-out mazes a policy fails: success broken down by what makes a random maze hard.

Scores a run's network (greedy and sampled, one episode per maze, the generalization benchmark's
starts) on the first ``--mazes`` held-out test mazes and groups the episodes by features of the wall
an STG1 episode must pass (the outermost): its number of gates, and the mean angle (over start
angles uniform around the channel) from a start to the nearest gate — how far the marble must travel
round the channel. Groups are terciles of each feature (gate counts as they are). Bootstrap 95%
intervals per group. For the failed episodes it also reports how close the marble came to the goal
(``info["goal_distance"]``, metres; its medians at the start, nearest and end): near the gate and
past it, or never near. Writes ``--results`` (JSON).

Usage: python benchmarks/bench_maze_difficulty.py RUN [--mazes 200] [--results FILE]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bimgame.envs.puzzles import puzzle
from bimgame.experiments.statistics import mean_interval
from bimgame.learn.actor import RecurrentActor, tilt_input
from bimgame.learn.common import load_run_network
from bimgame.learn.runs import torch_threads
from bimgame.sim.maze import MazeSpec
from bimgame.sim.maze_sets import MazeSet
from bimgame.util.files import atomic_write_bytes

#: The generalization benchmark's evaluation seed (bench_generalization.SCORE_SEED): the same starts.
SCORE_SEED = 12345


def outer_wall_features(spec: MazeSpec) -> dict[str, float]:
    """The outermost wall's gate count and the mean angle (degrees) from a start angle, uniform round
    the channel, to its nearest gate."""
    outer = max(spec.walls, key=lambda wall: wall.mid_radius)
    angles = np.array([gate.angle for gate in outer.gates])
    starts = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    offsets = np.abs((starts[:, None] - angles[None, :] + np.pi) % (2 * np.pi) - np.pi)
    return {"gates": float(len(outer.gates)), "mean_angle_to_gate": float(np.degrees(offsets.min(axis=1).mean()))}


def _episodes(net: Any, run: Any, mazes: int, greedy: bool) -> dict[str, np.ndarray]:
    """One episode on each of the first ``mazes`` held-out mazes (batched, starts and sampling from
    :data:`SCORE_SEED`, as :func:`~bimgame.learn.actor.evaluate_network` runs them): per episode its
    success and its goal distance at the start, nearest and end."""
    env = puzzle(run.task).vector_env(
        mazes,
        obs_mode=run.network.obs,
        action_type=net.config.action_type,
        max_episode_steps=run.time_limit,
        nthread=1,
        autoreset_mode="same_step",
        num_mazes=mazes,
        maze_split="test",
    )
    actor = RecurrentActor(net, mazes, generator=torch.Generator().manual_seed(SCORE_SEED), greedy=greedy)
    obs, info = env.reset(seed=SCORE_SEED, options={"maze": list(range(mazes))})
    start = info["goal_distance"][:, 0].copy()
    nearest, end = start.copy(), np.zeros(mazes)
    success, finished = np.zeros(mazes, dtype=bool), np.zeros(mazes, dtype=bool)
    try:
        while not finished.all():
            actions, _, _ = actor.act(obs, tilt_input(info, env.maze.max_tilt))
            obs, reward, terminated, truncated, info = env.step(actor.executed(actions).numpy())
            done = terminated | truncated
            distance = info["goal_distance"][:, 0].copy()
            for i in np.flatnonzero(done & ~finished):
                distance[i] = info["final_info"]["goal_distance"][i][0]
                end[i], success[i] = distance[i], bool(info["final_info"]["is_success"][i])
            nearest = np.where(finished, nearest, np.minimum(nearest, distance))
            finished |= done
            actor.observe(actions, reward, done)
    finally:
        env.close()
    return {"success": success.astype(float), "start": start, "nearest": nearest, "end": end}


def _groups(values: np.ndarray, feature: str) -> list[tuple[str, np.ndarray]]:
    """Masks of ``values``' groups: each gate count, or the terciles of a continuous feature."""
    if feature == "gates":
        return [(f"{int(v)} gate{'s' if v > 1 else ''}", values == v) for v in np.unique(values)]
    edges = np.quantile(values, [0, 1 / 3, 2 / 3, 1])
    groups = []
    for i, (low, high) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        mask = (values >= low) & ((values <= high) if i == 2 else (values < high))
        groups.append((f"{low:.0f}–{high:.0f}°", mask))
    return groups


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a run trained on random mazes (bimgame train/dagger --num-mazes)")
    parser.add_argument("--mazes", type=int, default=200, help="held-out mazes, one episode each (default 200)")
    parser.add_argument("--results", type=Path, default=None, help="write the breakdown as JSON here")
    args = parser.parse_args(argv)
    if args.mazes < 3:
        parser.error(f"--mazes takes a count >= 3 (terciles), got {args.mazes}")
    net, run, step = load_run_network(args.run)
    numbers = list(range(args.mazes))
    with torch_threads(1):
        episodes = {mode: _episodes(net, run, args.mazes, greedy=mode == "greedy") for mode in ("greedy", "sampled")}
    successes = {mode: values["success"] for mode, values in episodes.items()}
    maze_set, board = MazeSet(num_mazes=args.mazes, split="test"), MazeSpec.merl()
    features = [outer_wall_features(maze_set.maze(k, board)) for k in numbers]
    rng = np.random.default_rng(0)
    out: dict[str, Any] = {"run": str(args.run), "step": step, "mazes": args.mazes, "overall": {}, "by": {}}
    for mode, values in episodes.items():
        failed = values["success"] == 0
        out["overall"][mode] = float(values["success"].mean())
        out["failed_goal_distance_cm"] = out.get("failed_goal_distance_cm", {})
        out["failed_goal_distance_cm"][mode] = {
            key: float(100 * np.median(values[key][failed])) if failed.any() else None
            for key in ("start", "nearest", "end")
        }
        print(
            f"{mode}: success {100 * values['success'].mean():.0f}%; failed episodes' goal distance (median cm): "
            + ", ".join(f"{k} {v:.1f}" for k, v in out["failed_goal_distance_cm"][mode].items() if v is not None)
        )
    for feature in ("gates", "mean_angle_to_gate"):
        column = np.array([f[feature] for f in features])
        rows = {}
        for label, mask in _groups(column, feature):
            row: dict[str, Any] = {"mazes": int(mask.sum())}
            for mode, values in successes.items():
                low, high = mean_interval(values[mask], rng=rng)
                row[mode] = {"mean": float(values[mask].mean()), "interval": [low, high]}
            rows[label] = row
            print(
                f"{feature:>18} {label:>10}: {row['mazes']:3d} mazes  greedy {100 * row['greedy']['mean']:3.0f}%  "
                f"sampled {100 * row['sampled']['mean']:3.0f}% [{100 * row['sampled']['interval'][0]:.0f}, "
                f"{100 * row['sampled']['interval'][1]:.0f}]"
            )
        out["by"][feature] = rows
    if args.results is not None:
        atomic_write_bytes(args.results, json.dumps(out, indent=2).encode())
        print(f"wrote {args.results}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
