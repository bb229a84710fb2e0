"""``bimgame pretrain`` and ``bimgame dagger``: learning from the expert's trajectories."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

from bimgame.cli.argtypes import non_negative_float, non_negative_int, positive_float, positive_int

__all__ = ["add_pretrain_arguments", "run_pretrain", "add_dagger_arguments", "run_dagger"]


def add_pretrain_arguments(parser: argparse.ArgumentParser) -> None:
    from bimgame.envs.observe import OBS_MODES
    from bimgame.learn.pretrain import PretrainConfig
    from bimgame.sim.tasks import Task

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
    add("--batch-episodes", type=positive_int, default=d.batch_episodes,
        help=f"policy: episodes per batch (default {d.batch_episodes})")
    add("--batch-frames", type=positive_int, default=d.batch_frames,
        help=f"value: frames per batch (default {d.batch_frames})")
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
    from bimgame.learn.pretrain import PretrainConfig

    values = {f.name: getattr(args, f.name) for f in dataclasses.fields(PretrainConfig) if hasattr(args, f.name)}
    values["target"] = "value" if args.value_only else "policy"
    return PretrainConfig(**values)


def run_pretrain(args: argparse.Namespace) -> int:
    from bimgame.learn.pretrain import pretrain

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


def add_dagger_arguments(parser: argparse.ArgumentParser) -> None:
    from bimgame.learn.dagger import DAggerConfig
    from bimgame.envs.observe import OBS_MODES
    from bimgame.sim.tasks import Task

    d = DAggerConfig()
    add = parser.add_argument
    add("--run-dir", type=Path, required=True, help="directory for the weights, aggregated data and logs")
    add("--resume", action="store_true", help="continue after the run's last finished iteration")
    add("--init", type=Path, default=None, help="start the learner from these weights (e.g. bimgame pretrain's)")
    add("--task", choices=[t.value for t in Task], type=str.upper, default="STG1", help="(default STG1)")
    add("--obs", choices=OBS_MODES, default=d.learner.obs, help=f"observations (default {d.learner.obs})")
    add("--iterations", type=positive_int, default=None,
        help=f"(default {d.iterations}; with --resume, a larger number continues the run)")
    add("--episodes-per-iteration", type=positive_int, default=d.episodes_per_iteration,
        help=f"learner rollouts per iteration (default {d.episodes_per_iteration})")
    add("--beta0", type=non_negative_float, default=d.beta0,
        help=f"probability of executing the expert's action at iteration 0 (default {d.beta0})")
    add("--beta-decay", type=non_negative_float, default=d.beta_decay,
        help=f"beta_i = beta0 * beta_decay^i (default {d.beta_decay})")
    add("--epochs-per-iteration", type=positive_int, default=d.epochs_per_iteration,
        help=f"passes over the aggregated data per iteration (default {d.epochs_per_iteration})")
    add("--lr", type=positive_float, default=d.learner.lr, help=f"Adam learning rate (default {d.learner.lr})")
    add("--hidden", type=positive_int, default=None, help="LSTM size (default 256 pixels, 128 state)")
    add("--features", type=positive_int, default=None, help="encoder output size (default 256 pixels, 128 state)")
    add("--subtract-background", action="store_true", help="pixels: subtract the empty-maze frame")
    add("--eval-episodes", type=non_negative_int, default=None,
        help=f"greedy and sampled evaluation episodes per iteration (default {d.eval_episodes})")
    add("--seed", type=int, default=0, help="(default 0)")
    add("--no-progress", action="store_true", help="no progress bar")


def run_dagger(args: argparse.Namespace) -> int:
    from bimgame.learn.dagger import DAggerConfig, dagger
    from bimgame.learn.pretrain import PretrainConfig

    if args.resume:
        # The run's own settings; only the number of iterations and evaluation episodes may change.
        from bimgame.learn.runs import CONFIG

        path = args.run_dir / CONFIG
        if not path.is_file():
            raise ValueError(f"--resume: no {CONFIG} in {args.run_dir}; start a new run without --resume")
        stored = DAggerConfig.from_dict(json.loads(path.read_text())["dagger"])
        given = {k: getattr(args, k) for k in DAggerConfig.RESUMABLE_CHANGES if getattr(args, k) is not None}
        config = dataclasses.replace(stored, **given)
    else:
        learner = PretrainConfig(task=args.task, obs=args.obs, lr=args.lr, hidden=args.hidden,
                                 features=args.features, subtract_background=args.subtract_background, seed=args.seed)
        defaults = DAggerConfig()
        config = DAggerConfig(learner=learner, iterations=args.iterations or defaults.iterations,
                              episodes_per_iteration=args.episodes_per_iteration, beta0=args.beta0,
                              beta_decay=args.beta_decay, epochs_per_iteration=args.epochs_per_iteration,
                              eval_episodes=defaults.eval_episodes if args.eval_episodes is None else args.eval_episodes)
    print(f"DAgger on {config.learner.task} ({config.learner.obs}): {config.iterations} iterations x "
          f"{config.episodes_per_iteration} episodes -> {args.run_dir}", file=sys.stderr)
    result = dagger(config, args.run_dir, resume=args.resume, init=args.init, progress=not args.no_progress)
    if result.final_eval is None:
        print(f"nothing to do: the run in {args.run_dir} has finished its {result.iterations} iterations "
              f"(pass a larger --iterations with --resume to continue)")
        return 0
    final = result.final_eval
    print(f"done: {result.iterations} iterations in {result.seconds / 60:.1f} min; {result.env_steps:,} environment "
          f"steps, {result.expert_sim_steps:,} simulator steps of expert planning; final greedy success "
          f"{final.get('greedy_success_rate', float('nan')):.0%}, sampled {final.get('sampled_success_rate', float('nan')):.0%}")
    return 0
