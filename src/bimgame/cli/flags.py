"""Command-line flags generated from the settings dataclasses, so that a setting is declared once.

For each field named, :func:`add_settings_flags` adds ``--field-name`` with

- **help** from the field's docstring (:func:`bimgame.util.settings.field_docs`) and its default;
  a default the class fills in from other settings (``hidden=None``: 256 for pixels, 128 for state)
  is shown as the docstring's ``None:`` clause, or else per observation mode — never as the value it
  takes for the default observations;
- **choices** for the fields whose allowed values the library names once (:data:`FIELD_CHOICES`);
- **booleans** as switches: ``--keypoints`` for a False default, ``--no-tilt-input`` for a True one,
  whose help is the docstring's ``False:`` clause (what the flag does), not the setting's meaning;
  both ``--x`` and ``--no-x`` (:data:`TWO_WAY_SWITCHES`) where the default depends on other settings;
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
from collections.abc import Callable, Iterable, Mapping, Sequence
from types import UnionType
from typing import Any

from bimgame.cli.argtypes import TASK_NAMES, non_negative_float, non_negative_int, positive_float, positive_int
from bimgame.envs.env import ACTION_TYPES
from bimgame.envs.observe import OBS_MODES
from bimgame.envs.puzzles import NETWORK_OBS
from bimgame.envs.randomization import RANDOMIZATION_PRESETS
from bimgame.experiments.budgets import ALGORITHMS
from bimgame.expert.mpc import PLANNING_REWARDS, SAMPLINGS
from bimgame.learn.a3c import OPTIMIZERS, START_CURRICULA
from bimgame.learn.devices import DEVICES
from bimgame.learn.encoders import MAZE_FRAMES
from bimgame.learn.learner_settings import FINETUNE_PRESETS
from bimgame.learn.nets import PRECISIONS
from bimgame.learn.supervised import TARGETS
from bimgame.util.settings import FieldDoc, field_docs, split_field_doc

__all__ = [
    "add_settings_flags",
    "add_flag_groups",
    "add_grouped_settings_flags",
    "given_settings",
    "plain",
    "FIELD_CHOICES",
    "FIELD_METAVARS",
    "TWO_WAY_SWITCHES",
    "OTHER_SETTINGS",
]

#: The allowed values of the settings that name a choice, wherever they appear.
FIELD_CHOICES: dict[str, tuple[str, ...]] = {
    "task": TASK_NAMES,
    "tasks": TASK_NAMES,
    "obs": NETWORK_OBS,
    "action_type": ACTION_TYPES,
    "optimizer": OPTIMIZERS,
    "target": TARGETS,
    "sampling": SAMPLINGS,
    "reward": PLANNING_REWARDS,
    "algorithms": ALGORITHMS,
    "finetune": tuple(FINETUNE_PRESETS),
    "start_curriculum": START_CURRICULA,
    "precision": PRECISIONS,
    "maze_frame": MAZE_FRAMES,
    "device": DEVICES,
    "randomize": tuple(RANDOMIZATION_PRESETS),
}
#: The names shown for the values of settings that take a fixed number of them.
FIELD_METAVARS: dict[str, tuple[str, ...]] = {"demo_start_window": ("FROM", "TO")}
#: Switches that get both ``--x`` and ``--no-x``: those a fine-tuning preset sets (``--init`` turns
#: them on unless told otherwise) and those of privileged learning, ``aux_heads`` (on for pixels,
#: off for state) and ``asymmetric_critic`` (which the experiments turn on and off). Any other
#: switch whose class default is None (filled in from other settings) is two-way too.
TWO_WAY_SWITCHES = frozenset(
    {name for name, value in FINETUNE_PRESETS["keep"].items() if isinstance(value, bool)}
    | {"aux_heads", "asymmetric_critic"}
)
#: The ``--help`` group of the settings that :func:`add_grouped_settings_flags` was given no group for.
OTHER_SETTINGS = "other settings"
#: Fields whose values are parsed case-insensitively (``--task stg1``).
_UPPER = {"task", "tasks"}


@dataclasses.dataclass(frozen=True)
class _Field:
    """What the flag of one settings field is made from."""

    name: str
    flag: str
    kind: Any
    default: Any
    """The value the class gives when the flag is not given (shown in the help)."""
    text: str
    """The help as written: the field's docstring, or the caller's own text."""
    filled_in: bool
    """The class declares None and fills the value in from other settings (e.g. the observation mode)."""
    per_mode: str | None
    """For a filled-in value: the values per observation mode ("256 for pixels, 128 for state")."""

    @property
    def doc(self) -> FieldDoc:
        return split_field_doc(self.text)


class _Switch(argparse.BooleanOptionalAction):
    """``--x`` / ``--no-x`` with the help as given (Python 3.10's version appends its own default)."""

    def __init__(self, option_strings: Sequence[str], dest: str, **options: Any) -> None:
        help_text = options.get("help")
        super().__init__(option_strings, dest, **options)
        self.help = help_text


def add_settings_flags(
    parser: argparse.ArgumentParser | Any,
    cls: type,
    names: Iterable[str],
    *,
    defaults: Any = None,
    default_none: bool = False,
    types: dict[str, Callable[[str], Any]] | None = None,
    flags: dict[str, str] | None = None,
    helps: dict[str, str] | None = None,
    aliases: dict[str, tuple[str, ...]] | None = None,
    default_text: str | None = None,
    choices: dict[str, tuple[str, ...]] | None = None,
) -> None:
    """Add a flag for each field of the settings dataclass ``cls`` in ``names`` to ``parser`` (a
    parser or one of its argument groups, :func:`add_flag_groups`).

    ``defaults``: an instance whose values are the defaults (default: ``cls()``). ``default_none``:
    every flag defaults to None, so the caller can tell what was given (``--resume`` keeps the rest);
    the help still shows the real default. ``types``: parsers for fields that need a special one
    (e.g. step counts such as ``5M``). ``flags``: other flag names (``{"reward": "--planning-reward"}``;
    for a switch whose default is True, the name of the switch that turns it off).
    ``helps``: help texts that replace the docstring. ``aliases``: more option strings (``{"horizon": ("-H",)}``).
    A tuple field takes one or more values (``--tasks STG1 STG2``). ``default_text``: what the help
    says the default is, when it is not the value in ``defaults`` (e.g. "the budget's"). ``choices``:
    allowed values that replace :data:`FIELD_CHOICES`'s for this verb (``bimgame train --task`` also
    takes the labyrinth's tasks).
    """
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    defaults = defaults if defaults is not None else cls()
    types, flags, helps, aliases = types or {}, flags or {}, helps or {}, aliases or {}
    choices = {**FIELD_CHOICES, **(choices or {})}
    for name in names:
        if name not in fields:
            raise ValueError(f"{cls.__name__} has no setting {name!r}; it has {sorted(fields)}")
        default = getattr(defaults, name)
        filled_in = fields[name].default is None and default is not None
        field = _Field(
            name=name,
            flag=flags.get(name, "--" + name.replace("_", "-")),
            kind=_base_type(hints[name]),
            default=default,
            text=helps.get(name, docs.get(name, "")),
            filled_in=filled_in,
            per_mode=_per_mode(cls, name) if filled_in else None,
        )
        initial = None if default_none else default
        if field.kind is bool:
            _add_switch(
                parser,
                field,
                initial,
                keeps_none=default_none,
                two_way=name in TWO_WAY_SWITCHES or fields[name].default is None,
            )
            continue
        shown = " " + default_text if default_text is not None else _default_shown(field, keeps_none=default_none)
        parser.add_argument(
            field.flag,
            *aliases.get(name, ()),
            dest=name,
            default=initial,
            help=f"{_value_text(field)} (default{shown})".strip(),
            **_value_options(cls, field, types, choices),
        )


def add_flag_groups(parser: argparse.ArgumentParser, groups: Sequence[tuple[str, str]]) -> dict[str, Any]:
    """Argument groups of ``parser`` by title, in the order given: ``groups`` holds (title,
    description) pairs, so that ``--help`` lists a verb's many flags by subject."""
    return {title: parser.add_argument_group(title, description or None) for title, description in groups}


def add_grouped_settings_flags(
    parser: argparse.ArgumentParser,
    groups: dict[str, Any],
    cls: type,
    names: Iterable[str],
    placement: Mapping[str, Iterable[str]],
    **options: Any,
) -> None:
    """:func:`add_settings_flags` for ``names``, each into its group of ``groups`` (from
    :func:`add_flag_groups`): ``placement`` lists the names of each group title; a name in none of
    them goes to an "other settings" group (so that a setting added to ``cls`` still gets its flag)."""
    names = list(names)
    placed = {name: title for title, members in placement.items() for name in members}
    for title in dict.fromkeys(placed.get(name, OTHER_SETTINGS) for name in names):
        if title not in groups:
            groups[title] = parser.add_argument_group(title)
        add_settings_flags(groups[title], cls, [n for n in names if placed.get(n, OTHER_SETTINGS) == title], **options)


def _add_switch(parser: Any, field: _Field, initial: Any, *, two_way: bool, keeps_none: bool) -> None:
    """A boolean setting: ``--x`` / ``--no-x`` (``two_way``), or the one switch away from its
    default, whose help says what that switch does (the docstring's ``False:`` clause for ``--no-x``)."""
    doc = field.doc
    if two_way:
        off_flag = "--no-" + field.flag.removeprefix("--")
        off = f" {off_flag}: {plain(doc.false)}." if doc.false else ""
        parser.add_argument(
            field.flag,
            dest=field.name,
            action=_Switch,
            default=initial,
            help=f"{plain(doc.text)}{off} (default{_switch_default(field, keeps_none)})".strip(),
        )
    elif not field.default:
        parser.add_argument(
            field.flag,
            dest=field.name,
            action="store_const",
            const=True,
            default=initial,
            help=plain(doc.text) + (f" Without it: {plain(doc.false)}." if doc.false else ""),
        )
    else:
        flag = field.flag if field.flag != "--" + field.name.replace("_", "-") else "--no-" + field.flag[2:]
        off = _capitalised(plain(doc.false)) + "." if doc.false else f"Turns off (on by default): {plain(doc.text)}"
        parser.add_argument(flag, dest=field.name, action="store_const", const=False, default=initial, help=off)


def _value_options(
    cls: type, field: _Field, types: dict[str, Callable[[str], Any]], choices: Mapping[str, tuple[str, ...]]
) -> dict[str, Any]:
    """``nargs``, ``metavar``, ``choices`` and ``type`` of a setting that takes a value."""
    options: dict[str, Any] = {}
    kind = field.kind
    if typing.get_origin(kind) is tuple:
        members = typing.get_args(kind)
        if Ellipsis in members:
            options.update(nargs="+", metavar=field.name.rstrip("s").upper())
        else:
            options.update(nargs=len(members), metavar=FIELD_METAVARS.get(field.name))
        kind = members[0]
    if field.name in choices:
        options["choices"] = choices[field.name]
        options["type"] = str.upper if field.name in _UPPER else str
    elif field.name in types:
        options["type"] = types[field.name]
    elif kind in (int, float):
        options["type"] = _number_type(cls, field.name, kind)
    return options


def _value_text(field: _Field) -> str:
    """The help of a setting that takes a value, before its default. A filled-in value loses the
    docstring's ``None:`` clause: it becomes the default shown, or (when the flag's default is the
    value filled in for the default observations) it does not hold."""
    return plain(field.doc.text if field.filled_in else field.text)


def _default_shown(field: _Field, *, keeps_none: bool) -> str:
    """What the help says the default is, after "(default". A filled-in value with a flag default of
    None (the class decides from the other flags): the docstring's ``None:`` clause, else the values
    per observation mode; otherwise the flag's default."""
    if field.filled_in and keeps_none:
        return ": " + plain(field.doc.none or field.per_mode or _shown(field.default))
    return " " + _shown(field.default)


def _switch_default(field: _Field, keeps_none: bool) -> str:
    """:func:`_default_shown` for a switch: "on" or "off"."""
    if field.filled_in and keeps_none:
        return ": " + plain(field.doc.none or field.per_mode or _on_off(field.default))
    return " " + _on_off(field.default)


def _per_mode(cls: type, name: str) -> str | None:
    """ "256 for pixels, 128 for state": the value ``cls`` fills in for each observation mode, or None
    if it has no ``obs`` setting or the value does not depend on it."""
    if "obs" not in {f.name for f in dataclasses.fields(cls)}:
        return None
    try:
        values = {mode: getattr(cls(obs=mode), name) for mode in OBS_MODES}
    except (ValueError, TypeError):
        return None
    if len(set(map(repr, values.values()))) == 1:
        return None
    show = _on_off if all(isinstance(v, bool) for v in values.values()) else _shown
    return ", ".join(f"{show(value)} for {mode}" for mode, value in values.items())


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


def plain(text: str) -> str:
    """A docstring without its reStructuredText markup, for ``--help`` (``%`` doubled: argparse
    formats help texts with ``%``)."""
    text = re.sub(
        r":[a-z]+:`~?([^`]+)`", lambda m: m.group(1).rsplit(".", 1)[-1] if "~" in m.group(0) else m.group(1), text
    )
    return text.replace("``", "").replace("%", "%%")


def _capitalised(text: str) -> str:
    return text[:1].upper() + text[1:]


def _on_off(value: Any) -> str:
    return {True: "on", False: "off"}.get(value, str(value))


def _shown(value: Any) -> str:
    if isinstance(value, tuple):
        return " ".join(map(str, value))
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10_000:
        return f"{value:,}"
    return str(value)
