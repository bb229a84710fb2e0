"""Command-line verbs for learning agents: ``bimgame train`` (A3C) and ``bimgame evaluate``."""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import sys
from pathlib import Path

from bimgame.argtypes import non_negative_int, positive_int

__all__ = ["add_train_arguments", "add_evaluate_arguments", "run_train", "run_evaluate", "step_count",
           "a3c_config_from"]

_SUFFIXES = {"": 1, "k": 1_000, "m": 1_000_000, "g": 1_000_000_000}


def step_count(text: str) -> int:
    """A number of environment steps: ``300000``, ``200k``, ``5M``, ``2.5M``, ``1e6``."""
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:e[0-9]+)?)\s*([kKmMgG]?)\s*", text)
    if not match:
        raise argparse.ArgumentTypeError(f"expected a step count such as 300000, 200k, 5M or 1e6, got {text!r}")
    value = float(match.group(1)) * _SUFFIXES[match.group(2).lower()]
    if value < 1 or value != int(value):
        raise argparse.ArgumentTypeError(f"expected a positive whole number of steps, got {text!r}")
    return int(value)


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text!r}")
    return value


def _non_negative_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}") from None
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text!r}")
    return value


def add_train_arguments(parser: argparse.ArgumentParser) -> None:
    from bimgame.a3c import OPTIMIZERS, A3CConfig
    from bimgame.observe import OBS_MODES
    from bimgame.tasks import Task

    d = A3CConfig()
    add = parser.add_argument
    add("--run-dir", type=Path, required=True, help="directory for config, checkpoints and logs")
    add("--resume", action="store_true", help="continue the run in --run-dir from its last checkpoint "
                                              "(settings come from its config.json)")
    add("--init", type=Path, default=None, help="start from these weights (checkpoint file or run directory)")
    add("--no-progress", action="store_true", help="no progress bar")
    # Settings default to None so that --resume can tell what was given explicitly.
    add("--task", choices=[t.value for t in Task], type=str.upper, default=None, help=f"(default {d.task})")
    add("--obs", choices=OBS_MODES, default=None, help=f"observations (default {d.obs})")
    add("--steps", type=step_count, default=None, help="environment steps, e.g. 5M (default 5M)")
    add("--workers", type=positive_int, default=None, help=f"worker processes (default {d.workers})")
    add("--envs-per-worker", type=positive_int, default=None,
        help=f"environments per worker, one batched forward pass (default {d.envs_per_worker}; 1 = paper's A3C)")
    add("--n-steps", type=positive_int, default=None, help=f"steps per update, t_max (default {d.n_steps})")
    add("--lr", type=_positive_float, default=None, help=f"learning rate (default {d.lr})")
    add("--optimizer", choices=OPTIMIZERS, default=None, help=f"shared optimiser (default {d.optimizer})")
    add("--gamma", type=_non_negative_float, default=None, help=f"discount (default {d.gamma})")
    add("--gae-lambda", type=_non_negative_float, default=None, help=f"GAE lambda; 1 = n-step returns (default {d.gae_lambda})")
    add("--entropy-coef", type=_non_negative_float, default=None, help=f"(default {d.entropy_coef})")
    add("--value-coef", type=_non_negative_float, default=None, help=f"(default {d.value_coef})")
    add("--max-grad-norm", type=_positive_float, default=None, help=f"(default {d.max_grad_norm})")
    add("--hidden", type=positive_int, default=None, help="LSTM size (default 256 pixels, 128 state)")
    add("--features", type=positive_int, default=None, help="encoder output size (default 256 pixels, 128 state)")
    add("--no-tilt-input", dest="tilt_input", action="store_const", const=False, default=None,
        help="do not feed the board tilt to the LSTM (the paper's exact inputs)")
    add("--keypoints", action="store_const", const=True, default=None,
        help="pixels: add spatial soft-argmax keypoints to the conv encoder")
    add("--subtract-background", action="store_const", const=True, default=None,
        help="pixels: subtract the empty-maze frame before the convolutions")
    add("--max-episode-steps", type=positive_int, default=None, help="time limit (default: the task's)")
    add("--seed", type=int, default=None, help=f"(default {d.seed})")
    add("--checkpoint-every", type=step_count, default=None, help=f"steps between checkpoints (default {d.checkpoint_every:,})")
    add("--eval-every", type=non_negative_int, default=None,
        help=f"steps between evaluations, 0 = none (default {d.eval_every:,})")
    add("--eval-episodes", type=positive_int, default=None, help=f"(default {d.eval_episodes})")


def a3c_config_from(args: argparse.Namespace) -> "A3CConfig":  # noqa: F821
    """The run's settings: the defaults (or, with --resume, the run's stored settings) overridden by
    the flags given."""
    from bimgame.a3c import A3CConfig
    from bimgame.runs import CONFIG

    names = [f.name for f in dataclasses.fields(A3CConfig)]
    given = {name: getattr(args, name) for name in names if getattr(args, name, None) is not None}
    if args.resume:
        path = args.run_dir / CONFIG
        if not path.is_file():
            raise ValueError(f"--resume: no {CONFIG} in {args.run_dir}; start a new run without --resume")
        stored = json.loads(path.read_text())["a3c"]
        return A3CConfig.from_dict({**stored, **given})
    return A3CConfig(**given)


def run_train(args: argparse.Namespace) -> int:
    from bimgame.a3c import TrainingError, train

    config = a3c_config_from(args)
    print(f"A3C on {config.task} ({config.obs}): {config.steps:,} steps, {config.workers} workers x "
          f"{config.envs_per_worker} envs -> {args.run_dir}", file=sys.stderr)
    try:
        result = train(config, args.run_dir, resume=args.resume, init=args.init, progress=not args.no_progress)
    except TrainingError as error:
        print(f"bimgame train: stopped: {error}", file=sys.stderr)
        return 1
    if result.stopped == "interrupted":
        print(f"interrupted at {result.steps:,} steps; checkpoint saved. Continue with: bimgame train "
              f"--run-dir {args.run_dir} --resume", file=sys.stderr)
        return 130
    final = result.final_eval or {}
    print(f"done: {result.steps:,} steps in {result.seconds / 60:.1f} min; final evaluation: greedy success "
          f"{final.get('greedy_success_rate', float('nan')):.0%}, sampled success "
          f"{final.get('sampled_success_rate', float('nan')):.0%}")
    return 0


def add_evaluate_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", type=Path, help="a training run directory (or checkpoint file inside one)")
    parser.add_argument("--episodes", type=positive_int, default=50)
    parser.add_argument("--seed", type=int, default=12345, help="start positions (default 12345)")
    parser.add_argument("--sample", action="store_true", help="sample actions instead of the greedy action")
    parser.add_argument("--task", type=str.upper, default=None, help="evaluate on another task (default: the run's)")
    parser.add_argument("--gif", type=Path, default=None, help="also write one episode as a GIF")
    parser.add_argument("--out", type=Path, default=None, help="write the results as JSON here")


def run_evaluate(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from bimgame.a3c import load_run_network
    from bimgame.agent import evaluate_network
    from bimgame.cli import write_gif
    from bimgame.runs import write_json
    from bimgame.tasks import parse_task

    net, config, step = load_run_network(args.run_dir)
    run_dir = args.run_dir.parent if args.run_dir.is_file() else args.run_dir
    task = parse_task(args.task or config.task).value
    limit = config.max_episode_steps if task == config.task else None
    obs_mode = config.obs
    result = evaluate_network(net, task=task, obs_mode=obs_mode, episodes=args.episodes, seed=args.seed,
                              greedy=not args.sample, max_episode_steps=limit)
    mode = "sampled" if args.sample else "greedy"
    table = Table(title=f"{run_dir} at {step:,} steps: {mode} policy on {task} (seed {args.seed})")
    for column in ("episodes", "success", "mean length", "mean return"):
        table.add_column(column, justify="right")
    table.add_row(str(args.episodes), f"{result.success_rate:.0%}", f"{result.mean_length:.1f}",
                  f"{result.mean_return:.2f}")
    console = Console()
    console.print(table)
    if args.out is not None:
        write_json(args.out, {"run_dir": str(run_dir), "step": step, "task": task, "mode": mode, "seed": args.seed,
                              **result.summary(), "lengths": result.lengths, "successes": result.successes})
        console.print(f"wrote {args.out}")
    if args.gif is not None:
        shown = evaluate_network(net, task=task, obs_mode=obs_mode, episodes=1, seed=args.seed,
                                 greedy=not args.sample, max_episode_steps=limit, record=True)
        console.print(f"wrote {write_gif(shown.frames, args.gif)} ({len(shown.frames)} frames, "
                      f"{'solved' if shown.successes[0] else 'not solved'})")
    return 0
