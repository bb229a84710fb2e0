"""``bimgame score``: any policy scored with the benchmark protocol (:mod:`bimgame.experiments.protocol`),
on MERL's maze or on numbered random mazes (``--mazes``), printed as a table and written as JSON;
``--measure-references`` measures the random and expert references of the normalised score anew."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from rich.console import Console
from rich.table import Table

from bimgame.cli.argtypes import TASK_NAMES, add_task_argument, check_output_file, positive_int, run_group
from bimgame.envs.observe import OBS_MODES
from bimgame.envs.puzzles import puzzle
from bimgame.envs.randomization import RANDOMIZATION_PRESETS, randomization_preset
from bimgame.experiments.protocol import MAZE_FORMS, PROTOCOL_EPISODES, MazeChoice, measure_references, score
from bimgame.experiments.robustness import robustness_rows, write_robustness
from bimgame.learn.common import read_run
from bimgame.learn.runs import CONFIG
from bimgame.util.files import write_json

__all__ = ["add_score_arguments", "run_score", "maze_choice", "add_robustness_arguments", "run_robustness"]


def maze_choice(text: str) -> str:
    """A ``--mazes`` value in its canonical spelling (``argparse`` names the flag and the allowed forms
    when it is not one)."""
    try:
        return str(MazeChoice.parse(text))
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def add_score_arguments(parser: argparse.ArgumentParser) -> None:
    add = parser.add_argument
    add(
        "policy",
        nargs="?",
        metavar="POLICY",
        help="random | noop | geodesic | expert | a bimgame run directory or checkpoint | an SB3 model .zip | "
        "module:callable (observation -> action)",
    )
    add_task_argument(parser, "STG1", help="(default STG1)")
    add("--obs", choices=OBS_MODES, default="state", help="observations the policy gets (default state)")
    add(
        "--episodes",
        type=positive_int,
        default=PROTOCOL_EPISODES,
        help=f"episodes of the protocol (default {PROTOCOL_EPISODES}; scores are comparable only at the default)",
    )
    add(
        "--mazes",
        type=maze_choice,
        default="merl",
        metavar="MAZES",
        help=f"the mazes the episodes are on, one of: {MAZE_FORMS}. merl (default): MERL's maze; test: "
        "episode k on held-out test maze k (the default 100 episodes score 100 held-out mazes); test:N, "
        "train:N: the episodes spread evenly over mazes 0..N-1 of the split (train:N: the mazes of a run "
        "trained with --num-mazes N); train:START:N, test:START:N: mazes START..START+N-1. Built-in "
        "policies plan in each episode's maze. On mazes, state observations end with the maze's encoding "
        "(128 values): a bimgame network trained with --num-mazes reads it, one trained on MERL's maze "
        "gets the observations without it, SB3 models and module:callable policies get it as it is",
    )
    add("--sampled", action="store_true", help="a network samples its actions instead of acting greedily")
    add("--out", type=Path, default=None, help="write the result as JSON here")
    add("--no-progress", action="store_true", help="no progress bar")
    add(
        "--measure-references",
        action="store_true",
        help="measure the random and expert reference returns of every task (writes --out; takes minutes) on "
        "--mazes (MERL's maze, or e.g. test: the references of the normalised score on random mazes)",
    )


def _pair(value: float | None, interval: list[float] | None, percent: bool = False) -> str:
    if value is None:
        return "–"
    shown = (lambda v: f"{100 * v:.0f}%") if percent else (lambda v: f"{v:.2f}")
    return f"{shown(value)} [{shown(interval[0])}, {shown(interval[1])}]" if interval else shown(value)


def _refuse_labyrinth_run(policy: str) -> None:
    """Refuse a bimgame run on the labyrinth: the benchmark protocol (its tasks, mazes and reference
    scores) is the circular maze's. ``bimgame evaluate`` evaluates such a run."""
    path = Path(policy)
    run_dir = path.parent if path.is_file() else path
    if not (run_dir / CONFIG).is_file():
        return
    try:
        task = read_run(run_dir).task
    except ValueError:
        return  # not a run this verb reads either: score() says what it is not
    if not puzzle(task).is_maze:
        raise ValueError(
            f"{policy} is a run on {task}: bimgame score runs the circular maze's benchmark protocol (its tasks, "
            f"mazes and reference scores) only; evaluate it with: bimgame evaluate {policy}"
        )


def run_score(args: argparse.Namespace) -> int:
    console = Console()
    if args.measure_references:
        if args.out is None:
            raise ValueError("--measure-references needs --out FILE for the measured references")
        references = measure_references(
            list(TASK_NAMES), episodes=args.episodes, progress=not args.no_progress, mazes=args.mazes
        )
        console.print(f"wrote {write_json(args.out, references)}")
        return 0
    if args.policy is None:
        raise ValueError("POLICY is required (or --measure-references)")
    check_output_file(args.out, "--out", "score.json")
    _refuse_labyrinth_run(args.policy)
    summary = score(
        args.policy,
        args.task,
        obs=args.obs,
        episodes=args.episodes,
        sampled=args.sampled,
        progress=not args.no_progress,
        mazes=args.mazes,
    )
    table = Table(
        title=f"{args.policy} on {summary['task']} ({summary['obs']}), {summary['episodes']} protocol episodes, "
        f"{summary['maze_set']}"
    )
    for column in ("success [95% CI]", "mean return", "mean length (solved)", "normalised score"):
        table.add_column(column, justify="right")
    table.add_row(
        _pair(summary["success_rate"], summary["success_rate_ci"], percent=True),
        _pair(summary["mean_return"], summary["mean_return_ci"]),
        _pair(summary["mean_length_solved"], summary["mean_length_solved_ci"]),
        _pair(summary["normalised_score"], summary["normalised_score_ci"]),
    )
    console.print(table)
    if summary["references"] is None:
        console.print(
            f"no normalised score: no reference scores for {summary['task']} on random mazes "
            "(measured with: bimgame score --measure-references --mazes test --out FILE)"
        )
    for note in summary["notes"]:
        console.print(f"note: {note}")
    if args.out is not None:
        console.print(f"wrote {write_json(args.out, {'policy': args.policy, **summary})}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit("use: bimgame score ...")


def add_robustness_arguments(parser: argparse.ArgumentParser) -> None:
    """``bimgame robustness``: policies and the expert on the nominal board and randomised ones."""
    add = parser.add_argument
    add(
        "groups",
        nargs="*",
        type=run_group,
        metavar="LABEL=RUN[,RUN...]",
        help="a label and its run directories (e.g. one per seed)",
    )
    add_task_argument(parser, "STG1", help="(default STG1)")
    add(
        "--randomize",
        nargs="+",
        choices=tuple(RANDOMIZATION_PRESETS),
        default=["physics"],
        help="randomised conditions besides the nominal board (default physics)",
    )
    add("--episodes", type=positive_int, default=50, help="episodes per source and condition (default 50)")
    add("--expert-seeds", type=int, default=3, help="MPC expert: sources (seeds) to measure, 0: none (default 3)")
    add("--expert-episodes", type=positive_int, default=None, help="episodes per expert seed (default --episodes)")
    add("--sampled", action="store_true", help="networks sample their actions instead of acting greedily")
    add("--seed", type=int, default=0, help="seed of the evaluation episodes (default 0)")
    add(
        "--workers",
        type=positive_int,
        default=1,
        help="processes for the expert's episodes (they do not depend on it; default 1)",
    )
    add("--out", type=Path, required=True, help="directory for robustness.csv and robustness.md")
    add("--no-progress", action="store_true", help="no progress bar")


def run_robustness(args: argparse.Namespace) -> int:
    if args.expert_seeds < 0:
        raise ValueError(f"--expert-seeds must be >= 0, got {args.expert_seeds}")
    if not args.groups and args.expert_seeds == 0:
        raise ValueError("nothing to measure: give LABEL=RUN groups or --expert-seeds > 0")
    conditions = {"nominal": None, **{name: randomization_preset(name) for name in args.randomize}}
    groups: dict[str, Sequence[str]] = {str(label): [str(p) for p in runs] for label, runs in args.groups}
    rows = robustness_rows(
        groups,
        args.task,
        conditions,
        episodes=args.episodes,
        seed=args.seed,
        sampled=args.sampled,
        progress=not args.no_progress,
    )
    if args.expert_seeds:
        rows += robustness_rows(
            {},
            args.task,
            conditions,
            episodes=args.expert_episodes or args.episodes,
            seed=args.seed,
            expert_seeds=args.expert_seeds,
            progress=not args.no_progress,
            workers=args.workers,
        )
    csv_path, md_path = write_robustness(rows, args.out)
    print(md_path.read_text())
    print(f"wrote {csv_path} and {md_path}", file=sys.stderr)
    return 0
