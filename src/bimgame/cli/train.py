"""Command-line verbs for learning agents: ``bimgame train`` (A3C) and ``bimgame evaluate``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from types import SimpleNamespace

from rich.console import Console
from rich.table import Table

from bimgame.cli.argtypes import (
    check_output_file,
    episode_count,
    finite_float,
    positive_float,
    seed,
    step_count,
    step_count_or_zero,
)
from bimgame.cli.flags import add_flag_groups, add_grouped_settings_flags, given_settings, plain
from bimgame.cli.train_ppo import (
    PPO_GROUP,
    add_ppo_arguments,
    announce,
    given_reward,
    refuse_ppo_only_flags,
    train_ppo_from_args,
)
from bimgame.envs.labyrinth_env import LABYRINTH_OFF_PATH_RULES
from bimgame.envs.puzzles import TASK_NAMES, puzzle
from bimgame.envs.shaping import DEFAULT_GEODESIC_COEF
from bimgame.learn.a3c import A3CConfig, resolve_config, train
from bimgame.learn.actor import evaluate_network
from bimgame.learn.common import NetworkSettings, load_run_network
from bimgame.learn.learner_settings import DEFAULT_FINETUNE
from bimgame.learn.rewards import RewardSettings, run_reward
from bimgame.learn.run_dir import TrainingError, TrainResult
from bimgame.util.files import write_json
from bimgame.util.images import write_gif
from bimgame.util.settings import field_docs

__all__ = ["add_train_arguments", "add_evaluate_arguments", "run_train", "run_evaluate", "TRAIN_GROUPS", "A3C_GROUPS"]


#: The learners ``bimgame train --algo`` runs.
ALGOS = ("a3c", "ppo")
#: ``bimgame train --help``'s groups: (title, description) in the order shown.
TRAIN_GROUPS = (
    ("run", "the run directory and where the run starts from"),
    ("environment", "the task, its episodes and the reward"),
    ("network", "the actor-critic's observations, sizes and inputs (with --init or --resume: the run's unless given)"),
    ("optimisation", "A3C's workers, loss and optimiser"),
    (
        "fine-tuning",
        (
            f"starting from a pre-trained π^s (--init), a setting not given takes the value of the "
            f"--finetune preset (default {DEFAULT_FINETUNE})"
        ),
    ),
    ("curriculum", "where training episodes start"),
    ("logging", "checkpoints, evaluations and logs"),
    PPO_GROUP,
)
#: The group of each A3C setting (the network settings are all in "network").
A3C_GROUPS: dict[str, tuple[str, ...]] = {
    "network": NetworkSettings.field_names(),
    "environment": (
        "task",
        "max_episode_steps",
        "randomize",
        "num_mazes",
        "start_maze",
        "off_path_rule",
        "fail_reward",
    ),
    "optimisation": (
        "steps",
        "workers",
        "envs_per_worker",
        "n_steps",
        "gamma",
        "gae_lambda",
        "lr",
        "optimizer",
        "rmsprop_alpha",
        "optimizer_eps",
        "entropy_coef",
        "value_coef",
        "max_grad_norm",
        "entropy_target",
        "entropy_target_steps",
        "aux_coef",
        "augment_shift",
        "seed",
    ),
    "fine-tuning": (
        "finetune",
        "critic_warmup_steps",
        "actor_ramp_steps",
        "kl_coef",
        "kl_decay_steps",
        "kl_temperature",
        "advantage_norm",
        "bc_coef",
        "bc_decay_steps",
    ),
    "curriculum": ("start_curriculum", "curriculum_threshold", "expert_data"),
    "logging": ("checkpoint_every", "eval_every", "eval_episodes", "log_every"),
}
#: Parsers of the A3C settings that need more than a number (step counts such as ``5M``, bounded ones).
_A3C_TYPES = {
    "steps": step_count,
    "checkpoint_every": step_count,
    "eval_every": step_count_or_zero,
    "log_every": step_count,
    "max_episode_steps": step_count,
    "seed": seed,
    "eval_episodes": episode_count,
    "fail_reward": finite_float,
}


def add_train_arguments(parser: argparse.ArgumentParser) -> None:
    """``bimgame train``: every :class:`~bimgame.learn.a3c.A3CConfig` setting as a flag (defaults of None,
    so that ``--resume`` keeps what is not given), the reward shaping and the run's options, in the
    groups of :data:`TRAIN_GROUPS`."""
    groups = add_flag_groups(parser, TRAIN_GROUPS)
    run = groups["run"].add_argument
    run("--run-dir", type=Path, required=True, help="directory for config, checkpoints and logs")
    run(
        "--resume",
        action="store_true",
        help="continue the run in --run-dir from its last checkpoint (settings come from its config.json)",
    )
    run("--init", type=Path, default=None, help="start from these weights (checkpoint file or run directory)")
    run("--algo", choices=ALGOS, default="a3c", help="the learner: a3c (the paper's) or ppo (default a3c)")
    flat_defaults = SimpleNamespace(**A3CConfig().to_dict())  # an absent part's flat values included
    for cls, names in A3CConfig.name_groups():
        add_grouped_settings_flags(
            parser,
            groups,
            cls,
            names,
            A3C_GROUPS,
            defaults=flat_defaults,
            default_none=True,
            types=_A3C_TYPES,
            helps={"steps": "environment steps to train for, all workers together, e.g. 5M"},
            # the tasks are the maze's and the labyrinth's
            choices={"task": TASK_NAMES, "off_path_rule": LABYRINTH_OFF_PATH_RULES},
        )
    docs = field_docs(RewardSettings)
    reward = groups["environment"].add_argument
    reward("--value-reward", type=Path, default=None, metavar="RUN", help=plain(docs["value_reward"]))
    reward(
        "--geodesic-reward",
        dest="geodesic_coef",
        type=positive_float,
        nargs="?",
        const=DEFAULT_GEODESIC_COEF,
        default=None,
        metavar="COEF",
        help=f"{plain(docs['geodesic_coef'])} (COEF default {DEFAULT_GEODESIC_COEF:g})",
    )
    groups["logging"].add_argument("--no-progress", action="store_true", help="no progress bar")
    add_ppo_arguments(parser, groups)


def run_train(args: argparse.Namespace) -> int:
    if args.resume and args.init is not None:
        raise ValueError(
            f"--init {args.init} with --resume: a resumed run continues from its own checkpoint "
            f"(and keeps the π^s it started from); give --init only to start a new run"
        )
    try:
        result, steps = train_ppo_from_args(args) if args.algo == "ppo" else _train_a3c(args)
    except TrainingError as error:
        print(f"bimgame train: stopped: {error}", file=sys.stderr)
        return 1
    resume = f"bimgame train{' --algo ppo' if args.algo == 'ppo' else ''} --run-dir {args.run_dir} --resume"
    if result.stopped == "interrupted" and result.steps >= steps:
        print(
            f"interrupted after all {result.steps:,} steps, before the final evaluation; checkpoint saved. "
            f"Evaluate and write the summary with: {resume}",
            file=sys.stderr,
        )
        return 130
    if result.stopped == "interrupted":
        print(f"interrupted at {result.steps:,} steps; checkpoint saved. Continue with: {resume}", file=sys.stderr)
        return 130
    final = result.final_eval or {}
    print(
        f"done: {result.steps:,} steps in {result.seconds / 60:.1f} min; final evaluation: greedy success "
        f"{final.get('greedy_success_rate', float('nan')):.0%}, sampled success "
        f"{final.get('sampled_success_rate', float('nan')):.0%}"
    )
    return 0


def _train_a3c(args: argparse.Namespace) -> tuple[TrainResult, int]:
    """Resolve the A3C settings and reward shaping from the flags given and train; returns the run's
    outcome and its step budget."""
    refuse_ppo_only_flags(args)
    config = resolve_config(
        given_settings(args, A3CConfig, A3CConfig.flat_names()), args.run_dir, resume=args.resume, init=args.init
    )
    reward, wrapper = run_reward(
        given_reward(args),
        args.run_dir,
        resume=args.resume,
        task=config.task,
        obs=config.network.obs,
        gamma=config.optimization.gamma,
    )
    schedule = config.schedule
    announce("A3C", config, args, f"{schedule.workers} workers x {schedule.envs_per_worker} envs", reward)
    result = train(
        config,
        args.run_dir,
        resume=args.resume,
        init=args.init,
        progress=not args.no_progress,
        env_wrapper=wrapper,
        extra_config={"reward": reward.to_dict()},
    )
    return result, schedule.steps


def add_evaluate_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", type=Path, help="a training run directory (or checkpoint file inside one)")
    parser.add_argument("--episodes", type=episode_count, default=50, help="episodes, run side by side (default 50)")
    parser.add_argument("--seed", type=seed, default=12345, help="start positions (default 12345)")
    parser.add_argument("--sample", action="store_true", help="sample actions instead of the greedy action")
    parser.add_argument("--task", type=str.upper, default=None, help="evaluate on another task (default: the run's)")
    parser.add_argument("--gif", type=Path, default=None, help="also write one episode as a GIF")
    parser.add_argument("--out", type=Path, default=None, help="write the results as JSON here")


def run_evaluate(args: argparse.Namespace) -> int:
    check_output_file(args.out, "--out", "eval.json")  # before the evaluation, not after it
    check_output_file(args.gif, "--gif", "episode.gif")
    if args.task is not None:
        puzzle(args.task)
    net, run, step = load_run_network(args.run_dir)
    run_dir = run.run_dir
    task = puzzle(args.task or run.task).task
    if puzzle(task).family != puzzle(run.task).family:
        raise ValueError(
            f"--task {task}: {run_dir} was trained on {run.task} (the {puzzle(run.task).family}); its network "
            f"reads that puzzle's observations, not the {puzzle(task).family}'s"
        )
    limit = run.time_limit if task == run.task else None
    obs_mode = run.network.obs
    result = evaluate_network(
        net,
        task=task,
        obs_mode=obs_mode,
        episodes=args.episodes,
        seed=args.seed,
        greedy=not args.sample,
        max_episode_steps=limit,
    )
    mode = "sampled" if args.sample else "greedy"
    table = Table(title=f"{run_dir} at {step:,} steps: {mode} policy on {task} (seed {args.seed})")
    for column in ("episodes", "success", "mean length", "mean return"):
        table.add_column(column, justify="right")
    table.add_row(
        str(args.episodes), f"{result.success_rate:.0%}", f"{result.mean_length:.1f}", f"{result.mean_return:.2f}"
    )
    console = Console()
    console.print(table)
    if args.out is not None:
        write_json(
            args.out,
            {
                "run_dir": str(run_dir),
                "step": step,
                "task": task,
                "mode": mode,
                "seed": args.seed,
                **result.summary(),
                "lengths": result.lengths,
                "successes": result.successes,
            },
        )
        console.print(f"wrote {args.out}")
    if args.gif is not None:
        shown = evaluate_network(
            net,
            task=task,
            obs_mode=obs_mode,
            episodes=1,
            seed=args.seed,
            greedy=not args.sample,
            max_episode_steps=limit,
            record=True,
        )
        console.print(
            f"wrote {write_gif(shown.frames, args.gif)} ({len(shown.frames)} frames, "
            f"{'solved' if shown.successes[0] else 'not solved'})"
        )
    return 0
