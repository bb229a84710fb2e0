"""Command-line verbs of the puzzle itself: ``bimgame maze`` (the maze drawn to a PNG), ``bimgame
rollout`` (episodes of a scripted policy, a summary table, optionally a GIF) and ``bimgame demo``
(the Quick start's maze picture and GIF of one episode)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from bimgame.cli.argtypes import add_max_steps_argument, add_task_argument, non_negative_int, positive_int
from bimgame.expert.policies import POLICIES
from bimgame.expert.rollout import run_episodes
from bimgame.sim.figures import draw_maze, draw_maze_grid
from bimgame.sim.generate import maze_hash
from bimgame.sim.maze import MazeSpec
from bimgame.sim.maze_sets import MAZE_SPLITS, maze_number
from bimgame.util.images import write_gif

__all__ = ["add_parsers", "run_maze", "run_rollout", "run_demo"]


def add_parsers(verbs: argparse._SubParsersAction) -> None:
    """Add the ``maze``, ``rollout`` and ``demo`` verbs to the command line's sub-parsers."""
    maze = verbs.add_parser("maze", help="draw the maze (MERL's, or random ones) to a PNG")
    maze.add_argument("--out", type=Path, default=Path("maze.png"), help="PNG path (default maze.png)")
    maze.add_argument("--no-geodesic", action="store_true", help="do not shade the geodesic distance")
    maze.add_argument(
        "--number",
        type=non_negative_int,
        default=None,
        help="draw random maze NUMBER of --split (the mazes of --num-mazes; default: MERL's maze)",
    )
    maze.add_argument("--split", choices=MAZE_SPLITS, default="train", help="with --number or --grid (default train)")
    maze.add_argument(
        "--grid", type=positive_int, default=None, help="draw random mazes 0..GRID-1 of --split side by side"
    )
    maze.set_defaults(run=run_maze)

    rollout = verbs.add_parser("rollout", help="run episodes of a simple policy and summarise them")
    add_task_argument(rollout, "STG1")
    rollout.add_argument("--policy", choices=POLICIES, default="random")
    rollout.add_argument("--episodes", type=positive_int, default=10)
    rollout.add_argument("--seed", type=int, default=0)
    add_max_steps_argument(rollout)
    rollout.add_argument("--n-marbles", type=positive_int, default=1)
    rollout.add_argument("--gif", type=Path, default=None, help="write the first episode as a GIF")
    rollout.set_defaults(run=run_rollout)

    demo = verbs.add_parser("demo", help="write a maze picture and a GIF of one episode")
    demo.add_argument("--out", type=Path, default=Path("out"), help="output directory (default out/)")
    add_task_argument(demo, "FULL")
    demo.add_argument("--policy", choices=POLICIES, default="expert")
    demo.add_argument("--seed", type=int, default=0)
    demo.set_defaults(run=run_demo)


def run_maze(args: argparse.Namespace) -> int:
    """``bimgame maze``: MERL's maze, a random maze (``--number``) or several (``--grid``) drawn to a PNG."""
    if args.grid is not None and args.number is not None:
        raise SystemExit("bimgame maze: --grid and --number exclude each other (many mazes, or one)")
    if args.grid is not None:
        specs = [maze_number(i, args.split) for i in range(args.grid)]
        titles = [f"{args.split} maze {i} ({maze_hash(spec)[:8]})" for i, spec in enumerate(specs)]
        print(f"wrote {draw_maze_grid(specs, titles, args.out)}")
        return 0
    spec = MazeSpec.merl() if args.number is None else maze_number(args.number, args.split)
    print(f"wrote {draw_maze(spec, args.out, geodesic=not args.no_geodesic)}")
    return 0


def run_rollout(args: argparse.Namespace) -> int:
    """``bimgame rollout``: episodes of a scripted policy, a summary table, optionally a GIF."""
    results, frames = run_episodes(
        args.task,
        args.policy,
        args.episodes,
        seed=args.seed,
        max_steps=args.max_steps,
        n_marbles=args.n_marbles,
        record_first=args.gif is not None,
    )
    console = Console()
    table = Table(title=f"{args.policy} policy on {args.task} ({args.episodes} episodes, seed {args.seed})")
    for column in ("episodes", "success", "mean return", "mean length", "median length", "steps/s"):
        table.add_column(column, justify="right")
    lengths = np.array([r["length"] for r in results])
    table.add_row(
        str(len(results)),
        f"{np.mean([r['success'] for r in results]):.0%}",
        f"{np.mean([r['return'] for r in results]):.2f}",
        f"{lengths.mean():.1f}",
        f"{np.median(lengths):.0f}",
        f"{lengths.sum() / max(sum(r['seconds'] for r in results), 1e-9):,.0f}",
    )
    console.print(table)
    if args.gif is not None:
        console.print(f"wrote {write_gif(frames, args.gif)} ({len(frames)} frames)")
    return 0


def run_demo(args: argparse.Namespace) -> int:
    """``bimgame demo``: the maze picture and a GIF of one episode in ``--out``."""
    print(f"wrote {draw_maze(MazeSpec.merl(), args.out / 'maze.png')}")
    results, frames = run_episodes(args.task, args.policy, 1, seed=args.seed, record_first=True)
    result = results[0]
    gif = write_gif(frames, args.out / "episode.gif")
    print(
        f"{args.policy} policy on {args.task}: {'solved' if result['success'] else 'not solved'} in "
        f"{result['length']} steps, return {result['return']:.0f}; wrote {gif}"
    )
    return 0
