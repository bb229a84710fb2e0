"""The shell examples of README.md and the documentation site, and how CI runs each of them.

An example is a command line in a fenced block that is not Python (``bimgame …``, ``./dev …``,
``python3 -m pip …``, ``ray …``). Each documented page is a tutorial a reader follows from an empty
directory, so the runner (``.ci/shell-examples``) runs each page's examples in order in a fresh
directory of its own, as written except for their budgets: :data:`TINY` sets the flags that decide
how long a command runs (``--steps 500k`` becomes 2,000 steps, ``--episodes 500`` two episodes) and
leaves every other flag, path and value as documented, so an example that drifts from the code (a
renamed flag, a missing input, a path an earlier line did not create) fails. ``bimgame play`` is
started, its page fetched, and stopped.

What is not run says why (:data:`NOT_RUN`): the set-up and test commands CI runs itself, a cluster
across machines, input only a person can make, the benchmarks (hours of runs), and synopses (lines
with placeholders such as ``DIR`` or ``RUN``, which tests/cli/test_docs_commands.py parses). Optional
flags in brackets are run included; of ``a|b`` alternatives the first is run.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
#: Languages of fenced blocks that hold shell lines (an unlabelled fence is shell here).
SHELL_FENCES = {"", "bash", "sh", "shell", "console"}
#: The programs whose lines are examples.
PROGRAMS = {"bimgame", "./dev", "python", "python3", "pip", "ray"}
#: Words that stand for a value in a synopsis (also how tests/cli/test_docs_commands.py reads them).
PLACEHOLDERS = {"ARGS", "ADDR", "COEF", "DATA", "DIR", "G", "HEAD_IP", "J", "K", "LABEL", "MODEL", "N", "PNG",
                "POLICY", "R", "RUN", "RUN_DIR", "T", "VERB"}
#: What ``./dev VERB`` runs (see the ``dev`` script), for the verbs whose lines are run.
DEV_VERBS = {"bimgame": [], "demo": ["demo"], "reproduce": ["reproduce", "--out", "runs/reproduce-quick"]}
#: Lines not run, by how they start, and why.
NOT_RUN = {
    "python3 -m pip install": "the set-up: CI installs the same way (./dev setup)",
    "./dev test": "the test suite: CI runs it itself",
    "./dev docs": "the site's build: CI runs it itself",
    "ray start": "starts a Ray cluster across machines",
    "python benchmarks/": (
        "a benchmark: several seeds for hours, run by hand; its results are committed under benchmarks/results/"
    ),
    "bimgame pretrain --data data/human": "needs episodes a person played in the browser",
    "bimgame score runs/mb-laws/": "needs a law the model-based benchmark above fits (half an hour a seed)",
    "bimgame train --run-dir runs/stg1-pixels --resume": (
        "continues an interrupted run; a finished one is refused (tests/learn/test_run_reliability.py kills and "
        "resumes runs)"
    ),
}
#: The flags that decide how long a command runs, per verb, and the tiny values CI gives them
#: (added when the example leaves them out).
TINY: dict[str, dict[str, str]] = {
    "train": {"--steps": "2000", "--eval-episodes": "2"},
    "evaluate": {"--episodes": "2"},
    "score": {"--episodes": "2"},
    "generate": {"--episodes": "2"},
    "expert-eval": {"--episodes": "2"},
    "rollout": {"--episodes": "2"},
    "pretrain": {"--epochs": "2", "--patience": "1", "--eval-episodes": "2"},
    "dagger": {"--iterations": "1", "--episodes-per-iteration": "2", "--max-episode-steps": "100",
               "--eval-episodes": "2"},
    "robustness": {"--episodes": "2", "--expert-seeds": "1", "--expert-episodes": "1"},
}
_FENCE = re.compile(r"^\s*(```|~~~)\s*([\w-]*)")
_PLACEHOLDER = re.compile(r"^([A-Z][A-Z0-9_]*)(?![a-z0-9])")


@dataclass(frozen=True)
class ShellExample:
    """One documented command line: where it is and the line (``\\`` continuations joined)."""

    where: str
    line: str


@dataclass(frozen=True)
class Step:
    """How CI treats one example: the bimgame arguments it runs (None: not run, ``skip`` says why),
    and whether it is a server to start, check and stop."""

    example: ShellExample
    argv: tuple[str, ...] | None
    skip: str | None = None
    server: bool = False


def documents() -> list[Path]:
    """README.md, then the site's pages in the order of its navigation, then any other page."""
    nav = yaml.safe_load((ROOT / "mkdocs.yml").read_text())["nav"]
    ordered = [ROOT / "README.md", *(ROOT / "docs" / page for page in _pages(nav))]
    rest = sorted(set((ROOT / "docs").rglob("*.md")) - set(ordered))
    return [path for path in [*ordered, *rest] if path.is_file()]


def _pages(nav: object) -> list[str]:
    """The page paths of a mkdocs ``nav`` (nested lists of {title: page or nav})."""
    if isinstance(nav, str):
        return [nav]
    if isinstance(nav, list):
        return [page for item in nav for page in _pages(item)]
    if isinstance(nav, dict):
        return [page for value in nav.values() for page in _pages(value)]
    return []


def shell_examples(path: Path) -> list[ShellExample]:
    """The example lines of one Markdown document, in order."""
    found: list[ShellExample] = []
    fence: str | None = None
    pending: tuple[int, str] | None = None
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        match = _FENCE.match(line)
        if match:
            fence = match.group(2) if fence is None else None
            continue
        if fence is None or fence not in SHELL_FENCES:
            continue
        start, joined = pending if pending is not None else (number, "")
        joined += line.strip()
        if joined.endswith("\\"):
            pending = (start, joined[:-1] + " ")
            continue
        pending = None
        words = joined.split()
        if words and words[0] in PROGRAMS:
            found.append(ShellExample(f"{path.relative_to(ROOT)}:{start}", joined))
    return found


def plan(example: ShellExample) -> Step:
    """What CI does with ``example`` (see the module notes)."""
    for start, why in NOT_RUN.items():
        if example.line.startswith(start):
            return Step(example, None, skip=why)
    words = shlex.split(example.line, comments=True)
    if words[0] == "./dev" and len(words) > 1 and words[1] in DEV_VERBS:
        words = ["bimgame", *DEV_VERBS[words[1]], *words[2:]]
    if words[0] != "bimgame" or len(words) < 2:
        return Step(example, None, skip="not a bimgame command line")
    if "HEAD_IP" in example.line or "auto" in words:
        return Step(example, None, skip="joins a running Ray cluster")
    words = [w.replace("[", "").replace("]", "") for w in words[1:]]
    words = [w.split("|")[0] for w in words if w and w != "..."]
    if any(is_placeholder(w) for w in words):
        return Step(example, None, skip="a synopsis (placeholders); its flags are parsed by test_docs_commands")
    return Step(example, tuple(_tiny(words)), server=words[0] == "play")


def is_placeholder(word: str) -> bool:
    """Whether ``word`` stands for a value in a synopsis (``DIR``, ``RUN_DIR``, ``N``, ``LABEL=RUN`` …)."""
    match = _PLACEHOLDER.match(word)
    return match is not None and match.group(1) in PLACEHOLDERS


def _tiny(words: list[str]) -> list[str]:
    """``words`` (a verb and its arguments) with the budget flags of :data:`TINY` set (a ``--resume``
    line only those it gives: the stored run's budget is what it continues to); a reproduction runs the
    ``smoke`` budget instead of ``quick`` (the default) and plans the longer ones (--dry-run)."""
    verb, argv = words[0], list(words)
    for flag, value in TINY.get(verb, {}).items():
        if flag in argv:
            argv[argv.index(flag) + 1] = value
        elif "--resume" not in argv:
            argv += [flag, value]
    if verb == "reproduce":
        budget = argv[argv.index("--budget") + 1] if "--budget" in argv else "quick"
        if budget == "quick":
            argv = [w for w in argv if w not in ("--budget", "quick")] + ["--budget", "smoke"]
        elif "--dry-run" not in argv:
            argv.append("--dry-run")
    return argv
