"""DAgger's best iterate: the weights of the iteration whose in-run evaluation was best, kept in
``best.pt`` beside the run's last weights (``checkpoint.pt``).

Why: retraining on the whole aggregate does not hold on to a good policy. On the easy labyrinth the
in-run evaluations of one run jumped 10-50 points between iterations, and two more iterations took a
seed from 70% to 21% greedy success. DAgger's guarantee (Ross et al., 2011) is for the best policy
of the sequence, chosen on held-out episodes, not for the last one, so the run keeps that one too.

Iterations are ranked by their in-run evaluation (``eval_episodes`` per mode) as every learner's
best iterate is (:mod:`bimgame.learn.best_iterate`). A run without in-run evaluation keeps no best.

The record of the best (``state["best"]``: iteration, step, rank) is part of the counts the checkpoint
commits; ``best.pt`` is written after that commit. A run stopped between the two is repaired on
resume: the best then is the last finished iteration, whose weights are the checkpoint's.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from bimgame.learn.best_iterate import save_best
from bimgame.learn.checkpoints import load_checkpoint

__all__ = ["repair_best"]


def repair_best(
    path: Path, model: dict[str, torch.Tensor], best: dict[str, Any] | None, finished_iterations: int
) -> bool:
    """Rewrite ``path`` with the checkpoint's weights ``model`` (those of the last of
    ``finished_iterations``) when the recorded ``best`` is that iteration but ``path`` does not hold
    it (a run stopped after the commit, before ``best.pt`` was written); returns whether it did. No
    other mismatch can happen: an earlier best's weights were written before the next iteration began."""
    if best is None or best["iteration"] != finished_iterations - 1:
        return False
    if path.is_file() and load_checkpoint(path).get("iteration") == best["iteration"]:
        return False
    save_best(path, model, best)
    return True
