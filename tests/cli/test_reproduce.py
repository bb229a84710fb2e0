"""``bimgame reproduce --dry-run`` and ``bimgame report`` through the command line: the dry run
lists the plan and writes nothing, a bad budget names the allowed ones, and a directory that is not
a reproduction is refused with a message, not a traceback. (The end-to-end reproduction, its
continuation and the budget validation are in tests/experiments/test_reproduce.py.)"""

from __future__ import annotations

import json
import re

import pytest
from support.files import snapshot

from bimgame.cli.main import main
from bimgame.experiments.budgets import BUDGETS
from bimgame.experiments.grid import plan_pieces


def _listed(err: str) -> dict[str, str]:
    """Piece id → state ("to do" / "done") of the dry run's piece lines."""
    return {m.group(1): m.group(2) for m in re.finditer(r"^\s+(\S+)\s+(to do|done)\s+≈", err, re.MULTILINE)}


def _dry_run(argv: list[str], capsys) -> str:
    capsys.readouterr()
    assert main(["reproduce", *argv, "--dry-run"]) == 0
    captured = capsys.readouterr()
    assert captured.out == ""  # the plan goes to stderr, like the progress display
    return captured.err


# ------------------------------------------------------------------------------------- dry run
def test_dry_run_of_a_new_directory_lists_the_quick_plan_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "repro"
    err = _dry_run(["--out", str(out)], capsys)
    pieces = plan_pieces(BUDGETS["quick"])
    listed = _listed(err)
    assert list(listed) == [p.id for p in pieces]  # every piece, in the order they run
    assert set(listed.values()) == {"to do"}
    flat = " ".join(err.split())
    assert "budget quick" in flat
    assert f"for all {len(pieces)} pieces" in flat and f"for the {len(pieces)} not finished yet" in flat
    # The presets are named with their sizes.
    for name, budget in BUDGETS.items():
        assert f"{name}: {len(plan_pieces(budget))} pieces" in flat, name
    kinds = {p.kind for p in pieces}
    assert all(f"{kind} ×{sum(p.kind == kind for p in pieces)}" in flat for kind in kinds)
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_dry_run_applies_the_budget_and_grid_flags(tmp_path, capsys):
    out = tmp_path / "paper"
    err = _dry_run(["--out", str(out), "--budget", "paper", "--tasks", "stg2", "--algorithms", "a3c", "dagger",
                    "--seeds", "3"], capsys)
    budget = BUDGETS["paper"].with_grid(tasks=["STG2"], algorithms=["a3c", "dagger"], seeds=3)
    expected = [p.id for p in plan_pieces(budget)]
    assert list(_listed(err)) == expected
    # Only what those algorithms need: the dataset, then A3C and DAgger runs of STG2, 3 seeds each.
    assert len(expected) == 1 + 2 * 3 and all("STG2" in i for i in expected[1:])
    assert not any(i.startswith("pretrain/") for i in expected)
    flat = " ".join(err.split())
    assert "budget paper" in flat and "tasks STG2" in flat and "3 seeds" in flat
    assert f"{budget.obs} observations" in flat
    assert not out.exists()


@pytest.mark.parametrize("name", ["beyond", "ablation"])
def test_dry_run_of_the_budgets_beyond_the_paper_lists_their_plan_within_two_hours(tmp_path, capsys, name):
    err = _dry_run(["--out", str(tmp_path / name), "--budget", name], capsys)
    budget = BUDGETS[name]
    assert list(_listed(err)) == [p.id for p in plan_pieces(budget)]
    flat = " ".join(err.split())
    assert f"budget {name}: tasks {', '.join(budget.tasks)}; {', '.join(budget.algorithms)}; 3 seeds" in flat
    estimate = re.search(r"≈ ([\d.]+) (min|h) for all", flat)
    assert estimate is not None and (estimate.group(2) == "min" or float(estimate.group(1)) <= 2.0), flat
    assert not (tmp_path / name).exists()


def test_dry_run_of_a_started_directory_marks_finished_pieces_and_changes_nothing(tmp_path, capsys):
    out = tmp_path / "repro"
    pieces = plan_pieces(BUDGETS["quick"])
    done = next(p for p in pieces if p.kind == "pretrain-policy")
    # A finished pre-training leaves its summary and checkpoint.
    (out / done.path).mkdir(parents=True)
    (out / done.path / "summary.json").write_text("{}")
    (out / done.path / "checkpoint.pt").write_bytes(b"weights")
    before = snapshot(out)
    err = _dry_run(["--out", str(out)], capsys)
    listed = _listed(err)
    assert listed[done.id] == "done"
    assert [i for i, state in listed.items() if state == "to do"] == [p.id for p in pieces if p is not done]
    assert f"for the {len(pieces) - 1} not finished yet" in " ".join(err.split())
    assert snapshot(out) == before  # no plan, status or lock file written


def test_bad_budget_names_the_allowed_budgets(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["reproduce", "--out", str(tmp_path / "r"), "--budget", "tiny", "--dry-run"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "--budget" in err and "'tiny'" in err
    for name in BUDGETS:
        assert f"'{name}'" in err, name
    assert list(tmp_path.iterdir()) == []


# -------------------------------------------------------------------------------------- report
def _not_a_reproduction(tmp_path, kind: str):
    """A path that is not a reproduction directory, of the given kind."""
    path = tmp_path / "dir"
    if kind == "missing":
        return path
    if kind == "file":
        path.write_text("hello")
        return path
    path.mkdir()
    (path / "other.txt").write_text("unrelated")
    contents = {"not json": "{ plan", "json list": json.dumps(["format"]),
                "other format": json.dumps({"format": "something-else-2", "budget": {}, "pieces": []}),
                "run directory": None}[kind]
    if contents is not None:
        (path / "plan.json").write_text(contents)
    else:  # a training run's directory is not a reproduction either
        (path / "config.json").write_text(json.dumps({"kind": "a3c"}))
        (path / "summary.json").write_text(json.dumps({"steps": 10}))
    return path


@pytest.mark.parametrize("kind, message", [
    ("missing", "not a reproduction directory"),
    ("file", "not a reproduction directory"),
    ("not json", "not a reproduction directory"),
    ("json list", "not a reproduction directory"),
    ("other format", "not a bimgame reproduction plan"),
    ("run directory", "not a reproduction directory"),
])
def test_report_on_something_else_fails_with_a_message(tmp_path, capsys, kind, message):
    path = _not_a_reproduction(tmp_path, kind)
    before = snapshot(tmp_path)
    capsys.readouterr()
    code = main(["report", str(path), "--resamples", "10"])
    captured = capsys.readouterr()
    assert code == 2
    assert captured.err.startswith("bimgame report: error:") and message in captured.err, captured.err
    assert "Traceback" not in captured.err and captured.out == ""
    assert snapshot(tmp_path) == before  # no figures, tables or report written
    if kind == "missing":
        assert not path.exists()  # not created either


@pytest.mark.parametrize("verb", ["report", "reproduce"])
def test_a_damaged_plan_of_the_right_format_is_refused_with_a_message(tmp_path, capsys, verb):
    (tmp_path / "plan.json").write_text(json.dumps({"format": "bimgame-reproduction-1"}))
    argv = ["report", str(tmp_path)] if verb == "report" else ["reproduce", "--out", str(tmp_path), "--dry-run"]
    assert main(argv) == 2
    assert "plan.json" in capsys.readouterr().err


def test_dry_run_plans_ppo_beside_a3c_on_the_same_pi_s_and_the_help_names_them(tmp_path, capsys):
    err = _dry_run(["--out", str(tmp_path / "r"), "--algorithms", "pretrain+ppo", "ppo", "pretrain+a3c"], capsys)
    budget = BUDGETS["quick"].with_grid(algorithms=["pretrain+a3c", "ppo", "pretrain+ppo"])
    listed = list(_listed(err))
    assert listed == [p.id for p in plan_pieces(budget)]
    assert sum(i.startswith("pretrain/") for i in listed) == 2  # one π^s per seed, for both learners
    assert "runs/STG1/pretrain-ppo/seed1" in listed and "ppo ×4" in " ".join(err.split())
    with pytest.raises(SystemExit):
        main(["reproduce", "--help"])
    assert "ppo and pretrain+ppo" in " ".join(capsys.readouterr().out.split())
