"""Budgets and their validation, the pieces they plan and the cost estimates of the presets."""

from __future__ import annotations

import dataclasses

import pytest

from bimgame.experiments.budgets import ALGORITHMS, BUDGETS, budget_named
from bimgame.experiments.costs import estimate_seconds
from bimgame.experiments.grid import plan_pieces


@pytest.mark.parametrize("changes, message", [
    ({"tasks": ("STG9",)}, r"Budget.tasks: unknown task 'STG9'; allowed: FULL, STG1, STG2, STG3, STG4"),
    ({"tasks": ()}, r"Budget.tasks must name at least one task"),
    ({"algorithms": ("ppo",)}, r"Budget.algorithms: unknown \['ppo'\]; allowed: a3c, pretrain\+a3c"),
    ({"seeds": 0}, r"Budget.seeds must be an integer >= 1, got 0"),
    ({"obs": "rgb"}, r"Budget.obs must be one of pixels, state, got 'rgb'"),
    ({"threshold_fraction": 0.0}, r"Budget.threshold_fraction must be in \(0, 1\], got 0.0"),
    ({"tasks": ("STG2",), "a3c_steps": {"STG1": 10}}, r"Budget.a3c_steps has no entry for \['STG2'\]"),
    ({"a3c_steps": {"STG1": 0}}, r"Budget.a3c_steps\['STG1'\] must be an integer >= 1, got 0"),
    ({"tasks": ("STG2",), "dataset_task": "STG1", "a3c_steps": {"STG2": 10}},
     r"Budget.dataset_task STG1 cannot label \['STG2'\].*dataset_task='FULL'"),
])
def test_bad_budgets_are_rejected_naming_the_field_and_what_is_allowed(changes, message, tiny_budget):
    with pytest.raises(ValueError, match=message):
        dataclasses.replace(tiny_budget, **changes)
    with pytest.raises(ValueError, match="unknown budget 'huge'; allowed: quick, paper"):
        budget_named("huge")


def test_plan_of_the_presets_and_their_estimates():
    quick, paper = BUDGETS["quick"], BUDGETS["paper"]
    pieces = plan_pieces(quick)
    assert [p.id for p in pieces[:8]] == [
        "data", "pretrain/STG1/policy-seed0", "pretrain/STG1/value-seed0", "runs/STG1/a3c/seed0",
        "runs/STG1/pretrain-a3c/seed0", "runs/STG1/a3c-value/seed0", "runs/STG1/pretrain-a3c-value/seed0",
        "runs/STG1/dagger/seed0"]
    assert len(pieces) == 1 + 2 * 2 + 2 * len(ALGORITHMS) and len({p.id for p in pieces}) == len(pieces)
    by_id = {p.id: p for p in pieces}
    assert by_id["runs/STG1/pretrain-a3c-value/seed1"].needs == ("pretrain/STG1/policy-seed1",
                                                                  "pretrain/STG1/value-seed1")
    assert by_id["runs/STG1/a3c/seed1"].needs == () and by_id["runs/STG1/dagger/seed1"].needs == ()
    # Pieces run only after what they need.
    order = [p.id for p in pieces]
    assert all(order.index(n) < order.index(p.id) for p in pieces for n in p.needs)
    quick_seconds = sum(estimate_seconds(p, quick) for p in pieces)
    paper_seconds = sum(estimate_seconds(p, paper) for p in plan_pieces(paper))
    assert 5 * 60 < quick_seconds < 30 * 60  # the quick budget's promise, on an idle two-core machine
    assert paper_seconds > 24 * 3600
    # Only the pieces the algorithms need are planned.
    ids = [p.id for p in plan_pieces(quick.with_grid(algorithms=["dagger", "a3c"], seeds=1))]
    assert ids == ["data", "runs/STG1/a3c/seed0", "runs/STG1/dagger/seed0"]
