"""DAgger's best iterate: the weights of the iteration whose in-run evaluation was best, kept in
``best.pt`` beside the run's last weights (``checkpoint.pt``).

Why: retraining on the whole aggregate does not hold on to a good policy. On the easy labyrinth the
in-run evaluations of one run jumped 10-50 points between iterations, and two more iterations took a
seed from 70% to 21% greedy success. DAgger's guarantee (Ross et al., 2011) is for the best policy
of the sequence, chosen on held-out episodes, not for the last one, so the run keeps that one too.

The rank of an iteration is (greedy + sampled success rate, greedy + sampled mean return) of its
in-run evaluation (``eval_episodes`` per mode, from the task's evaluation seeds); a later iteration
replaces the best only when it ranks strictly higher. A run without in-run evaluation keeps no best.
The scores of the kept iterate are a selection on those episodes, so they are optimistic: score
``best.pt`` on fresh episodes (``bimgame score RUN/best.pt``), as the benchmark does.

The record of the best (``state["best"]``: iteration, step, rank) is part of the counts the checkpoint
commits; ``best.pt`` is written after that commit. A run stopped between the two is repaired on
resume: the best then is the last finished iteration, whose weights are the checkpoint's.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from bimgame.learn.checkpoints import load_checkpoint, save_checkpoint
from bimgame.learn.run_dir import DAGGER_BEST as BEST

__all__ = ["BEST", "evaluation_rank", "is_better", "repair_best", "save_best"]


def evaluation_rank(evaluation: dict[str, float]) -> list[float]:
    """The rank of an in-run ``evaluation`` (:data:`~bimgame.learn.evaluations.EVAL_COLUMNS`): success
    over both modes first, mean return over both modes to break ties."""
    return [
        float(evaluation["greedy_success_rate"] + evaluation["sampled_success_rate"]),
        float(evaluation["greedy_mean_return"] + evaluation["sampled_mean_return"]),
    ]


def is_better(evaluation: dict[str, float], best: dict[str, Any] | None) -> bool:
    """Whether an iteration with ``evaluation`` replaces the recorded ``best`` (None: none yet)."""
    return best is None or evaluation_rank(evaluation) > list(best["rank"])


def save_best(path: Path, model: dict[str, torch.Tensor], best: dict[str, Any]) -> Path:
    """Write the best iterate's weights ``model`` and its record ``best`` to ``path``, atomically."""
    return save_checkpoint(path, model=model, step=best["step"], iteration=best["iteration"], rank=best["rank"])


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
