"""Every ``bimgame …`` command line in README.md and docs/**/*.md (also ``./dev bimgame …``,
``./dev reproduce …`` and ``./dev demo …``) parses with the real command line: each flag is one of
its verb's, spelled out (no abbreviation argparse would accept), and the values parse.

Command lines are read from fenced code blocks (continued with ``\\``) and from inline code that
starts with ``bimgame``. Synopses are read as their readers would: ``[--sample]`` is the flag,
``--obs pixels|state`` is checked with each alternative, ``...`` elides values, placeholders such
as ``DIR``, ``N`` or ``RUN`` take a value the flag accepts, and required flags a sentence leaves out
(``bimgame train --task STG1 --subtract-background``) take one too. Nothing runs: the arguments
are only parsed.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import shlex
from dataclasses import dataclass
from pathlib import Path

import pytest

from support.shell_examples import DEV_VERBS, is_placeholder

from bimgame.cli.argtypes import run_group
from bimgame.cli.main import build_parser

ROOT = Path(__file__).resolve().parents[2]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
#: Shell tokens that end a command (what follows is another command or a redirection).
SHELL_ENDS = {"|", "||", "&&", ";", "&", ">", ">>", "2>&1"}
ELLIPSIS = "..."
_FENCE = re.compile(r"^\s*(```|~~~)")
_INLINE = re.compile(r"`([^`]+)`")


@dataclass(frozen=True)
class Command:
    """One documented command line: where it is and its words after ``bimgame``."""

    where: str
    words: tuple[str, ...]

    def __str__(self) -> str:
        return f"{self.where}: bimgame {' '.join(self.words)}"


def split_markdown(text: str) -> tuple[str, list[tuple[int, str]]]:
    """A Markdown document's prose (fenced blocks blanked, so offsets keep their line numbers) and
    its fenced code lines, numbered, with ``\\`` continuations joined."""
    prose: list[str] = []
    code: list[tuple[int, str]] = []
    in_fence = False
    pending: tuple[int, str] | None = None
    for number, line in enumerate(text.splitlines(), start=1):
        if _FENCE.match(line):
            in_fence = not in_fence
            prose.append("")
            continue
        prose.append("" if in_fence else line)
        if not in_fence:
            continue
        start, joined = pending if pending is not None else (number, "")
        joined += line.rstrip()
        pending = (start, joined[:-1] + " ") if joined.endswith("\\") else None
        if pending is None:
            code.append((start, joined))
    return "\n".join(prose), code


def _inline_code(prose: str) -> list[tuple[int, str]]:
    """The inline code spans of ``prose`` (a span may run over lines), with their line numbers."""
    return [(prose.count("\n", 0, m.start()) + 1, m.group(1).replace("\n", " ")) for m in _INLINE.finditer(prose)]


def commands_in(text: str, name: str) -> list[Command]:
    """The bimgame command lines of a Markdown document: fenced code lines (joined across ``\\``
    continuations) and inline code spans outside the fences."""
    prose, code = split_markdown(text)
    found = []
    for number, line in [*code, *_inline_code(prose)]:
        words = _bimgame_words(line)
        if words is not None:
            found.append(Command(f"{name}:{number}", words))
    return found


def inline_flags(text: str, name: str) -> list[tuple[str, str]]:
    """(where, flag) for each ``--flag`` in inline code that starts with a flag: flags named in a
    sentence, e.g. "`--no-aux-heads --no-asymmetric-critic` is the paper's network" (a span that
    starts with a program's name, such as ``python benchmarks/bench_a3c.py --seconds 40``, is that
    program's)."""
    prose, _ = split_markdown(text)
    return [(f"{name}:{number}", flag) for number, span in _inline_code(prose) if span.lstrip().startswith("--")
            for flag in re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", span)]


def _bimgame_words(line: str) -> tuple[str, ...] | None:
    """The words after ``bimgame`` of a shell line that runs it (directly or through ``./dev``), up
    to a comment or another command; None for any other line or a bare ``bimgame``."""
    try:
        words = shlex.split(line, comments=True)
    except ValueError:  # an unbalanced quote in prose: read it word by word
        words = line.split("#", 1)[0].split()
    for index, word in enumerate(words):
        if word in SHELL_ENDS:
            words = words[:index]
            break
    if len(words) >= 2 and words[0] == "./dev" and words[1] in DEV_VERBS:
        words = ["bimgame", *DEV_VERBS[words[1]], *words[2:]]
    if len(words) < 2 or words[0] != "bimgame":
        return None
    return tuple(words[1:])


def variants(words: tuple[str, ...]) -> list[list[str]]:
    """The argument lists a synopsis stands for: brackets removed, and one list per alternative of
    ``a|b|c`` (a word with fewer alternatives keeps its last)."""
    cleaned = [w.replace("[", "").replace("]", "") for w in words]
    cleaned = [w for w in cleaned if w]
    choices = [w.split("|") if "|" in w else [w] for w in cleaned]
    count = max((len(c) for c in choices), default=1)
    return [[c[min(k, len(c) - 1)] for c in choices] for k in range(count)]


def _is_placeholder(word: str) -> bool:
    return word == ELLIPSIS or is_placeholder(word)


def _is_flag(word: str) -> bool:
    return word.startswith("-") and not re.fullmatch(r"-[0-9.][0-9.e]*", word)


def sample_value(action: argparse.Action) -> str:
    """A value ``action`` accepts, for a placeholder: its first choice, else the first of a few
    candidates its type parses."""
    if action.choices:
        return str(next(iter(action.choices)))
    for candidate in ("1", "x", f"A={ROOT / 'docs'}"):
        try:
            if action.type is not None:
                action.type(candidate)  # type: ignore[operator]
        except (argparse.ArgumentTypeError, TypeError, ValueError):
            continue
        return candidate
    raise AssertionError(f"no sample value for {action.option_strings or action.dest}")


def value_for(action: argparse.Action, word: str) -> str:
    """The word to parse for a documented value: a sample for a placeholder; for ``LABEL=RUN,...``
    run groups, the label with a directory that exists (the documented runs exist only after running
    the commands before it; the syntax is still checked by argparse)."""
    if _is_placeholder(word):
        return sample_value(action)
    if action.type is run_group:
        label, sep, runs = word.partition("=")
        return f"{label}={ROOT / 'docs'}" if sep and label and runs else word
    return word


def _values(words: list[str], start: int, action: argparse.Action) -> tuple[list[str], int]:
    """The values after an option (per its ``nargs``), placeholders replaced; and where the next
    word is."""
    end = start
    while end < len(words) and not _is_flag(words[end]):
        end += 1
    given = words[start:end]
    if action.nargs == 0:
        return [], start
    if action.nargs in (None, "?"):
        given = given[:1]
    elif action.nargs in ("+", "*"):
        given = [w for w in given if w != ELLIPSIS] or given
    return [value_for(action, w) for w in given], start + len(given)


def checked_argv(words: list[str]) -> tuple[list[str], list[str]]:
    """The argument list to parse for one variant of a command, and the problems found on the way
    (an unknown verb or flag, an abbreviated flag, a positional argument the verb does not take)."""
    verbs = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    if not words or words[0] not in verbs.choices:
        return [], [f"unknown verb {words[0] if words else '(none)'!r}; verbs: {sorted(verbs.choices)}"]
    parser = verbs.choices[words[0]]
    options = parser._option_string_actions
    positionals = [a for a in parser._actions if not a.option_strings]
    argv, problems, seen, position = [words[0]], [], set(), 0
    index = 1
    while index < len(words):
        word = words[index]
        if _is_flag(word):
            flag = word.split("=", 1)[0]
            if flag not in options:
                problems.append(f"{flag} is not a flag of 'bimgame {words[0]}'")
                index += 1
                continue
            seen.add(options[flag].dest)
            values, index = _values(words, index + 1, options[flag])
            argv += [flag, *values]
            continue
        index += 1
        if word == ELLIPSIS:
            continue
        if position >= len(positionals):
            problems.append(f"'bimgame {words[0]}' takes no argument {word!r}")
            continue
        action = positionals[position]
        seen.add(action.dest)
        argv.append(value_for(action, word))
        position += action.nargs not in ("+", "*")
    return argv + _missing_required(parser, seen), problems


def _missing_required(parser: argparse.ArgumentParser, seen: set[str]) -> list[str]:
    """Values for the required arguments a command line leaves out (a sentence's ``bimgame train
    --task STG1`` has no ``--run-dir``)."""
    extra: list[str] = []
    for action in parser._actions:
        if action.dest in seen or isinstance(action, argparse._HelpAction):
            continue
        if action.option_strings and action.required:
            extra += [action.option_strings[0], sample_value(action)]
        elif not action.option_strings and action.nargs not in ("?", "*"):
            extra.append(sample_value(action))
    return extra


def parse_error(argv: list[str]) -> str | None:
    """argparse's message for ``argv``, or None if it parses (``--help`` only needs known flags)."""
    if "-h" in argv or "--help" in argv:
        return None
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            build_parser().parse_args(argv)
        except SystemExit:
            return err.getvalue().strip().splitlines()[-1]
    return None


def problems_of(command: Command) -> list[str]:
    """Everything wrong with a documented command line, for every variant of its synopsis."""
    problems: list[str] = []
    for words in variants(command.words):
        if words and _is_placeholder(words[0]):  # "./dev bimgame ARGS": a synopsis of the script
            continue
        argv, found = checked_argv(words)
        error = None if found else parse_error(argv)
        problems += found + ([f"{error} (parsed: bimgame {' '.join(argv)})"] if error else [])
    return list(dict.fromkeys(problems))


def documented_commands() -> list[Command]:
    return [command for path in DOCUMENTS
            for command in commands_in(path.read_text(encoding="utf-8"), str(path.relative_to(ROOT)))]


COMMANDS = documented_commands()


def every_flag() -> set[str]:
    """The option strings of every verb."""
    verbs = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return {option for parser in verbs.choices.values() for option in parser._option_string_actions}


def test_the_documents_have_command_lines():
    # The README's sections moved to the guide (docs/guide/*.md): the README and the guide together.
    readme = [c for c in COMMANDS if c.where.startswith(("README.md:", "docs/guide/"))]
    assert len(readme) >= 50
    verbs = {c.words[0] for c in readme}
    assert {"train", "pretrain", "dagger", "generate", "reproduce", "score", "play", "robustness"} <= verbs


@pytest.mark.parametrize("command", COMMANDS, ids=str)
def test_documented_command_parses(command):
    assert problems_of(command) == [], str(command)


def test_flags_named_in_sentences_are_flags_of_a_verb():
    known = every_flag()
    named = [(where, flag) for path in DOCUMENTS
             for where, flag in inline_flags(path.read_text(encoding="utf-8"), str(path.relative_to(ROOT)))]
    assert len(named) >= 20
    assert [(where, flag) for where, flag in named if flag not in known] == []


SAMPLE = """\
Text with `bimgame train --task STG1 --nonsense 3` and `bimgame.learn.a3c` and
`bimgame play --task STG1
--seed 4`.

```bash
bimgame robustness --task STG1 --episodes 50 \\
    --sampled   # a comment --not-a-flag
./dev bimgame maze --out m.png
./dev reproduce --seeds 3
pip install bimgame
```
"""


def test_commands_are_read_from_fences_continuations_and_inline_code():
    found = {c.where: c.words for c in commands_in(SAMPLE, "S")}
    assert found == {
        "S:1": ("train", "--task", "STG1", "--nonsense", "3"),
        "S:2": ("play", "--task", "STG1", "--seed", "4"),
        "S:6": ("robustness", "--task", "STG1", "--episodes", "50", "--sampled"),
        "S:8": ("maze", "--out", "m.png"),
        "S:9": ("reproduce", "--out", "runs/reproduce-quick", "--seeds", "3"),
    }
    text = "A `--no-such-flag --seed` in a `bimgame maze --out x` or `python b.py --y` sentence.\n```\n`--x`\n```"
    assert inline_flags(text, "S") == [("S:1", "--no-such-flag"), ("S:1", "--seed")]


@pytest.mark.parametrize("line, problem", [
    ("bimgame train --task STG1 --nonsense 3", "--nonsense is not a flag of 'bimgame train'"),
    ("bimgame train --run-dir r --geodesic", "--geodesic is not a flag"),  # argparse would take the abbreviation
    ("bimgame train --run-dir r --obs rgb", "invalid choice: 'rgb'"),
    ("bimgame rollout --policy random|oracle", "invalid choice: 'oracle'"),
    ("bimgame fly", "unknown verb 'fly'"),
    ("bimgame maze extra", "takes no argument 'extra'"),
])
def test_bad_command_lines_are_caught(line, problem):
    problems = problems_of(Command("test", tuple(shlex.split(line)[1:])))
    assert any(problem in p for p in problems), problems


@pytest.mark.parametrize("line", [
    "bimgame reproduce --out DIR [--budget quick|paper] [--tasks ...] [--seeds N]",
    "bimgame train ... [--init RUN] [--value-reward RUN] [--geodesic-reward [COEF]]",
    "bimgame compare LABEL=RUN[,RUN...] ... --out PNG [--title T] [--max-step 1.2M]",
    "bimgame train --help",
    "./dev bimgame ARGS",
])
def test_synopses_parse_with_placeholders(line):
    words = _bimgame_words(line)
    assert words is not None
    assert problems_of(Command("test", words)) == []
