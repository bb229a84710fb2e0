"""Command-line verbs for learning agents: ``bimgame train`` (A3C) and ``bimgame evaluate``."""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import sys
from pathlib import Path

from bimgame.cli.argtypes import non_negative_float, positive_float, positive_int

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


def step_count_or_zero(text: str) -> int:
    """:func:`step_count`, or 0 (e.g. ``--eval-every 0``: never)."""
    return 0 if text.strip() == "0" else step_count(text)


def add_train_arguments(parser: argparse.ArgumentParser) -> None:
    from bimgame.learn.a3c import OPTIMIZERS, A3CConfig
    from bimgame.envs.observe import OBS_MODES
    from bimgame.sim.tasks import Task

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
    add("--lr", type=positive_float, default=None, help=f"learning rate (default {d.lr})")
    add("--optimizer", choices=OPTIMIZERS, default=None, help=f"shared optimiser (default {d.optimizer})")
    add("--gamma", type=non_negative_float, default=None, help=f"discount (default {d.gamma})")
    add("--gae-lambda", type=non_negative_float, default=None, help=f"GAE lambda; 1 = n-step returns (default {d.gae_lambda})")
    add("--entropy-coef", type=non_negative_float, default=None, help=f"(default {d.entropy_coef})")
    add("--value-coef", type=non_negative_float, default=None, help=f"(default {d.value_coef})")
    add("--max-grad-norm", type=positive_float, default=None, help=f"(default {d.max_grad_norm})")
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
    add("--eval-every", type=step_count_or_zero, default=None,
        help=f"steps between evaluations, 0 = none (default {d.eval_every:,})")
    add("--eval-episodes", type=positive_int, default=None, help=f"(default {d.eval_episodes})")
    add("--value-reward", type=Path, default=None, metavar="RUN",
        help="shape the reward with the frozen value function V̂ of RUN (bimgame pretrain --value-only): "
             "r + gamma V̂(s') - V̂(s)")
    add("--geodesic-reward", type=positive_float, nargs="?", const=10.0, default=None, metavar="COEF",
        help="add COEF x geodesic progress towards the centre (per metre; default 10) to the reward")


#: Settings that shape the network; ``--init RUN`` takes them from RUN unless given.
NETWORK_SETTINGS = ("obs", "hidden", "features", "tilt_input", "keypoints", "subtract_background")


def init_network_settings(source: Path) -> dict:
    """The network settings of the run ``--init`` points at ({} for a bare checkpoint file)."""
    from bimgame.learn.runs import CONFIG, KIND_VALUE, run_kind

    run_dir = source.parent if source.is_file() else source
    if not source.exists():
        raise ValueError(f"--init: {source} does not exist")
    if not (run_dir / CONFIG).is_file():
        return {}
    stored = json.loads((run_dir / CONFIG).read_text())
    if run_kind(run_dir) == KIND_VALUE:
        raise ValueError(f"--init: {source} holds a value function (V̂); pass it to --value-reward. --init takes "
                         f"a pre-trained policy (bimgame pretrain) or an A3C run")
    return {k: stored["a3c"][k] for k in NETWORK_SETTINGS if k in stored.get("a3c", {})}


def a3c_config_from(args: argparse.Namespace) -> "A3CConfig":  # noqa: F821
    """The run's settings: the defaults (or, with --resume, the run's stored settings) overridden by
    the flags given."""
    from bimgame.learn.a3c import A3CConfig
    from bimgame.learn.runs import CONFIG

    names = [f.name for f in dataclasses.fields(A3CConfig)]
    given = {name: getattr(args, name) for name in names if getattr(args, name, None) is not None}
    if args.resume:
        path = args.run_dir / CONFIG
        if not path.is_file():
            raise ValueError(f"--resume: no {CONFIG} in {args.run_dir}; start a new run without --resume")
        stored = json.loads(path.read_text())["a3c"]
        return A3CConfig.from_dict({**stored, **given})
    if args.init is not None:
        given = {**init_network_settings(args.init), **given}
    return A3CConfig(**given)


def reward_settings_from(args: argparse.Namespace) -> dict:
    """How the training reward is shaped: ``value_reward`` (a V̂ run) and ``geodesic_coef``; a resumed
    run keeps its own."""
    from bimgame.learn.runs import CONFIG

    settings = {"value_reward": None if args.value_reward is None else str(args.value_reward),
                "geodesic_coef": args.geodesic_reward}
    if args.resume:
        stored = json.loads((args.run_dir / CONFIG).read_text()).get("reward", {"value_reward": None,
                                                                               "geodesic_coef": None})
        changed = [k for k, v in settings.items() if v is not None and v != stored.get(k)]
        if changed:
            raise ValueError(f"--resume must keep the run's reward; it was {stored}, got {settings}")
        return stored
    return settings


def env_wrapper_for(settings: dict, config) -> object | None:
    """The picklable env wrapper for the reward settings (None: the task's reward)."""
    from bimgame.envs.shaping import Chain, GeodesicReward, ValueReward

    wrappers: list = []
    if settings.get("geodesic_coef") is not None:
        wrappers.append(GeodesicReward(settings["geodesic_coef"]))
    if settings.get("value_reward") is not None:
        from bimgame.learn.pretrain import load_value_network

        _, value_config = load_value_network(settings["value_reward"])
        if value_config.obs != config.obs:
            raise ValueError(f"--value-reward {settings['value_reward']}: V̂ was trained on {value_config.obs} "
                             f"observations, this run uses {config.obs}")
        wrappers.append(ValueReward(settings["value_reward"], gamma=config.gamma))
    return Chain(tuple(wrappers)) if wrappers else None


def run_train(args: argparse.Namespace) -> int:
    from bimgame.learn.a3c import TrainingError, train

    config = a3c_config_from(args)
    reward = reward_settings_from(args)
    wrapper = env_wrapper_for(reward, config)
    shaped = ", ".join(f"{k}={v}" for k, v in reward.items() if v is not None)
    print(f"A3C on {config.task} ({config.obs}): {config.steps:,} steps, {config.workers} workers x "
          f"{config.envs_per_worker} envs{', reward shaped: ' + shaped if shaped else ''}"
          f"{', from ' + str(args.init) if args.init else ''} -> {args.run_dir}", file=sys.stderr)
    try:
        result = train(config, args.run_dir, resume=args.resume, init=args.init, progress=not args.no_progress,
                       env_wrapper=wrapper, extra_config={"reward": reward})
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

    from bimgame.learn.a3c import load_run_network
    from bimgame.learn.actor import evaluate_network
    from bimgame.cli.main import write_gif
    from bimgame.learn.runs import write_json
    from bimgame.sim.tasks import parse_task

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
