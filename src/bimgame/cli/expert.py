"""Command-line verbs of the MPC expert: ``bimgame expert-eval`` (success rate, trajectory lengths and
their histogram) and ``bimgame generate`` (expert trajectories as a Minari dataset, on the circular
maze's tasks or CyberRunner's labyrinth's, ``--task LABYRINTH-EASY|MEDIUM|HARD``)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from bimgame.cli.argtypes import (
    add_backend_arguments,
    add_max_steps_argument,
    add_task_argument,
    non_negative_int,
    positive_int,
)
from bimgame.cli.flags import add_settings_flags, given_settings
from bimgame.envs.labyrinth_env import LABYRINTH_ACTION_TYPES, LABYRINTH_CONTROL_RATES
from bimgame.envs.puzzles import TASK_NAMES as PUZZLE_TASKS
from bimgame.envs.puzzles import puzzle
from bimgame.expert.datasets import MINARI_DIR, dataset_summary, generate_dataset
from bimgame.expert.evaluation import evaluate_expert, plot_length_histogram, summarise, write_results
from bimgame.expert.labyrinth_datasets import generate_labyrinth_dataset
from bimgame.expert.labyrinth_mpc import LABYRINTH_SAMPLINGS, LabyrinthMPCConfig
from bimgame.expert.mpc import SAMPLINGS, MPCConfig
from bimgame.util.files import DiskFullError

#: The expert's settings with a flag (the hold lengths and threads keep their defaults).
MPC_FLAGS = ("n_samples", "horizon", "sampling", "reward")
#: Those that ``bimgame generate`` also sets for the labyrinth's expert (:class:`LabyrinthMPCConfig`).
LABYRINTH_MPC_FLAGS = ("n_samples", "horizon", "sampling")
#: The labyrinth expert's own settings with a flag (the maze's expert has no such setting).
LABYRINTH_ONLY_MPC_FLAGS = ("n_plans",)
#: The flag of each MPC setting whose name is not ``--field-name``.
_MPC_FLAG_NAMES = {"reward": "--planning-reward", "n_plans": "--plans"}
#: Samplings of the labyrinth's expert only (the maze's refuses them naming the flag).
LABYRINTH_ONLY_SAMPLINGS = tuple(name for name in LABYRINTH_SAMPLINGS if name not in SAMPLINGS)
_SAMPLING_HELP = (
    '"uniform" (independent actions), "hold" (each action held for hold_min..hold_max steps) or, on the '
    'labyrinth with continuous actions, "mppi" (a remembered mean plan refined by score-weighted averaging)'
)

__all__ = [
    "add_parsers",
    "add_mpc_arguments",
    "mpc_config_from",
    "mpc_flag",
    "labyrinth_mpc_config_from",
    "add_generate_arguments",
    "run_generate",
    "run_expert_eval",
]


def add_parsers(verbs: argparse._SubParsersAction) -> None:
    """Add the ``expert-eval`` and ``generate`` verbs to the command line's sub-parsers."""
    evaluate = verbs.add_parser("expert-eval", help="measure the MPC expert: success, lengths, histogram")
    add_task_argument(evaluate, "FULL")
    evaluate.add_argument("--episodes", type=positive_int, default=50)
    evaluate.add_argument("--seed", type=int, default=0)
    evaluate.add_argument("--workers", type=positive_int, default=None, help="processes (default: all cores)")
    add_max_steps_argument(evaluate)
    add_mpc_arguments(evaluate)
    evaluate.add_argument(
        "--out", type=Path, default=None, help="directory for results.json and lengths.png (default: print only)"
    )
    evaluate.set_defaults(run=run_expert_eval)

    generate = verbs.add_parser("generate", help="write expert trajectories as a Minari dataset")
    add_generate_arguments(generate)
    add_mpc_arguments(generate, labyrinth=True)
    generate.set_defaults(run=run_generate)


def add_mpc_arguments(parser: argparse.ArgumentParser, *, labyrinth: bool = False) -> None:
    """The MPC expert's flags (shared by expert-eval and generate), in a group of their own.
    ``labyrinth``: the verb also runs the labyrinth's expert, which takes :data:`LABYRINTH_MPC_FLAGS`
    with defaults of its own: every flag then defaults to None (not given), its help naming both
    defaults, and :func:`mpc_config_from` / :func:`labyrinth_mpc_config_from` fill in each expert's."""
    group = parser.add_argument_group("MPC expert", "the random-shooting planner's samples, horizon and reward")
    aliases: dict[str, tuple[str, ...]] = {"n_samples": ("-K",), "horizon": ("-H",)}
    if not labyrinth:
        add_settings_flags(group, MPCConfig, MPC_FLAGS, flags=_MPC_FLAG_NAMES, aliases=aliases)
        return
    maze, board = MPCConfig(), LabyrinthMPCConfig()
    for name in MPC_FLAGS:
        ours, theirs = getattr(maze, name), getattr(board, name, None)
        if name not in LABYRINTH_MPC_FLAGS:
            shown = f" {ours}; the maze's only"
        else:
            shown = f" {ours}" if ours == theirs else f" {ours} on the maze, {theirs} on the labyrinth"
        add_settings_flags(
            group,
            MPCConfig,
            [name],
            default_none=True,
            default_text=shown,
            flags=_MPC_FLAG_NAMES,
            aliases=aliases,
            choices={"sampling": tuple(dict.fromkeys(SAMPLINGS + LABYRINTH_SAMPLINGS))},
            helps={"sampling": _SAMPLING_HELP},
        )
    add_settings_flags(
        group,
        LabyrinthMPCConfig,
        LABYRINTH_ONLY_MPC_FLAGS,
        default_none=True,
        default_text=" 1; the labyrinth's only",
        flags=_MPC_FLAG_NAMES,
        aliases={"n_plans": ("-P",)},
    )


def mpc_flag(name: str) -> str:
    """The command-line flag of MPC setting ``name`` (``n_plans`` → ``--plans``)."""
    return _MPC_FLAG_NAMES.get(name, "--" + name.replace("_", "-"))


def mpc_config_from(args: argparse.Namespace, base: MPCConfig | None = None) -> MPCConfig:
    """The maze expert's settings from the flags of :func:`add_mpc_arguments`, ``base``'s (default:
    the expert's defaults) for those not given; a labyrinth-only setting given is refused naming its flag."""
    refused = [mpc_flag(name) for name in given_settings(args, LabyrinthMPCConfig, LABYRINTH_ONLY_MPC_FLAGS)]
    refused += [f"--sampling {args.sampling}"] if getattr(args, "sampling", None) in LABYRINTH_ONLY_SAMPLINGS else []
    if refused:
        raise ValueError(
            f"{', '.join(refused)}: the labyrinth's expert setting, not the circular maze's "
            f"(task {getattr(args, 'task', None)}); the maze's expert takes "
            f"{', '.join(map(mpc_flag, MPC_FLAGS))} (--sampling {' or '.join(SAMPLINGS)})"
        )
    return dataclasses.replace(base or MPCConfig(), **given_settings(args, MPCConfig, MPC_FLAGS))


def labyrinth_mpc_config_from(args: argparse.Namespace) -> LabyrinthMPCConfig:
    """The labyrinth expert's settings from the flags of :func:`add_mpc_arguments` (``labyrinth=True``),
    its own defaults for those not given; a maze-only setting given is refused naming its flag."""
    given = given_settings(args, MPCConfig, MPC_FLAGS)
    refused = [mpc_flag(name) for name in given if name not in LABYRINTH_MPC_FLAGS]
    if refused:
        raise ValueError(
            f"{', '.join(refused)}: the circular maze's expert setting, not the labyrinth's (task {args.task}); "
            f"the labyrinth's expert takes {', '.join(map(mpc_flag, LABYRINTH_MPC_FLAGS + LABYRINTH_ONLY_MPC_FLAGS))}"
        )
    own = given_settings(args, LabyrinthMPCConfig, LABYRINTH_ONLY_MPC_FLAGS)
    return LabyrinthMPCConfig(**{name: value for name, value in given.items() if name in LABYRINTH_MPC_FLAGS}, **own)


def add_generate_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the ``bimgame generate`` options to ``parser`` (a sub-parser; the MPC expert's own flags
    are :func:`add_mpc_arguments`, shared with ``expert-eval``); returns it."""
    parser.add_argument(
        "--task",
        choices=PUZZLE_TASKS,
        default="FULL",
        type=str.upper,
        help="(default FULL) a task of the circular maze or of CyberRunner's labyrinth (LABYRINTH-EASY, -MEDIUM, "
        "-HARD: the labyrinth's MPC expert, bimgame.expert.labyrinth_datasets)",
    )
    parser.add_argument("--episodes", type=positive_int, default=500)
    parser.add_argument(
        "--out", type=Path, required=True, help="the run's directory (new, empty, or this run's to resume it)"
    )
    parser.add_argument("--seed", type=non_negative_int, default=0, help="run seed (default 0)")
    parser.add_argument(
        "--workers", type=positive_int, default=None, help="parallel episodes (default: the number of CPUs)"
    )
    add_backend_arguments(parser, "episodes")
    add_max_steps_argument(parser)
    parser.add_argument(
        "--num-mazes",
        type=non_negative_int,  # 0 is refused by generate_dataset, which says why
        default=None,
        help="play the episodes on this many random training mazes, episode j on maze START + (j mod N), "
        "as `bimgame train --num-mazes N --start-maze START` trains on (default: MERL's maze)",
    )
    parser.add_argument(
        "--start-maze", type=non_negative_int, default=0, help="the first training maze's number (with --num-mazes)"
    )
    labyrinth = parser.add_argument_group("labyrinth", "only with a labyrinth task")
    labyrinth.add_argument(
        "--action-type",
        choices=LABYRINTH_ACTION_TYPES,
        default=None,
        help="the labyrinth's actions: continuous tilt rates (default, CyberRunner's) or discrete (0..4)",
    )
    labyrinth.add_argument(
        "--control-hz",
        type=int,
        choices=LABYRINTH_CONTROL_RATES,
        default=None,
        help="the labyrinth's action rate in Hz (default 55, CyberRunner's)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def run_generate(args: argparse.Namespace) -> int:
    """``bimgame generate``: generate (or resume, or verify) a dataset and print a summary."""
    if not puzzle(args.task).is_maze:
        return _run_labyrinth_generate(args)
    labyrinth_only = [
        flag
        for flag, value in (("--action-type", args.action_type), ("--control-hz", args.control_hz))
        if value is not None
    ]
    if labyrinth_only:
        raise ValueError(
            f"{', '.join(labyrinth_only)}: the labyrinth's option{'s' if len(labyrinth_only) > 1 else ''}, not the "
            f"circular maze's (task {args.task}, whose expert plays discrete actions at 30 Hz)"
        )
    start = time.perf_counter()
    try:
        out = generate_dataset(
            args.out,
            args.task,
            args.episodes,
            seed=args.seed,
            config=mpc_config_from(args),
            workers=args.workers,
            backend=args.backend,
            ray_address=args.ray_address,
            progress=not args.no_progress,
            max_steps=args.max_steps,
            num_mazes=args.num_mazes,
            start_maze=args.start_maze,
        )
    except ImportError as error:
        print(f"bimgame generate: error: {error}", file=sys.stderr)
        return 2
    mazes = (
        ""
        if args.num_mazes is None
        else f" on training mazes {args.start_maze}..{args.start_maze + args.num_mazes - 1}"
    )
    _print_summary(out, mazes, time.perf_counter() - start)
    print(
        f"load with bimgame.expert.datasets.load_dataset({str(out)!r}), or minari.load_dataset("
        f"{dataset_summary(out)['dataset_id']!r}) with MINARI_DATASETS_PATH={out / MINARI_DIR}"
    )
    return 0


def _run_labyrinth_generate(args: argparse.Namespace) -> int:
    """``bimgame generate`` on a labyrinth task: :func:`generate_labyrinth_dataset`; the circular
    maze's options are refused by name."""
    maze_only = [
        flag
        for flag, given in (
            ("--num-mazes", args.num_mazes is not None),
            ("--start-maze", args.start_maze != 0),
        )
        if given
    ]
    if maze_only:
        raise ValueError(
            f"{', '.join(maze_only)}: the circular maze's random mazes; the labyrinth plays the layout of "
            f"--task {args.task} (leave {' and '.join(maze_only)} out)"
        )
    config = labyrinth_mpc_config_from(args)
    given = {name: getattr(args, name) for name in ("action_type", "control_hz") if getattr(args, name) is not None}
    start = time.perf_counter()
    try:
        out = generate_labyrinth_dataset(
            args.out,
            args.task,
            args.episodes,
            seed=args.seed,
            **given,  # the rest: generate_labyrinth_dataset's defaults (CyberRunner's)
            config=config,
            workers=args.workers,
            backend=args.backend,
            ray_address=args.ray_address,
            progress=not args.no_progress,
            max_steps=args.max_steps,
        )
    except ImportError as error:
        print(f"bimgame generate: error: {error}", file=sys.stderr)
        return 2
    _print_summary(out, "", time.perf_counter() - start)
    print(
        f"load with bimgame.expert.labyrinth_datasets.load_labyrinth_sequences({str(out)!r}, gamma=...) or "
        f"load_labyrinth_dataset, or minari.load_dataset({dataset_summary(out)['dataset_id']!r}) with "
        f"MINARI_DATASETS_PATH={out / MINARI_DIR}"
    )
    return 0


def _print_summary(out: Path, mazes: str, seconds: float) -> None:
    """A finished dataset's counts and disk use."""
    summary = dataset_summary(out)
    print(
        f"{summary['dataset_id']} in {out}: {summary['episodes']} episodes{mazes}, {summary['steps']} steps, "
        f"success {summary['success_rate']:.0%}, mean length {summary['mean_length']:.1f}, "
        f"{seconds:.1f} s"
    )
    print(
        f"disk: Minari (hdf5) {_megabytes(summary['bytes_minari'])} "
        f"({summary['bytes_per_1000_steps_minari'] / 1e3:.0f} kB per 1000 steps), episode files "
        f"{_megabytes(summary['bytes_episode_files'])} "
        f"({summary['bytes_per_1000_steps_episode_files'] / 1e3:.0f} kB per 1000 steps)"
    )


def run_expert_eval(args: argparse.Namespace) -> int:
    """``bimgame expert-eval``: run the expert, print a summary table, optionally write the results
    and the length histogram."""
    config = mpc_config_from(args)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)  # an unusable --out fails now, not after the episodes
    start = time.perf_counter()
    results = evaluate_expert(
        args.task, args.episodes, config, seed=args.seed, workers=args.workers, max_steps=args.max_steps
    )
    summary = summarise(results)
    summary["wall_seconds"] = time.perf_counter() - start
    table = Table(
        title=f"MPC expert on {args.task}: K={config.n_samples} H={config.horizon} "
        f"{config.sampling} sampling, {config.reward} reward, seed {args.seed}"
    )
    for column in ("episodes", "success", "median length (solved)", "90th pct", "max", "ms/decision", "wall s"):
        table.add_column(column, justify="right")
    table.add_row(
        str(summary["episodes"]),
        f"{summary['success_rate']:.0%}",
        _steps(summary["median_length_solved"]),
        _steps(summary["p90_length_solved"]),
        _steps(summary["max_length_solved"]),
        f"{summary['ms_per_decision']:.1f}",
        f"{summary['wall_seconds']:.0f}",
    )
    console = Console()
    console.print(table)
    if args.out is not None:
        try:
            write_results(results, summary, config, args.task, args.out / "results.json")
            png = plot_length_histogram(
                results,
                args.out / "lengths.png",
                title=f"MPC expert, {args.task}, K={config.n_samples}, H={config.horizon}",
            )
        except DiskFullError as error:
            saved = (
                "results.json was saved, the histogram not" if error.path.name == "lengths.png" else "nothing was saved"
            )
            raise error.with_advice(f"{saved}; free some space and rerun the same command") from error
        console.print(f"wrote {args.out / 'results.json'} and {png}")
    return 0


def _steps(value: float | None) -> str:
    """A length statistic for the table: "-" when no episode was solved."""
    return "-" if value is None else f"{value:.0f}"


def _megabytes(size: int) -> str:
    return f"{size / 1e6:.1f} MB"
