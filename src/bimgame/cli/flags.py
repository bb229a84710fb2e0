"""Command-line flags generated from the settings dataclasses, so that a setting is declared once.

For each field named, :func:`add_settings_flags` adds ``--field-name`` with

- **help** from the field's docstring (:func:`bimgame.util.settings.field_docs`) and its default;
- **choices** for the fields whose allowed values the library names once (:data:`FIELD_CHOICES`);
- **booleans** as switches: ``--keypoints`` for a False default, ``--no-tilt-input`` for a True one;
- **numbers** parsed at the command line with the loosest of "positive", "non-negative" or "any"
  that the settings class itself accepts — probed once by building the class with 0 and −1 for that
  field — so a bound is declared only in the class's own validation, and a bad value is refused
  by argparse with the flag's name before any work starts.

Why not tyro (CleanRL's choice): the verbs keep their established flag names, aliases and short
options (``--steps 5M``, ``--no-tilt-input``, ``-K``), their argparse error messages and the
``--resume`` rule "a flag not given keeps the run's stored value", which needs defaults of None.
This module is that much of tyro, on argparse.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import typing
from collections.abc import Callable, Iterable
from types import UnionType
from typing import Any

from bimgame.cli.argtypes import TASK_NAMES, non_negative_float, non_negative_int, positive_float, positive_int
from bimgame.envs.observe import OBS_MODES
from bimgame.envs.randomization import RANDOMIZATION_PRESETS
from bimgame.experiments.budgets import ALGORITHMS
from bimgame.expert.mpc import PLANNING_REWARDS, SAMPLINGS
from bimgame.learn.a3c import OPTIMIZERS, START_CURRICULA
from bimgame.learn.finetune import FINETUNE_PRESETS
from bimgame.learn.nets import PRECISIONS
from bimgame.learn.supervised import TARGETS
from bimgame.util.settings import field_docs

__all__ = ["add_settings_flags", "given_settings", "FIELD_CHOICES"]

#: The allowed values of the settings that name a choice, wherever they appear.
FIELD_CHOICES: dict[str, tuple[str, ...]] = {
    "task": TASK_NAMES, "tasks": TASK_NAMES, "obs": OBS_MODES, "optimizer": OPTIMIZERS, "target": TARGETS,
    "sampling": SAMPLINGS, "reward": PLANNING_REWARDS, "algorithms": ALGORITHMS,
    "finetune": tuple(FINETUNE_PRESETS), "start_curriculum": START_CURRICULA, "precision": PRECISIONS,
    "randomize": tuple(RANDOMIZATION_PRESETS),
}
#: Switches a fine-tuning preset may turn on: they get both ``--x`` and ``--no-x``.
_TWO_WAY_SWITCHES = {name for name, value in FINETUNE_PRESETS["keep"].items() if isinstance(value, bool)}
#: Fields whose values are parsed case-insensitively (``--task stg1``).
_UPPER = {"task", "tasks"}


def add_settings_flags(parser: argparse.ArgumentParser | Any, cls: type, names: Iterable[str], *,
                       defaults: Any = None, default_none: bool = False,
                       types: dict[str, Callable[[str], Any]] | None = None,
                       flags: dict[str, str] | None = None, helps: dict[str, str] | None = None,
                       aliases: dict[str, tuple[str, ...]] | None = None, default_text: str | None = None) -> None:
    """Add a flag for each field of the settings dataclass ``cls`` in ``names``.

    ``defaults``: an instance whose values are the defaults (default: ``cls()``). ``default_none``:
    every flag defaults to None, so the caller can tell what was given (``--resume`` keeps the rest);
    the help still shows the real default. ``types``: parsers for fields that need a special one
    (e.g. step counts such as ``5M``). ``flags``: other flag names (``{"reward": "--planning-reward"}``).
    ``helps``: help texts that replace the docstring. ``aliases``: more option strings (``{"horizon": ("-H",)}``).
    A tuple field takes one or more values (``--tasks STG1 STG2``). ``default_text``: what the help
    says the default is, when it is not the value in ``defaults`` (e.g. "the budget's").
    """
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    defaults = defaults if defaults is not None else cls()
    types, flags, helps, aliases = types or {}, flags or {}, helps or {}, aliases or {}
    for name in names:
        if name not in fields:
            raise ValueError(f"{cls.__name__} has no setting {name!r}; it has {sorted(fields)}")
        default = getattr(defaults, name)
        text = helps.get(name, _plain(docs.get(name, "")))
        flag = flags.get(name, "--" + name.replace("_", "-"))
        kind = _base_type(hints[name])
        if kind is bool and name in _TWO_WAY_SWITCHES:
            for switch, value in ((flag, True), ("--no-" + name.replace("_", "-"), False)):
                parser.add_argument(switch, dest=name, action="store_const", const=value,
                                    default=None if default_none else default,
                                    help=f"{text} (default {_shown(default)})" if value else argparse.SUPPRESS)
            continue
        if kind is bool:
            switch = flag if not default else flags.get(name, "--no-" + name.replace("_", "-"))
            parser.add_argument(switch, dest=name, action="store_const", const=not default,
                                default=None if default_none else default, help=text)
            continue
        options: dict[str, Any] = {"dest": name, "default": None if default_none else default}
        if typing.get_origin(kind) is tuple:
            options.update(nargs="+", metavar=name.rstrip("s").upper())
            kind = typing.get_args(kind)[0]
        if name in FIELD_CHOICES:
            options["choices"] = FIELD_CHOICES[name]
            options["type"] = str.upper if name in _UPPER else str
        elif name in types:
            options["type"] = types[name]
        elif kind in (int, float):
            options["type"] = _number_type(cls, name, kind)
        shown = default_text if default_text is not None else _shown(default)
        parser.add_argument(flag, *aliases.get(name, ()), help=f"{text} (default {shown})".strip(),
                            **options)


def given_settings(args: argparse.Namespace, cls: type, names: Iterable[str] | None = None) -> dict[str, Any]:
    """The settings of ``cls`` that were given on the command line (flags added with
    ``default_none=True`` that are not None)."""
    names = names if names is not None else [f.name for f in dataclasses.fields(cls)]
    return {name: getattr(args, name) for name in names if getattr(args, name, None) is not None}


def _base_type(hint: Any) -> Any:
    """``int`` for ``int`` and ``int | None``; likewise for float, bool, str."""
    if typing.get_origin(hint) in (typing.Union, UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        return args[0] if len(args) == 1 else hint
    return hint


def _accepts(cls: type, name: str, value: Any) -> bool:
    try:
        cls(**{name: value})
    except (ValueError, TypeError):
        return False
    return True


def _number_type(cls: type, name: str, kind: type) -> Callable[[str], Any]:
    """The loosest command-line parser the settings class accepts for ``name`` (see the module notes)."""
    zero, minus_one = kind(0), kind(-1)
    if _accepts(cls, name, minus_one):
        return int if kind is int else float
    if _accepts(cls, name, zero):
        return non_negative_int if kind is int else non_negative_float
    return positive_int if kind is int else positive_float


def _plain(text: str) -> str:
    """A docstring without its reStructuredText markup, for ``--help`` (``%`` doubled: argparse
    formats help texts with ``%``)."""
    text = re.sub(r":[a-z]+:`~?([^`]+)`", lambda m: m.group(1).rsplit(".", 1)[-1] if "~" in m.group(0) else m.group(1),
                  text)
    return text.replace("``", "").replace("%", "%%")


def _shown(value: Any) -> str:
    if isinstance(value, tuple):
        return " ".join(map(str, value))
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10_000:
        return f"{value:,}"
    return str(value)
