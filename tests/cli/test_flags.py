"""Flags generated from settings dataclasses: help from the field docstrings, switches for booleans,
the loosest number parser the class accepts, several values for tuples, defaults of None for
``--resume``, renamed flags and aliases."""

from __future__ import annotations

import argparse
import dataclasses

import pytest

from bimgame.cli.flags import FIELD_CHOICES, add_settings_flags, given_settings
from bimgame.cli.main import build_parser
from bimgame.envs.puzzles import NETWORK_OBS
from bimgame.learn.a3c import A3CConfig


@dataclasses.dataclass(frozen=True)
class Toy:
    """Settings used only by these tests."""

    count: int = 3
    """How many widgets to make."""
    rate: float = 0.5
    """Widget rate per
    second, over several lines."""
    offset: int = 0
    """Shift of the widgets (any integer)."""
    flag_on: bool = True
    """Whether the lamp is on."""
    flag_off: bool = False
    """Whether the fan runs."""
    names: tuple[str, ...] = ("a",)
    """Names of the widgets."""
    limit: int | None = None
    """Upper bound on widgets; None: no bound."""
    big: int = 250_000
    undocumented: int = 1

    def __post_init__(self) -> None:
        if not (isinstance(self.count, int) and self.count >= 1):
            raise ValueError(f"Toy.count must be >= 1, got {self.count!r}")
        if not self.rate >= 0:
            raise ValueError(f"Toy.rate must be >= 0, got {self.rate!r}")
        if self.limit is not None and self.limit < 1:
            raise ValueError(f"Toy.limit must be None or >= 1, got {self.limit!r}")


@dataclasses.dataclass(frozen=True)
class Choosy:
    obs: str = "pixels"
    """Observation mode."""
    task: str = "STG1"
    """Task name."""


ALL = [f.name for f in dataclasses.fields(Toy)]


def _parser(names=ALL, **options) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="toy")
    add_settings_flags(parser, Toy, names, **options)
    return parser


def _help(parser: argparse.ArgumentParser) -> str:
    return " ".join(parser.format_help().split())


def _action(parser: argparse.ArgumentParser, dest: str) -> argparse.Action:
    (action,) = [a for a in parser._actions if a.dest == dest]
    return action


def test_defaults_are_the_classes_and_help_comes_from_the_docstrings():
    parser = _parser()
    args = parser.parse_args([])
    assert (args.count, args.rate, args.offset, args.flag_on, args.flag_off, args.limit) == (3, 0.5, 0, True, False, None)
    assert tuple(args.names) == ("a",)
    assert _action(parser, "count").help == "How many widgets to make. (default 3)"
    assert _action(parser, "rate").help == "Widget rate per second, over several lines. (default 0.5)"
    assert _action(parser, "names").help == "Names of the widgets. (default a)"
    assert _action(parser, "limit").help == "Upper bound on widgets; None: no bound. (default None)"
    assert _action(parser, "big").help == "(default 250,000)"  # no docstring: only the default
    text = _help(parser)
    assert "--count COUNT How many widgets to make. (default 3)" in text
    assert "Whether the lamp is on." in text and "Whether the fan runs." in text


def test_defaults_from_an_instance_and_default_text():
    parser = _parser(["count", "rate"], defaults=Toy(count=9), default_text="the budget's")
    args = parser.parse_args([])
    assert args.count == 9
    assert _action(parser, "count").help == "How many widgets to make. (default the budget's)"


def test_booleans_are_switches_away_from_their_default():
    parser = _parser(["flag_on", "flag_off"])
    options = {s for a in parser._actions for s in a.option_strings}
    assert {"--no-flag-on", "--flag-off"} <= options
    assert "--flag-on" not in options and "--no-flag-off" not in options
    args = parser.parse_args(["--no-flag-on", "--flag-off"])
    assert args.flag_on is False and args.flag_off is True
    args = parser.parse_args([])
    assert args.flag_on is True and args.flag_off is False


def test_positive_field_refuses_zero_with_argparses_message(capsys):
    parser = _parser()
    with pytest.raises(SystemExit) as exit_info:
        parser.parse_args(["--count", "0"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "--count" in err and "expected a positive integer" in err
    assert parser.parse_args(["--count", "1"]).count == 1


def test_non_negative_field_refuses_minus_one_and_accepts_zero(capsys):
    parser = _parser()
    with pytest.raises(SystemExit):
        parser.parse_args(["--rate", "-1"])
    err = capsys.readouterr().err
    assert "--rate" in err and ">= 0" in err
    args = parser.parse_args(["--rate", "0"])
    assert args.rate == 0.0 and isinstance(args.rate, float)


def test_unbounded_field_accepts_negative_values():
    args = _parser().parse_args(["--offset", "-5"])
    assert args.offset == -5 and isinstance(args.offset, int)


def test_optional_int_parser_is_positive(capsys):
    parser = _parser()
    assert parser.parse_args(["--limit", "4"]).limit == 4
    with pytest.raises(SystemExit):
        parser.parse_args(["--limit", "0"])
    assert "expected a positive integer" in capsys.readouterr().err


def test_numbers_that_are_not_numbers_are_refused(capsys):
    with pytest.raises(SystemExit):
        _parser().parse_args(["--count", "many"])
    assert "'many'" in capsys.readouterr().err


def test_tuple_field_takes_several_values():
    parser = _parser()
    assert list(parser.parse_args(["--names", "x", "y", "z"]).names) == ["x", "y", "z"]
    assert _action(parser, "names").nargs == "+"
    with pytest.raises(SystemExit):
        parser.parse_args(["--names"])


def test_default_none_and_given_settings():
    parser = _parser(default_none=True)
    args = parser.parse_args(["--count", "5", "--no-flag-on", "--names", "p", "q"])
    assert args.rate is None and args.offset is None and args.flag_off is None and args.limit is None
    given = given_settings(args, Toy)
    assert given == {"count": 5, "flag_on": False, "names": ["p", "q"]}
    assert given_settings(args, Toy, ["count", "rate"]) == {"count": 5}
    assert given_settings(parser.parse_args([]), Toy) == {}
    # the help still shows the real default
    assert _action(parser, "count").help.endswith("(default 3)")


def test_flags_and_aliases_rename_and_add_option_strings():
    parser = _parser(["count", "flag_on", "rate"], flags={"count": "--widgets", "flag_on": "--dark"},
                     aliases={"count": ("-n",), "rate": ("-r", "--speed")})
    options = {s for a in parser._actions for s in a.option_strings}
    assert {"--widgets", "-n", "--dark", "--rate", "-r", "--speed"} <= options
    assert "--count" not in options and "--no-flag-on" not in options
    args = parser.parse_args(["-n", "7", "--dark", "--speed", "2.5"])
    assert (args.count, args.flag_on, args.rate) == (7, False, 2.5)
    assert parser.parse_args(["--widgets", "8"]).count == 8


def test_helps_and_types_replace_the_generated_ones():
    parser = _parser(["count"], helps={"count": "my own words"}, types={"count": lambda s: int(s) * 10})
    assert _action(parser, "count").help == "my own words (default 3)"
    assert parser.parse_args(["--count", "-2"]).count == -20  # the given type replaces the probed one


def test_unknown_field_is_named():
    with pytest.raises(ValueError, match="'nonsense'"):
        _parser(["count", "nonsense"])


def test_choice_fields_are_restricted_and_tasks_case_insensitive(capsys):
    parser = argparse.ArgumentParser()
    add_settings_flags(parser, Choosy, ["obs", "task"])
    assert tuple(_action(parser, "obs").choices) == NETWORK_OBS == FIELD_CHOICES["obs"]
    args = parser.parse_args(["--obs", "state", "--task", "stg2"])
    assert (args.obs, args.task) == ("state", "STG2")
    with pytest.raises(SystemExit):
        parser.parse_args(["--obs", "rgb"])
    assert "invalid choice" in capsys.readouterr().err


def test_train_flags_of_the_real_a3c_config(tmp_path):
    args = build_parser().parse_args(["train", "--run-dir", str(tmp_path / "X"), "--steps", "2M", "--no-tilt-input",
                                      "--obs", "state"])
    assert args.steps == 2_000_000 and args.tilt_input is False and args.obs == "state"
    given = given_settings(args, A3CConfig, A3CConfig.flat_names())
    assert given == {"steps": 2_000_000, "tilt_input": False, "obs": "state"}
    others = [name for name in A3CConfig.flat_names() if name not in {"steps", "tilt_input", "obs"}]
    assert others and all(getattr(args, name) is None for name in others)


@dataclasses.dataclass(frozen=True)
class Modal:
    """Settings whose defaults depend on the observation mode, filled in like NetworkSettings'."""

    obs: str = "pixels"
    """Observation mode."""
    size: int | None = None
    """Layer size; None: 8 for pixels, 4 for state."""
    width: int | None = None
    """Layer width."""
    lamp: bool | None = None
    """Light the lamp. None: on for pixels, off for state."""
    tilt: bool = True
    """Feed the tilt to the network. False: no tilt input, the paper's exact input."""
    fan: bool = False
    """Run the fan. False: a silent board."""
    mirror: bool = True
    """Mirror the board."""

    def __post_init__(self) -> None:
        pixels = self.obs == "pixels"
        for name, value in (("size", 8 if pixels else 4), ("width", 6 if pixels else 3), ("lamp", pixels)):
            if getattr(self, name) is None:
                object.__setattr__(self, name, value)


MODAL = [f.name for f in dataclasses.fields(Modal)]


def _modal(**options) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="modal")
    add_settings_flags(parser, Modal, MODAL, **options)
    return parser


def test_a_default_filled_in_per_mode_is_shown_per_mode_when_the_class_decides():
    parser = _modal(default_none=True)
    assert _action(parser, "size").help == "Layer size. (default: 8 for pixels, 4 for state)"
    assert _action(parser, "width").help == "Layer width. (default: 6 for pixels, 3 for state)"  # no None clause
    assert parser.parse_args([]).size is None  # the class decides from --obs


def test_a_filled_in_default_that_the_flag_fixes_is_shown_as_that_value():
    """Without default_none the flag's default is the value for the default observations: the
    docstring's None clause does not hold for it, so the help leaves it out."""
    parser = _modal()
    assert _action(parser, "size").help == "Layer size. (default 8)"
    assert parser.parse_args(["--obs", "state"]).size == 8


def test_a_switch_whose_default_depends_on_the_mode_is_two_way():
    parser = _modal(default_none=True)
    assert parser.parse_args([]).lamp is None
    assert parser.parse_args(["--lamp"]).lamp is True
    assert parser.parse_args(["--no-lamp"]).lamp is False
    assert _action(parser, "lamp").help == "Light the lamp. (default: on for pixels, off for state)"
    assert "--lamp, --no-lamp" in _help(parser)
    assert _action(_modal(), "lamp").help == "Light the lamp. (default on)"


def test_the_off_switch_says_what_it_does():
    parser = _modal()
    options = {s for a in parser._actions for s in a.option_strings}
    assert {"--no-tilt", "--fan", "--no-mirror"} <= options and not {"--tilt", "--no-fan", "--mirror"} & options
    assert _action(parser, "tilt").help == "No tilt input, the paper's exact input."
    assert _action(parser, "fan").help == "Run the fan. Without it: a silent board."
    # without a False clause the help still says that the switch turns the setting off
    assert _action(parser, "mirror").help == "Turns off (on by default): Mirror the board."
    assert parser.parse_args(["--no-tilt", "--fan", "--no-mirror"]) == argparse.Namespace(
        obs="pixels", size=8, width=6, lamp=True, tilt=False, fan=True, mirror=False)


def test_train_has_two_way_privileged_switches_and_says_what_no_tilt_input_does(tmp_path):
    parser = build_parser()
    base = ["train", "--run-dir", str(tmp_path / "r")]
    for flag, name, value in (("--aux-heads", "aux_heads", True), ("--no-aux-heads", "aux_heads", False),
                              ("--asymmetric-critic", "asymmetric_critic", True),
                              ("--no-asymmetric-critic", "asymmetric_critic", False),
                              ("--advantage-norm", "advantage_norm", True),
                              ("--no-advantage-norm", "advantage_norm", False)):
        assert getattr(parser.parse_args([*base, flag]), name) is value, flag
    args = parser.parse_args(base)
    assert args.aux_heads is None and args.asymmetric_critic is None and args.advantage_norm is None
    train = _verb_parser("train")
    assert not _action(train, "tilt_input").help.startswith("Feed")
    hidden = _action(train, "hidden").help
    assert "256 for pixels" in hidden and "128 for state" in hidden
    assert "(default 256)" not in hidden


def test_choices_in_help_are_the_settings_modules_own_tuples():
    from bimgame.learn.a3c.settings import OPTIMIZERS
    from bimgame.learn.learner_settings import START_CURRICULA

    train = _verb_parser("train")
    assert _action(train, "optimizer").choices is OPTIMIZERS
    assert _action(train, "start_curriculum").choices is START_CURRICULA


def test_train_pretrain_and_dagger_list_their_flags_in_groups():
    from bimgame.cli.flags import OTHER_SETTINGS
    from bimgame.cli.train import TRAIN_GROUPS

    for verb in ("train", "pretrain", "dagger"):
        parser = _verb_parser(verb)
        titles = [group.title for group in parser._action_groups]
        grouped = [a for group in parser._action_groups if group.title not in ("options", "optional arguments",
                                                                              "positional arguments", OTHER_SETTINGS)
                   for a in group._group_actions]
        ungrouped = {a.dest for a in parser._actions if a.dest != "help"} - {a.dest for a in grouped}
        assert not ungrouped, (verb, ungrouped)
        assert OTHER_SETTINGS not in titles, verb
    train_titles = [group.title for group in _verb_parser("train")._action_groups]
    shown = [title for title in train_titles if title not in ("options", "positional arguments")]
    assert [title for title, _ in TRAIN_GROUPS] == shown
    assert {"environment", "network", "optimisation", "fine-tuning", "curriculum", "logging"} <= set(train_titles)


def _verb_parser(verb: str) -> argparse.ArgumentParser:
    return next(a for a in build_parser()._actions if a.dest == "verb").choices[verb]
