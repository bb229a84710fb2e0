"""``bimgame score``: any policy scored with the benchmark protocol (:mod:`bimgame.experiments.protocol`),
on MERL's maze or on numbered random mazes (``--mazes``), printed as a table and written as JSON;
``--measure-references`` measures the random and expert references of the normalised score anew. On a
labyrinth task (``--task LABYRINTH-…``) it runs the labyrinth's protocol instead
(:mod:`bimgame.experiments.labyrinth_protocol`: success, completion time against CyberRunner's and the
human record)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from bimgame.cli.argtypes import TASK_NAMES, add_task_argument, check_output_file, positive_int, run_group
from bimgame.envs.labyrinth_env import LABYRINTH_OFF_PATH_RULES
from bimgame.envs.puzzles import NETWORK_OBS, check_obs, puzzle
from bimgame.envs.puzzles import TASK_NAMES as PUZZLE_TASKS
from bimgame.envs.randomization import RANDOMIZATION_PRESETS, randomization_preset
from bimgame.experiments.labyrinth_figures import plot_episode_ends
from bimgame.experiments.labyrinth_protocol import (
    CYBERRUNNER_RECORD_S,
    HUMAN_RECORD_S,
    LABYRINTH_POLICIES,
    LABYRINTH_PROTOCOL_EPISODES,
    score_labyrinth,
)
from bimgame.experiments.protocol import MAZE_FORMS, PROTOCOL_EPISODES, MazeChoice, measure_references, score
from bimgame.experiments.robustness import robustness_rows, write_robustness
from bimgame.learn.common import read_run
from bimgame.learn.maze_runs import stored_off_path_rule
from bimgame.learn.runs import CONFIG, read_run_config
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
        f"module:callable (observation -> action); on the labyrinth: {' | '.join(LABYRINTH_POLICIES)} | a bimgame "
        "run directory or checkpoint trained on --task | a model-based learner's marble law .json",
    )
    add(
        "--task",
        choices=PUZZLE_TASKS,
        default="STG1",
        type=str.upper,
        help="(default STG1) a task of the circular maze (its benchmark protocol) or of CyberRunner's labyrinth "
        "(LABYRINTH-EASY, -MEDIUM, -HARD: the labyrinth's protocol, success and completion time against "
        f"CyberRunner's {CYBERRUNNER_RECORD_S} s and the human record {HUMAN_RECORD_S} s on the hard layout)",
    )
    add(
        "--obs",
        choices=NETWORK_OBS,
        default=None,
        help="observations the policy gets (default state; on the labyrinth: a network's own, which --obs must "
        "match; built-in policies read none)",
    )
    add(
        "--episodes",
        type=positive_int,
        default=None,
        help=f"episodes of the protocol (default {PROTOCOL_EPISODES} on the maze, {LABYRINTH_PROTOCOL_EPISODES} on "
        "the labyrinth; scores are comparable only at the default)",
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
    add(
        "--off-path-rule",
        choices=LABYRINTH_OFF_PATH_RULES,
        default=None,
        help="(labyrinth tasks) when an episode ends off the path, for every policy: tolerance (the protocol's, "
        "default: no path segment near the marble in sight) or cyberrunner (CyberRunner's own test: no path "
        "point in the marble's free box); scores compare at the same rule",
    )
    add("--out", type=Path, default=None, help="write the result as JSON here")
    add(
        "--figure",
        type=Path,
        default=None,
        help="(labyrinth tasks) draw where the episodes ended to this PNG: the board with the spot on the path "
        "each episode reached, and a histogram of the progress reached",
    )
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


def _refuse_other_puzzles_run(policy: str, task: str) -> None:
    """Refuse a bimgame run trained on the other puzzle than ``task``'s (its network reads that
    puzzle's observations), naming the run's task: a labyrinth run is scored on its labyrinth task, a
    maze run on the maze's tasks. Anything else is left to the protocol to refuse."""
    path = Path(policy)
    run_dir = path.parent if path.is_file() else path
    if not (run_dir / CONFIG).is_file():
        return
    try:
        trained = read_run(run_dir).task
    except ValueError:
        return  # not a run this verb reads either: the protocol says what it is not
    if puzzle(trained).is_maze == puzzle(task).is_maze:
        return
    if puzzle(task).is_maze:
        raise ValueError(
            f"{policy} is a run on {trained} (the labyrinth), but --task {task} is the circular maze's, and "
            f"bimgame score runs the circular maze's benchmark protocol on the maze's tasks only; score the run "
            f"with --task {trained}"
        )
    raise ValueError(
        f"{policy} is a run on {trained} (the circular maze), but --task {task} is the labyrinth's: its network "
        f"reads the maze's observations; score it with --task {trained} (or another of the maze's tasks)"
    )


def _refuse_maze_flags(args: argparse.Namespace) -> None:
    """Refuse, by name, the flags of the circular maze's protocol on a labyrinth task."""
    if args.mazes != "merl":
        raise ValueError(
            f"--mazes {args.mazes}: the circular maze's random mazes; the labyrinth's protocol plays the layout "
            f"of --task {args.task} (leave --mazes out, or use a maze task: {', '.join(TASK_NAMES)})"
        )
    if args.measure_references:
        raise ValueError(
            f"--measure-references measures the circular maze's normalised-score references; --task {args.task} "
            f"is the labyrinth's, whose protocol compares completion times with CyberRunner's {CYBERRUNNER_RECORD_S} s "
            f"and the human record {HUMAN_RECORD_S} s instead (use a maze task: {', '.join(TASK_NAMES)})"
        )


def _run_labyrinth_score(args: argparse.Namespace, console: Console) -> int:
    """``bimgame score`` on a labyrinth task: :func:`score_labyrinth`, a table, ``--out`` JSON."""
    _refuse_maze_flags(args)
    if args.policy is None:
        raise ValueError(
            f"POLICY is required: {', '.join(LABYRINTH_POLICIES)}, or a bimgame run trained on {args.task}"
        )
    check_output_file(args.out, "--out", "score.json")
    check_output_file(args.figure, "--figure", "ends.png")
    _refuse_other_puzzles_run(args.policy, args.task)
    summary = score_labyrinth(
        args.policy,
        args.task,
        episodes=args.episodes or LABYRINTH_PROTOCOL_EPISODES,
        sampled=args.sampled,
        progress=not args.no_progress,
        obs=args.obs,
        off_path_rule=args.off_path_rule or "tolerance",
    )
    how = f"{summary['mode']}, {summary['obs']}" if summary["mode"] else "built-in"
    rule = "" if summary["off_path_rule"] == "tolerance" else f", off-path rule {summary['off_path_rule']}"
    table = Table(title=f"{args.policy} ({how}) on {summary['task']}, {summary['episodes']} protocol episodes{rule}")
    vs = f"vs CyberRunner {CYBERRUNNER_RECORD_S} s / human {HUMAN_RECORD_S} s"
    for column in ("success [95% CI]", escape("median time (s) [quartiles]"), "mean return", vs):
        table.add_column(column, justify="right")
    times = summary["completion_time_s"]
    median = "–"
    if times["median"] is not None:
        median = f"{times['median']:.2f} [{times['q25']:.2f}, {times['q75']:.2f}]"
    versus = "– (no success)"
    if summary["best_over_cyberrunner"] is not None:
        ratios = f"{summary['best_over_cyberrunner']:.2f}× / {summary['best_over_human']:.2f}×"
        versus = f"best {times['best']:.2f} s: {ratios}"
    elif times["best"] is not None:
        versus = f"best {times['best']:.2f} s (the records are the hard layout's)"
    table.add_row(
        _pair(summary["success_rate"], summary["success_rate_ci"], percent=True),
        median,
        _pair(summary["mean_return"], summary["mean_return_ci"]),
        versus,
    )
    console.print(table)
    ended = summary["ended_by"]
    console.print(
        f"mean progress reached: {100 * summary['mean_progress_fraction']:.1f}% of the path; episodes ended at the "
        f"goal {ended['goal']}, in a hole {ended['hole']}, off the path {ended['off_path']}, at the time limit "
        f"{ended['time']}"
    )
    if args.out is not None:
        console.print(f"wrote {write_json(args.out, summary)}")
    if args.figure is not None:
        console.print(f"wrote {plot_episode_ends(summary, args.figure, title=f'{table.title}: where they ended')}")
    trained = _trained_off_path_rule(args.policy)
    if trained is not None and trained != summary["off_path_rule"]:
        console.print(
            f"note: the run trained under the off-path rule {trained}; scored under {summary['off_path_rule']} "
            f"(--off-path-rule {trained} scores it under its own)"
        )
    return 0


def _trained_off_path_rule(policy: str) -> str | None:
    """The off-path rule the bimgame run ``policy`` (its directory or a checkpoint in it) trained under,
    if it names one; None otherwise, and for built-in policies (no run to read)."""
    try:
        return stored_off_path_rule(read_run_config(policy))
    except ValueError:
        return None


def run_score(args: argparse.Namespace) -> int:
    console = Console()
    if not puzzle(args.task).is_maze:
        return _run_labyrinth_score(args, console)
    if args.off_path_rule is not None:
        raise ValueError(
            f"--off-path-rule {args.off_path_rule}: when the labyrinth's episodes end off its printed path; "
            f"--task {args.task} is the circular maze's (use a labyrinth task: LABYRINTH-EASY, -MEDIUM, -HARD)"
        )
    if args.figure is not None:
        raise ValueError(
            f"--figure draws where the labyrinth's episodes ended; --task {args.task} is the circular maze's "
            "(use a labyrinth task: LABYRINTH-EASY, -MEDIUM, -HARD; a maze run's curves come from bimgame curves)"
        )
    episodes = args.episodes or PROTOCOL_EPISODES
    obs = args.obs or "state"
    check_obs("--obs", args.task, obs)
    if args.measure_references:
        if args.out is None:
            raise ValueError("--measure-references needs --out FILE for the measured references")
        references = measure_references(
            list(TASK_NAMES), episodes=episodes, progress=not args.no_progress, mazes=args.mazes
        )
        console.print(f"wrote {write_json(args.out, references)}")
        return 0
    if args.policy is None:
        raise ValueError("POLICY is required (or --measure-references)")
    check_output_file(args.out, "--out", "score.json")
    _refuse_other_puzzles_run(args.policy, args.task)
    summary = score(
        args.policy,
        args.task,
        obs=obs,
        episodes=episodes,
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
