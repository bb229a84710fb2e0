"""Whether a reproduction's piece is finished (plan.piece_done), judged from its own outputs."""

from __future__ import annotations

import json

import torch

from bimgame.experiments.grid import plan_pieces
from bimgame.experiments.plan import piece_done
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
