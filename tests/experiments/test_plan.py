"""Whether a reproduction's piece is finished (plan.piece_done), judged from its own outputs; and a
reproduction directory whose plan.json stores the budget as earlier versions did (flat) continues."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from bimgame.experiments.budgets import BUDGETS
from bimgame.experiments.grid import plan_pieces
from bimgame.experiments.plan import PLAN, check_compatible, load_plan, piece_done, write_plan
from bimgame.learn.checkpoints import save_checkpoint


def test_an_a3c_run_stopped_in_its_final_evaluation_is_resumed_not_taken_as_finished(tmp_path, tiny_budget):
    """Its checkpoint holds all its steps but it has no summary.json: A3C's resume evaluates it and writes
    the summary (it used to count as finished, its summary and final evaluation never written)."""
    piece = next(p for p in plan_pieces(tiny_budget) if p.kind == "a3c")
    run = tmp_path / piece.path
    steps = tiny_budget.steps_for(piece.task)
    save_checkpoint(run / "checkpoint.pt", model={"w": torch.zeros(1)}, step=steps)
    assert not piece_done(piece, tmp_path, tiny_budget)
    (run / "summary.json").write_text(json.dumps({"stopped": "interrupted", "steps": steps - 1}))
    assert not piece_done(piece, tmp_path, tiny_budget)
    (run / "summary.json").write_text(json.dumps({"stopped": "finished", "steps": steps}))
    assert piece_done(piece, tmp_path, tiny_budget)


def test_a_reproduction_whose_plan_stores_a_flat_budget_continues_with_the_same_budget(tmp_path):
    quick = BUDGETS["quick"]
    write_plan(tmp_path, quick)
    plan = json.loads((tmp_path / PLAN).read_text())
    flat = json.loads((Path(__file__).parent / "data" / "quick_budget_flat.json").read_text())
    (tmp_path / PLAN).write_text(json.dumps({**plan, "budget": flat}))
    budget, pieces = load_plan(tmp_path)
    assert budget == quick and pieces == plan_pieces(quick)
    # The same budget, another grid, or the pixel-only background switch (state here): the directory continues.
    check_compatible(tmp_path, quick)
    check_compatible(tmp_path, quick.with_grid(tasks=["STG1"], algorithms=["a3c"], seeds=5))
    check_compatible(tmp_path, quick.replace(network={"subtract_background": False}))
    # Settings that change what a piece computes are refused, named by their paths.
    with pytest.raises(ValueError, match=r"other settings \(dagger\.episodes: 6 there, 3 now; "
                                         r"torch_threads: 1 there, 2 now\)"):
        check_compatible(tmp_path, quick.replace(dagger={"episodes": 3}, torch_threads=2))


def test_a_reproduction_whose_plan_was_stored_before_the_ppo_group_continues_with_its_preset(tmp_path):
    """A nested ``plan.json`` of a reproduction started before PPO was in the reproduction has no
    ``ppo`` group: it loads with PPO's defaults, which the presets keep, and may add PPO's algorithms."""
    beyond = BUDGETS["beyond"]
    write_plan(tmp_path, beyond)
    plan = json.loads((tmp_path / PLAN).read_text())
    del plan["budget"]["ppo"]
    (tmp_path / PLAN).write_text(json.dumps(plan))
    budget, pieces = load_plan(tmp_path)
    assert budget == beyond and pieces == plan_pieces(beyond)
    check_compatible(tmp_path, beyond.with_grid(algorithms=["a3c", "pretrain+a3c", "ppo", "pretrain+ppo"]))
    with pytest.raises(ValueError, match=r"other settings \(ppo\.n_steps: 128 there, 64 now\)"):
        check_compatible(tmp_path, beyond.replace(ppo={"n_steps": 64}))
