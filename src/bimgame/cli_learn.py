"""``bimgame pretrain`` and ``bimgame dagger``: learning from the expert's trajectories."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

from bimgame.argtypes import non_negative_float, non_negative_int, positive_float, positive_int

__all__ = ["add_pretrain_arguments", "run_pretrain"]


def add_pretrain_arguments(parser: argparse.ArgumentParser) -> None:
    from bimgame.observe import OBS_MODES
    from bimgame.pretrain import PretrainConfig
    from bimgame.tasks import Task

    d = PretrainConfig()
    add = parser.add_argument
    add("--data", type=Path, required=True, help="an expert dataset directory (bimgame generate)")
    add("--out", type=Path, required=True, help="new run directory for the weights and logs")
    add("--task", choices=[t.value for t in Task], type=str.upper, default=d.task,
        help=f"task whose rewards give the value targets; the dataset's episodes are relabelled (default {d.task})")
    add("--obs", choices=OBS_MODES, default=d.obs, help=f"observations (default {d.obs})")
    add("--value-only", action="store_true",
        help="train the value-only network V̂ for --value-reward instead of the policy π^s")
    add("--epochs", type=positive_int, default=d.epochs, help=f"at most this many epochs (default {d.epochs})")
    add("--patience", type=positive_int, default=d.patience,
        help=f"stop after this many epochs without a better held-out loss (default {d.patience})")
    add("--lr", type=positive_float, default=d.lr, help=f"Adam learning rate (default {d.lr})")
    add("--l2", type=non_negative_float, default=d.l2, help=f"L2 penalty on the weights (default {d.l2})")
    add("--value-coef", type=non_negative_float, default=d.value_coef, help=f"(default {d.value_coef})")
    add("--gamma", type=non_negative_float, default=d.gamma, help=f"discount of the returns (default {d.gamma})")
    add("--val-fraction", type=positive_float, default=d.val_fraction,
        help=f"share of episodes held out (default {d.val_fraction})")
    add("--bptt", type=positive_int, default=d.bptt, help=f"steps per backpropagation chunk (default {d.bptt})")
    add("--hidden", type=positive_int, default=None, help="LSTM size (default 256 pixels, 128 state)")
    add("--features", type=positive_int, default=None, help="encoder output size (default 256 pixels, 128 state)")
    add("--no-tilt-input", dest="tilt_input", action="store_false", help="do not feed the board tilt")
    add("--keypoints", action="store_true", help="pixels: spatial soft-argmax keypoints")
    add("--subtract-background", action="store_true", help="pixels: subtract the empty-maze frame")
    add("--eval-episodes", type=non_negative_int, default=d.eval_episodes,
        help=f"episodes to measure π^s as a policy afterwards, 0 = skip (default {d.eval_episodes})")
    add("--seed", type=int, default=d.seed, help=f"(default {d.seed})")
    add("--no-progress", action="store_true", help="no progress bar")


def pretrain_config_from(args: argparse.Namespace):
    from bimgame.pretrain import PretrainConfig

    values = {f.name: getattr(args, f.name) for f in dataclasses.fields(PretrainConfig) if hasattr(args, f.name)}
    values["target"] = "value" if args.value_only else "policy"
    return PretrainConfig(**values)


def run_pretrain(args: argparse.Namespace) -> int:
    from bimgame.pretrain import pretrain

    config = pretrain_config_from(args)
    what = "value function V̂" if config.target == "value" else "policy π^s"
    print(f"pre-training the {what} on {args.data} ({config.task}, {config.obs}) -> {args.out}", file=sys.stderr)
    result = pretrain(config, args.data, args.out, progress=not args.no_progress)
    accuracy = "" if math.isnan(result.val_accuracy) else f"held-out accuracy {result.val_accuracy:.1%} (chance 20%), "
    print(f"done in {result.seconds:.0f} s: best epoch {result.best_epoch} of {result.epochs_run}, {accuracy}"
          f"value RMSE {result.val_value_rmse:.3f}")
    if result.policy_eval:
        e = result.policy_eval
        print(f"π^s alone on {config.task}: greedy success {e['greedy_success_rate']:.0%} "
              f"(mean length {e['greedy_mean_length']:.0f}), sampled success {e['sampled_success_rate']:.0%} "
              f"over {e['episodes']} episodes")
    use = "--value-reward" if config.target == "value" else "--init"
    print(f"use it with: bimgame train --task {config.task} --obs {config.obs} {use} {args.out} --run-dir RUN")
    return 0
