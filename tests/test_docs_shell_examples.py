"""The shell examples CI runs (``.ci/shell-examples``, tests/support/shell_examples.py): every
documented command line is either run, as written but for its budget flags, or says why not; and
every line that runs parses with the real command line. Running them takes minutes, so CI does that
as its own step; this checks the plan in a second."""

from __future__ import annotations

import contextlib
import io

import pytest
from support.shell_examples import NOT_RUN, TINY, documents, plan, shell_examples

from bimgame.cli.main import build_parser

STEPS = [plan(example) for path in documents() for example in shell_examples(path)]


def test_most_documented_command_lines_run():
    ran = [s for s in STEPS if s.argv is not None]
    assert len(STEPS) >= 60 and len(ran) >= 45, (len(STEPS), len(ran))
    # What is not run says why, and only for the documented reasons.
    reasons = {*NOT_RUN.values(), "joins a running Ray cluster",
               "a synopsis (placeholders); its flags are parsed by test_docs_commands"}
    assert {s.skip for s in STEPS if s.argv is None} <= reasons


@pytest.mark.parametrize("step", [s for s in STEPS if s.argv is not None], ids=lambda s: s.example.where)
def test_a_run_example_keeps_its_flags_and_parses(step):
    documented = [w.strip("[]").split("=")[0] for w in step.example.line.split("#")[0].split()]
    flags = {w for w in documented if w.startswith("--")}
    assert flags <= set(step.argv), flags - set(step.argv)
    for flag, value in TINY.get(step.argv[0], {}).items():
        if flag in step.argv or "--resume" not in step.argv:
            assert step.argv[step.argv.index(flag) + 1] == value
    with contextlib.redirect_stderr(io.StringIO()) as errors:
        try:
            build_parser().parse_args(list(step.argv))
        except SystemExit:
            if "not run directories" in errors.getvalue():
                return  # LABEL=RUN groups are checked to exist when parsed: the page's earlier lines make them
            pytest.fail(f"{step.example.where}: bimgame {' '.join(step.argv)} does not parse: {errors.getvalue()}")
