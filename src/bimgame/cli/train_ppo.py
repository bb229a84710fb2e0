"""``bimgame train --algo ppo``: PPO's own flags (a help group of their own) and the run. The flags PPO
shares with A3C (``--lr``, ``--n-steps``, ``--gamma``, the network, the schedule) are ``train``'s; a
setting not given takes PPO's default, and an A3C-only flag is refused by name."""

from __future__ import annotations

import argparse
import sys
from types import SimpleNamespace
from typing import Any

from bimgame.cli.flags import add_grouped_settings_flags, given_settings
from bimgame.learn.a3c import A3CConfig
from bimgame.learn.ppo import PPOConfig, PPOFinetuneSettings, PPOOptimizationSettings, resolve_ppo_config, train_ppo
from bimgame.learn.rewards import RewardSettings
from bimgame.learn.run_dir import TrainResult

__all__ = ["PPO_GROUP", "add_ppo_arguments", "announce", "given_reward", "refuse_ppo_only_flags", "train_ppo_from_args"]

_DEFAULTS = PPOOptimizationSettings()
#: The help group of PPO's own settings: (title, description), the shared defaults read from the class.
PPO_GROUP = (
    "PPO (--algo ppo)",
    (
        f"PPO's own settings; the shared flags above take PPO's defaults with --algo ppo (lr {_DEFAULTS.lr:g}, "
        f"n-steps {_DEFAULTS.n_steps}, gae-lambda {_DEFAULTS.gae_lambda:g}; one process: --workers 1; "
        f"--workers N: N processes averaging their gradients)"
    ),
)


def add_ppo_arguments(parser: argparse.ArgumentParser, groups: dict[str, argparse._ArgumentGroup]) -> None:
    """PPO's own settings as flags (defaults of None: ``--resume`` keeps what is not given)."""
    title = PPO_GROUP[0]  # the group is one of train's (TRAIN_GROUPS)
    shared = set(A3CConfig.flat_names())
    own = [name for name in PPOConfig.flat_names() if name not in shared]
    for owner in (PPOConfig, PPOOptimizationSettings, PPOFinetuneSettings):  # top level (device), then its parts'
        add_grouped_settings_flags(
            parser,
            groups,
            owner,
            [name for name in own if name in owner.__dataclass_fields__],
            {title: tuple(own)},
            defaults=SimpleNamespace(**PPOConfig().to_dict()),
            default_none=True,
        )


def refuse_ppo_only_flags(args: argparse.Namespace) -> None:
    """Raise ``ValueError`` naming PPO's own flags given to an A3C run (``--clip``, ``--policy-lag`` …):
    A3C would otherwise train without them, as if they had not been given."""
    shared = set(A3CConfig.flat_names())
    given = [name for name in PPOConfig.flat_names() if name not in shared and getattr(args, name, None) is not None]
    if given:
        flags = ", ".join("--" + name.replace("_", "-") for name in given)
        raise ValueError(f"{flags}: PPO's own settings; add --algo ppo, or leave them out for A3C")


def announce(learner: str, config: Any, args: argparse.Namespace, envs: str, reward: RewardSettings) -> None:
    """The line ``bimgame train`` prints as a run starts, either learner's: task, observations, steps,
    ``envs``, the reward's shaping and the weights it starts from."""
    shaped = reward.describe()
    print(
        f"{learner} on {config.task} ({config.network.obs}): {config.schedule.steps:,} steps, {envs}"
        f"{', reward shaped: ' + shaped if shaped else ''}{', from ' + str(args.init) if args.init else ''} "
        f"-> {args.run_dir}",
        file=sys.stderr,
    )


def given_reward(args: argparse.Namespace) -> RewardSettings:
    """The reward shaping the flags ask for (``--value-reward``, ``--geodesic-reward``), either learner's."""
    return RewardSettings(value_reward=args.value_reward, geodesic_coef=args.geodesic_coef)


def train_ppo_from_args(args: argparse.Namespace) -> tuple[TrainResult, int]:
    """Resolve the PPO settings from the flags given and train; returns the run's outcome and its step
    budget (``bimgame train`` reports both learners' outcomes alike). Raises
    :class:`~bimgame.learn.run_dir.TrainingError` when training fails."""
    # Every settings flag given, A3C's too: an A3C-only one is refused by PPOConfig, naming it.
    given = given_settings(args, PPOConfig, sorted(set(A3CConfig.flat_names()) | set(PPOConfig.flat_names())))
    config = resolve_ppo_config(given, args.run_dir, resume=args.resume, init=args.init)
    reward = given_reward(args)
    announce("PPO", config, args, f"{config.schedule.envs_per_worker} envs", reward)
    result = train_ppo(
        config, args.run_dir, resume=args.resume, init=args.init, progress=not args.no_progress, reward=reward
    )
    return result, config.schedule.steps
