"""argparse value types shared by the command-line verbs, which reject bad values with a message that
names the value and what is allowed, and the flags several verbs share (``--task``, ``--max-steps``)."""

from __future__ import annotations

import argparse

from bimgame.sim.tasks import Task

__all__ = ["positive_int", "non_negative_int", "positive_float", "non_negative_float", "TASK_NAMES",
           "add_task_argument", "add_max_steps_argument"]

#: The values of ``--task``.
TASK_NAMES = tuple(task.value for task in Task)


def _integer(text: str, minimum: int, what: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1."""
    return _integer(text, 1, "a positive integer")


def non_negative_int(text: str) -> int:
    """An integer >= 0."""
    return _integer(text, 0, "a non-negative integer")


def _number(text: str, strictly_positive: bool) -> float:
    what = "a positive finite number" if strictly_positive else "a finite number >= 0"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if not (value > 0 if strictly_positive else value >= 0) or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0."""
    return _number(text, strictly_positive=True)


def non_negative_float(text: str) -> float:
    """A finite number >= 0."""
    return _number(text, strictly_positive=False)


def add_task_argument(parser: argparse.ArgumentParser, default: str) -> None:
    """``--task``: one of :data:`TASK_NAMES`, in any case."""
    parser.add_argument("--task", choices=TASK_NAMES, default=default, type=str.upper)


def add_max_steps_argument(parser: argparse.ArgumentParser) -> None:
    """``--max-steps``: the time limit per episode, None for the task's registered limit."""
    parser.add_argument("--max-steps", type=positive_int, default=None,
                        help="time limit per episode (default: the task's registered limit)")
