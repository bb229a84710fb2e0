"""argparse value types shared by the command-line verbs, which reject bad values with a message that
names the value and what is allowed, and the flags several verbs share (``--task``, ``--max-steps``)."""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable
from pathlib import Path

from bimgame.expert.pool import BACKENDS
from bimgame.learn.common import MAX_SEED
from bimgame.learn.learner_settings import MAX_STEPS
from bimgame.sim.tasks import Task

__all__ = [
    "add_backend_arguments",
    "positive_int",
    "non_negative_int",
    "finite_float",
    "positive_float",
    "non_negative_float",
    "seed",
    "episode_count",
    "run_group",
    "episode_count_or_zero",
    "MAX_EPISODES",
    "TASK_NAMES",
    "add_task_argument",
    "add_max_steps_argument",
    "check_output_file",
    "step_count",
    "step_count_or_zero",
]

#: The most episodes a verb runs side by side (each has its own simulator): more is a typo that would
#: fail only when memory runs out.
MAX_EPISODES = 10_000

#: The values of ``--task``.
TASK_NAMES = tuple(task.value for task in Task)


def _integer(text: str, minimum: int, what: str, maximum: int | None = None) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if value < minimum or (maximum is not None and value > maximum):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1."""
    return _integer(text, 1, "a positive integer")


def non_negative_int(text: str) -> int:
    """An integer >= 0."""
    return _integer(text, 0, "a non-negative integer")


def seed(text: str) -> int:
    """A seed: an integer from 0 to :data:`~bimgame.learn.common.MAX_SEED` (numpy refuses negative
    seeds and torch those of 2**64 or more, deep inside a run)."""
    return _integer(text, 0, f"a non-negative integer <= {MAX_SEED} (a seed)", MAX_SEED)


def episode_count(text: str) -> int:
    """A number of episodes run side by side: an integer from 1 to :data:`MAX_EPISODES`."""
    return _integer(text, 1, f"a positive integer <= {MAX_EPISODES}", MAX_EPISODES)


def episode_count_or_zero(text: str) -> int:
    """:func:`episode_count`, or 0 (e.g. ``--eval-episodes 0``: none)."""
    return _integer(text, 0, f"an integer from 0 to {MAX_EPISODES}", MAX_EPISODES)


def _number(text: str, what: str, accepts: Callable[[float], bool]) -> float:
    """``text`` as a finite number that ``accepts`` takes; otherwise an error saying ``what`` is expected."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if not (math.isfinite(value) and accepts(value)):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return value


def finite_float(text: str) -> float:
    """A finite number of either sign (e.g. a reward or a penalty)."""
    return _number(text, "a finite number", lambda value: True)


def positive_float(text: str) -> float:
    """A finite number > 0."""
    return _number(text, "a positive finite number", lambda value: value > 0)


def non_negative_float(text: str) -> float:
    """A finite number >= 0."""
    return _number(text, "a finite number >= 0", lambda value: value >= 0)


def add_task_argument(parser: argparse.ArgumentParser, default: str | None, help: str | None = None) -> None:
    """``--task``: one of :data:`TASK_NAMES`, in any case."""
    parser.add_argument("--task", choices=TASK_NAMES, default=default, type=str.upper, help=help)


def add_max_steps_argument(parser: argparse.ArgumentParser) -> None:
    """``--max-steps``: the time limit per episode, None for the task's registered limit."""
    parser.add_argument(
        "--max-steps",
        type=positive_int,
        default=None,
        help="time limit per episode (default: the task's registered limit)",
    )


def add_backend_arguments(parser: argparse.ArgumentParser, what: str) -> None:
    """``--backend local|ray`` and ``--ray-address``/``--address`` (the Ray cluster to join) for a
    command whose ``what`` (e.g. "episodes") can run on a Ray cluster."""
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="local",
        help=f"local: this machine; ray: {what} as Ray tasks on a cluster (default local)",
    )
    parser.add_argument(
        "--ray-address",
        "--address",
        dest="ray_address",
        default=None,
        metavar="ADDR",
        help="the Ray cluster to join with --backend ray ('auto', or HOST:PORT of the head "
        "started by 'ray start --head'); default: start Ray on this machine",
    )


def check_output_file(path: Path | None, flag: str, example: str) -> None:
    """Refuse an output file path that cannot be written — a directory, or below a file — before any
    work is done (not after an evaluation that took minutes); ``example`` is a file name to suggest."""
    if path is None:
        return
    if path.is_dir():
        raise ValueError(f"{flag} {path} is a directory; give a file name, e.g. {path / example}")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise ValueError(f"{flag} {path}: {parent} is a file, not a directory")
            break


_SUFFIXES = {"": 1, "k": 1_000, "m": 1_000_000, "g": 1_000_000_000}


def step_count(text: str) -> int:
    """A number of environment steps: ``300000``, ``200k``, ``5M``, ``2.5M``, ``1e6``; at most
    :data:`~bimgame.learn.a3c.MAX_STEPS` (10¹²)."""
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][0-9]+)?)\s*([kKmMgG]?)\s*", text)
    if not match:
        raise argparse.ArgumentTypeError(f"expected a step count such as 300000, 200k, 5M or 1e6, got {text!r}")
    value = float(match.group(1)) * _SUFFIXES[match.group(2).lower()]
    if not value <= MAX_STEPS:  # also inf (1e400)
        raise argparse.ArgumentTypeError(f"expected at most 1e12 (10^12) steps, got {text!r}")
    if value < 1 or value != int(value):
        raise argparse.ArgumentTypeError(f"expected a positive whole number of steps, got {text!r}")
    return int(value)


def step_count_or_zero(text: str) -> int:
    """:func:`step_count`, or 0 (e.g. ``--eval-every 0``: never)."""
    return 0 if text.strip() == "0" else step_count(text)


def run_group(text: str) -> tuple[str, list[Path]]:
    """``LABEL=RUN[,RUN...]`` → (label, run directories)."""
    label, sep, runs = text.partition("=")
    paths = [Path(r) for r in runs.split(",") if r]
    if not sep or not label or not paths:
        raise argparse.ArgumentTypeError(f"expected LABEL=RUN[,RUN...], got {text!r}")
    missing = [str(p) for p in paths if not p.is_dir()]
    if missing:
        raise argparse.ArgumentTypeError(f"not run directories: {', '.join(missing)}")
    return label, paths
