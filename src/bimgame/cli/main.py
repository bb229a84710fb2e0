"""The ``bimgame`` command line: ``bimgame <verb> [options]``.

Verbs:
  maze         draw the maze (walls, gates, channels, geodesic distance) to a PNG
  rollout      run episodes of a simple policy on a task, print a summary table, optionally a GIF
  demo         the Quick start's main job: a maze picture and a GIF of one episode
  expert-eval  success rate and trajectory lengths of the MPC expert, with the length histogram
  generate     expert trajectories as a Minari dataset (parallel, resumable, local or Ray)
  train        A3C with the paper's recurrent actor-critic (checkpoints, logs, resume)
  evaluate     success rate and episode length of a trained run, optionally a GIF
  curves       learning curves of a run (PNG)
  compare      learning curves of several groups of runs in one figure (PNG)
  pretrain     supervised pre-training on expert trajectories: the policy π^s or the value V̂
  dagger       DAgger: the MPC expert (or a trained policy) labels the learner's states
  reproduce    the paper's experiments in one resumable command: dataset, pre-training, runs, report
  report       rebuild a reproduction's figures, tables and report.md from its saved results
  score        any policy scored with the benchmark protocol, normalised (random 0, expert 100)
  robustness   policies and the MPC expert on the nominal board and on domain-randomised boards
  play         play in a browser (arrow keys), watch a trained agent, record human episodes as a dataset

Each verb family has its module (:mod:`~bimgame.cli.maze`, :mod:`~bimgame.cli.expert`,
:mod:`~bimgame.cli.train`, :mod:`~bimgame.cli.learn`, :mod:`~bimgame.cli.reproduce`,
:mod:`~bimgame.cli.play`) with its
arguments and its run function; this one builds the parser from them and dispatches.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bimgame.cli import expert as cli_expert
from bimgame.cli import learn as cli_learn
from bimgame.cli import maze as cli_maze
from bimgame.cli import play as cli_play
from bimgame.cli import reproduce as cli_reproduce
from bimgame.cli import score as cli_score
from bimgame.cli import train as cli_train
from bimgame.cli.argtypes import run_group, step_count
from bimgame.learn.curves import plot_comparison, plot_run

__all__ = ["main", "build_parser"]


#: The verbs of the learning agents and the reproduction: (verb, help, add its arguments, run it).
_LEARNING_VERBS = (
    ("train", "train an A3C agent", cli_train.add_train_arguments, cli_train.run_train),
    ("evaluate", "evaluate a trained run", cli_train.add_evaluate_arguments, cli_train.run_evaluate),
    ("pretrain", "pre-train π^s (or V̂) on an expert dataset", cli_learn.add_pretrain_arguments, cli_learn.run_pretrain),
    ("dagger", "DAgger with the MPC expert or a trained teacher", cli_learn.add_dagger_arguments, cli_learn.run_dagger),
    (
        "reproduce",
        "run the paper's experiments (resumable)",
        cli_reproduce.add_reproduce_arguments,
        cli_reproduce.run_reproduce,
    ),
    (
        "report",
        "rebuild a reproduction's figures, tables and report",
        cli_reproduce.add_report_arguments,
        cli_reproduce.run_report,
    ),
    (
        "score",
        "score any policy with the benchmark protocol (normalised: random 0, expert 100)",
        cli_score.add_score_arguments,
        cli_score.run_score,
    ),
    (
        "robustness",
        "policies and the MPC expert on the nominal board and domain-randomised ones",
        cli_score.add_robustness_arguments,
        cli_score.run_robustness,
    ),
)


def build_parser() -> argparse.ArgumentParser:
    """The parser of every verb; ``args.run(args)`` runs the verb parsed."""
    parser = argparse.ArgumentParser(prog="bimgame", description="The Ball-in-Maze Game on MuJoCo.")
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="VERB")
    cli_maze.add_parsers(verbs)
    cli_expert.add_parsers(verbs)
    for name, text, add_arguments, run in _LEARNING_VERBS:
        verb = verbs.add_parser(name, help=text)
        add_arguments(verb)
        verb.set_defaults(run=run)
    cli_play.add_parsers(verbs)

    curves = verbs.add_parser("curves", help="plot a run's learning curves")
    curves.add_argument("run_dir", type=Path)
    curves.add_argument("--out", type=Path, default=None, help="PNG path (default RUN_DIR/curves.png)")
    curves.set_defaults(run=_curves)
    compare = verbs.add_parser("compare", help="learning curves of groups of runs in one figure")
    compare.add_argument(
        "groups",
        nargs="+",
        type=run_group,
        metavar="LABEL=RUN[,RUN...]",
        help="a label and the run directories averaged under it (e.g. seeds)",
    )
    compare.add_argument("--out", type=Path, required=True, help="PNG path")
    compare.add_argument("--title", default="", help="figure title")
    compare.add_argument("--max-step", type=step_count, default=None, help="cut runs at this many steps (e.g. 1.2M)")
    compare.set_defaults(run=_compare)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run ``bimgame`` with ``argv`` (default: the process's arguments); returns the exit status. A bad
    value or a file problem prints ``bimgame VERB: error: …`` and returns 2."""
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except (ValueError, OSError) as error:
        print(f"bimgame {args.verb}: error: {error}", file=sys.stderr)
        return 2


def _curves(args: argparse.Namespace) -> int:
    print(f"wrote {plot_run(args.run_dir, args.out)}")
    return 0


def _compare(args: argparse.Namespace) -> int:
    print(f"wrote {plot_comparison(dict(args.groups), args.out, title=args.title, max_step=args.max_step)}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
