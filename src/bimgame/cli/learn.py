"""``bimgame pretrain`` and ``bimgame dagger``: learning from the expert's trajectories."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from bimgame.cli.argtypes import episode_count, episode_count_or_zero, non_negative_float, seed
from bimgame.cli.expert import (
    LABYRINTH_ONLY_MPC_FLAGS,
    MPC_FLAGS,
    add_mpc_arguments,
    labyrinth_mpc_config_from,
    mpc_config_from,
    mpc_flag,
)
from bimgame.cli.flags import add_flag_groups, add_grouped_settings_flags, given_settings
from bimgame.envs.labyrinth_env import LABYRINTH_OFF_PATH_RULES, OBSERVATION_EXTRAS
from bimgame.envs.puzzles import TASK_NAMES, puzzle
from bimgame.expert.datasets import dataset_manifest
from bimgame.expert.labyrinth_mpc import LabyrinthMPCConfig
from bimgame.expert.mpc import MPCConfig
from bimgame.learn.common import NetworkSettings
from bimgame.learn.dagger import BEST, DAggerConfig, dagger, resolve_dagger_config
from bimgame.learn.learner_settings import puzzle_defaults
from bimgame.learn.pretrain import dataset_action_type, pretrain
from bimgame.learn.supervised import PretrainConfig
from bimgame.util.files import FileWriteError

__all__ = [
    "add_pretrain_arguments",
    "run_pretrain",
    "add_dagger_arguments",
    "run_dagger",
    "INIT_NETWORK_FLAGS",
    "init_network_flags",
    "PRETRAIN_GROUPS",
    "PRETRAIN_PLACEMENT",
    "DAGGER_GROUPS",
    "DAGGER_PLACEMENT",
]


#: Pre-training settings with a flag of their own; ``target`` is ``--value-only``.
PRETRAIN_FLAGS = (
    "task",
    "obs",
    "action_type",
    "epochs",
    "patience",
    "lr",
    "l2",
    "value_coef",
    "gamma",
    "val_fraction",
    "bptt",
    "batch_episodes",
    "batch_frames",
    "max_grad_norm",
    "hidden",
    "features",
    "tilt_input",
    "keypoints",
    "subtract_background",
    "aux_heads",
    "asymmetric_critic",
    "precision",
    "gate_bearings",
    "surroundings",
    "motion",
    "aux_coef",
    "eval_episodes",
    "seed",
)
#: The learner settings of DAgger with a flag (the rest keep the defaults of DAgger's learner).
DAGGER_LEARNER_FLAGS = (
    "task",
    "obs",
    "action_type",
    "lr",
    "hidden",
    "features",
    "tilt_input",
    "keypoints",
    "subtract_background",
    "precision",
    "gate_bearings",
    "surroundings",
    "motion",
    "aux_heads",
    "seed",
)
#: DAgger's own settings with a flag (``expert`` is the default MPC expert).
DAGGER_FLAGS = (
    "expert_data",
    "teacher",
    "iterations",
    "episodes_per_iteration",
    "beta0",
    "beta_decay",
    "demo_start_share",
    "demo_start_window",
    "epochs_per_iteration",
    "max_episode_steps",
    "stall_steps",
    "off_path_rule",
    "eval_episodes",
    "num_mazes",
    "start_maze",
)
#: The network settings a run started from π^s must share with it: its weights' shapes, its inputs
#: and the observation's extra parts. ``bimgame pretrain``'s closing hint repeats those given.
INIT_NETWORK_FLAGS = (
    "hidden",
    "features",
    "tilt_input",
    "keypoints",
    "subtract_background",
    "aux_heads",
    "gate_bearings",
    *OBSERVATION_EXTRAS,
)
#: Parsers with an upper bound too (a seed numpy and torch both take; episodes run side by side).
_TYPES = {"seed": seed, "eval_episodes": episode_count_or_zero}
#: ``bimgame pretrain --help``'s groups: (title, description) in the order shown.
PRETRAIN_GROUPS = (
    ("data", "the expert dataset, the new run directory and what is trained"),
    ("network", "the network's observations, sizes and inputs"),
    ("optimisation", "the loss, batches, early stopping and seed"),
    ("logging", "the evaluation after training and the progress bar"),
)
#: The group of each pre-training setting with a flag.
PRETRAIN_PLACEMENT: dict[str, tuple[str, ...]] = {
    "data": ("task",),
    "network": NetworkSettings.field_names(),
    "logging": ("eval_episodes",),
    "optimisation": (
        "epochs",
        "patience",
        "lr",
        "l2",
        "value_coef",
        "gamma",
        "val_fraction",
        "bptt",
        "batch_episodes",
        "batch_frames",
        "max_grad_norm",
        "aux_coef",
        "seed",
    ),
}
#: ``bimgame dagger --help``'s groups: (title, description) in the order shown.
DAGGER_GROUPS = (
    ("run", "the run directory, where the learner starts from and its task"),
    ("network", "the learner's observations, sizes and inputs"),
    ("DAgger", "iterations, rollouts, the expert's share β and the learner's training"),
    ("logging", "evaluations and the progress bar"),
)
#: The group of each DAgger setting with a flag (its own and its learner's).
DAGGER_PLACEMENT: dict[str, tuple[str, ...]] = {
    "run": ("task", "expert_data", "teacher", "num_mazes", "start_maze", "off_path_rule"),
    "network": NetworkSettings.field_names(),
    "logging": ("eval_episodes",),
    "DAgger": (
        "iterations",
        "episodes_per_iteration",
        "beta0",
        "beta_decay",
        "demo_start_share",
        "demo_start_window",
        "epochs_per_iteration",
        "max_episode_steps",
        "stall_steps",
        "lr",
        "seed",
    ),
}


def _add_learner_flags(
    parser: argparse.ArgumentParser,
    groups: dict[str, Any],
    names: tuple[str, ...],
    placement: dict[str, tuple[str, ...]],
) -> None:
    """The flags of the learner's settings ``names`` (a :class:`PretrainConfig`'s), in ``placement``'s
    groups: one not given takes its default for the observations (e.g. sizes), and ``--task`` takes
    the maze's tasks and the labyrinth's."""
    add_grouped_settings_flags(
        parser, groups, PretrainConfig, names, placement, types=_TYPES, default_none=True, choices={"task": TASK_NAMES}
    )


def add_pretrain_arguments(parser: argparse.ArgumentParser) -> None:
    """``bimgame pretrain``: the dataset, the output and the pre-training settings, in the groups of
    :data:`PRETRAIN_GROUPS`."""
    groups = add_flag_groups(parser, PRETRAIN_GROUPS)
    add = groups["data"].add_argument
    add("--data", type=Path, required=True, help="an expert dataset directory (bimgame generate)")
    add("--out", type=Path, required=True, help="new run directory for the weights and logs")
    add(
        "--value-only",
        action="store_true",
        help="train the value-only network V̂ for --value-reward instead of the policy π^s",
    )
    _add_learner_flags(parser, groups, PRETRAIN_FLAGS, PRETRAIN_PLACEMENT)
    groups["logging"].add_argument("--no-progress", action="store_true", help="no progress bar")


def _with_dataset_action_type(values: dict[str, Any], data_dir: Path) -> dict[str, Any]:
    """The learner settings ``values`` given on the command line, with ``action_type`` the dataset's
    in ``data_dir`` when not given (discrete if the dataset cannot be read: the learner names what is
    wrong with it)."""
    if "action_type" in values:
        return values
    try:
        return {**values, "action_type": dataset_action_type(dataset_manifest(data_dir))}
    except (ValueError, OSError):
        return {**values, "action_type": "discrete"}


def pretrain_config_from(args: argparse.Namespace) -> PretrainConfig:
    """The pre-training settings of the flags given; those not given take their defaults for the
    observations (as ``bimgame train``'s: 128 units for state, 256 for pixels), an ``--action-type``
    not given is the dataset's (the maze expert's discrete actions, or a labyrinth dataset's own), and
    the labyrinth's tasks their network defaults (no auxiliary heads)."""
    values = {name: getattr(args, name) for name in PRETRAIN_FLAGS if getattr(args, name) is not None}
    values = puzzle_defaults(_with_dataset_action_type(values, args.data), default_task="FULL")
    return PretrainConfig(**values, target="value" if args.value_only else "policy")


def run_pretrain(args: argparse.Namespace) -> int:
    config = pretrain_config_from(args)
    what = "value function V̂" if config.target == "value" else "policy π^s"
    print(f"pre-training the {what} on {args.data} ({config.task}, {config.obs}) -> {args.out}", file=sys.stderr)
    try:
        result = pretrain(config, args.data, args.out, progress=not args.no_progress)
    except KeyboardInterrupt:
        print(
            f"interrupted; pre-training cannot resume, so nothing was kept in {args.out}. Run the same command "
            f"again to start over",
            file=sys.stderr,
        )
        return 130
    chance = "chance 20%" if config.action_type == "discrete" else "each tilt change within 0.25 of the expert's"
    accuracy = "" if math.isnan(result.val_accuracy) else f"held-out accuracy {result.val_accuracy:.1%} ({chance}), "
    print(
        f"done in {result.seconds:.0f} s: best epoch {result.best_epoch} of {result.epochs_run}, {accuracy}"
        f"value RMSE {result.val_value_rmse:.3f}"
    )
    if result.policy_eval:
        e = result.policy_eval
        where = "" if not result.mazes else f" (the dataset's {result.mazes['num_mazes']} mazes)"
        print(
            f"π^s alone on {config.task}{where}: greedy success {e['greedy_success_rate']:.0%} "
            f"(mean length {e['greedy_mean_length']:.0f}), sampled success {e['sampled_success_rate']:.0%} "
            f"over {e['episodes']} episodes"
        )
    use = "--value-reward" if config.target == "value" else "--init"
    learner = " --algo ppo --action-type continuous" if config.action_type == "continuous" else ""
    print(
        f"use it with: bimgame train{learner} --task {config.task} --obs {config.obs}"
        f"{init_network_flags(args)}{spelled_flags(result.mazes)} {use} "
        f"{args.out} --run-dir RUN"
    )
    return 0


def init_network_flags(args: argparse.Namespace) -> str:
    """The :data:`INIT_NETWORK_FLAGS` given on the command line, spelled as given; those not given
    are left out."""
    return spelled_flags(given_settings(args, NetworkSettings, INIT_NETWORK_FLAGS))


def spelled_flags(values: dict[str, Any]) -> str:
    """Settings as the flags that give them, each after a space: a switch ``--keypoints`` or
    ``--no-tilt-input``, a value ``--hidden 64``."""
    flags = []
    for name, value in values.items():
        flag = name.replace("_", "-")
        if isinstance(value, bool):
            flags.append(f" --{flag}" if value else f" --no-{flag}")
        else:
            flags.append(f" --{flag} {value}")
    return "".join(flags)


def add_dagger_arguments(parser: argparse.ArgumentParser) -> None:
    """``bimgame dagger``: the run's options, the learner's settings and DAgger's own (defaults of
    None for those a resumed run may change, so that what is not given keeps the run's value), in the
    groups of :data:`DAGGER_GROUPS`."""
    groups = add_flag_groups(parser, DAGGER_GROUPS)
    add = groups["run"].add_argument
    add("--run-dir", type=Path, required=True, help="directory for the weights, aggregated data and logs")
    add("--resume", action="store_true", help="continue after the run's last finished iteration")
    add("--init", type=Path, default=None, help="start the learner from these weights (e.g. bimgame pretrain's)")
    _add_learner_flags(parser, groups, DAGGER_LEARNER_FLAGS, DAGGER_PLACEMENT)
    resumable = DAggerConfig.RESUMABLE_CHANGES
    add_grouped_settings_flags(
        parser,
        groups,
        DAggerConfig,
        [n for n in DAGGER_FLAGS if n not in resumable],
        DAGGER_PLACEMENT,
        default_none=True,  # --resume refuses a given setting that differs from the run's, names it
        types={"episodes_per_iteration": episode_count, "demo_start_window": non_negative_float},
        choices={"off_path_rule": LABYRINTH_OFF_PATH_RULES},
    )
    add_grouped_settings_flags(
        parser,
        groups,
        DAggerConfig,
        resumable,
        DAGGER_PLACEMENT,
        default_none=True,
        types=_TYPES,
        helps={"iterations": "Iterations to run; with --resume, a larger number continues the run."},
    )
    groups["logging"].add_argument("--no-progress", action="store_true", help="no progress bar")
    add_mpc_arguments(parser, labyrinth=True)


def dagger_expert_from(
    args: argparse.Namespace, learner: PretrainConfig, given: dict[str, Any]
) -> MPCConfig | LabyrinthMPCConfig | None:
    """The labelling expert's settings of the MPC flags given (``-K``, ``-H``, ``--sampling``,
    ``--planning-reward``; the labyrinth's ``--plans``) over those DAgger picks for the task (on
    random mazes the geodesic reward); None when no MPC flag is given. Refused with ``--resume``: a
    run keeps its expert."""
    mpc_given = given_settings(args, MPCConfig, MPC_FLAGS)
    labyrinth_only = given_settings(args, LabyrinthMPCConfig, LABYRINTH_ONLY_MPC_FLAGS)
    if not (mpc_given or labyrinth_only):
        return None
    flags = ", ".join(map(mpc_flag, sorted({**mpc_given, **labyrinth_only})))
    if args.resume:
        raise ValueError(f"--resume keeps the run's expert; drop the MPC expert's settings given ({flags})")
    if given.get("teacher") is not None:
        raise ValueError(
            f"--teacher labels the rollouts instead of the MPC expert; drop the expert's settings ({flags})"
        )
    args = argparse.Namespace(**{**vars(args), "task": learner.task})
    if puzzle(learner.task).is_maze:
        planner = DAggerConfig(learner=learner, **given).planner
        assert isinstance(planner, MPCConfig)  # the maze's expert
        return mpc_config_from(args, base=planner)
    return labyrinth_mpc_config_from(args)


def given_learner_settings(args: argparse.Namespace) -> dict[str, Any]:
    """The learner's settings given on the command line (DAgger's network flags that are not None)."""
    return {name: getattr(args, name) for name in DAGGER_LEARNER_FLAGS if getattr(args, name) is not None}


def dagger_learner_from(args: argparse.Namespace) -> PretrainConfig:
    """DAgger's learner of the flags given: those not given take their defaults for the observations
    (128 units for state, 256 for pixels) on task STG1 unless ``--task`` says otherwise, with no
    asymmetric critic and auxiliary heads only when asked for (``--aux-heads``: the labyrinth's
    rollouts record the states they learn from); an ``--action-type`` not given is
    ``--expert-data``'s, else discrete."""
    values = given_learner_settings(args)
    if args.expert_data is not None:
        values = _with_dataset_action_type(values, args.expert_data)
    values = {"task": DAggerConfig().learner.task, "aux_heads": False, **values}
    return PretrainConfig(**values, asymmetric_critic=False)


def run_dagger(args: argparse.Namespace) -> int:
    learner = dagger_learner_from(args)
    given = given_settings(args, DAggerConfig, DAGGER_FLAGS)
    expert = dagger_expert_from(args, learner, given)
    if expert is not None:
        given["expert"] = expert
    config = resolve_dagger_config(
        learner, given, args.run_dir, resume=args.resume, learner_given=given_learner_settings(args)
    )
    print(
        f"DAgger on {config.learner.task} ({config.learner.obs}): {config.iterations} iterations x "
        f"{config.episodes_per_iteration} episodes -> {args.run_dir}",
        file=sys.stderr,
    )
    try:
        result = dagger(config, args.run_dir, resume=args.resume, init=args.init, progress=not args.no_progress)
    except KeyboardInterrupt:
        print(
            f"interrupted; the finished iterations are saved. Continue with: bimgame dagger --run-dir "
            f"{args.run_dir} --resume",
            file=sys.stderr,
        )
        return 130
    except FileWriteError as error:
        print(f"bimgame dagger: stopped: {error}", file=sys.stderr)
        return 1
    if result.iterations_run == 0:
        print(
            f"nothing to do: the run in {args.run_dir} has finished its {result.iterations} iterations "
            f"(pass a larger --iterations with --resume to continue)"
        )
        return 0
    final = result.final_eval
    evaluation = (
        "no evaluation (--eval-episodes 0)"
        if final is None
        else f"final greedy success {final.get('greedy_success_rate', float('nan')):.0%}, "
        f"sampled {final.get('sampled_success_rate', float('nan')):.0%}"
    )
    print(
        f"done: {result.iterations} iterations in {result.seconds / 60:.1f} min; {result.env_steps:,} environment "
        f"steps, {result.expert_sim_steps:,} simulator steps of expert planning; {evaluation}"
    )
    if result.best is not None:
        best = Path(args.run_dir) / BEST
        print(
            f"best iterate by the in-run evaluation: iteration {result.best['iteration']}, kept in {best} "
            f"(score it on fresh episodes: bimgame score {best})"
        )
    return 0
