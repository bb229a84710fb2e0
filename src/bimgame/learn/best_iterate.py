"""A run's best iterate: the weights whose in-run evaluation ranked best, kept in ``best.pt`` beside
the run's last weights (``checkpoint.pt``).

Why: the last weights of a run are not its best. DAgger's guarantee (Ross et al., 2011) is for the
best policy of its sequence, chosen on held-out episodes; on the easy labyrinth two more DAgger
iterations took a seed from 70% to 21% greedy success. PPO's in-run evaluations of one STG3 run from
π^s moved by 10-25 points between evaluations 50k steps apart. Selecting weights on validation
episodes, as Stable-Baselines3's ``EvalCallback`` keeps ``best_model``, is the usual answer.

The rank of an evaluation (:data:`~bimgame.learn.evaluations.EVAL_COLUMNS`) is (greedy + sampled
success rate, greedy + sampled mean return); a later evaluation replaces the best only when it ranks
strictly higher. The kept weights are a selection on the in-run evaluation's episodes (the task's
evaluation seeds), so their in-run numbers are optimistic: score ``best.pt`` on fresh episodes
(``bimgame score RUN/best.pt``, the benchmark protocol's own start seeds).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from bimgame.learn.checkpoints import load_checkpoint, save_checkpoint

__all__ = ["evaluation_rank", "is_better", "read_best", "save_best"]


def evaluation_rank(evaluation: dict[str, float]) -> list[float]:
    """The rank of an in-run ``evaluation`` (:data:`~bimgame.learn.evaluations.EVAL_COLUMNS`): success
    over both modes first, mean return over both modes to break ties."""
    return [
        float(evaluation["greedy_success_rate"] + evaluation["sampled_success_rate"]),
        float(evaluation["greedy_mean_return"] + evaluation["sampled_mean_return"]),
    ]


def is_better(evaluation: dict[str, float], best: dict[str, Any] | None) -> bool:
    """Whether an evaluation replaces the recorded ``best`` (a record with its ``rank``; None: none yet)."""
    return best is None or evaluation_rank(evaluation) > list(best["rank"])


def save_best(path: Path, model: dict[str, torch.Tensor], best: dict[str, Any]) -> Path:
    """Write the best iterate's weights ``model`` and its record ``best`` (``step``, ``rank`` and
    whatever else the learner keeps, e.g. DAgger's ``iteration``) to ``path``, atomically."""
    return save_checkpoint(path, model=model, **best)


def read_best(path: Path) -> dict[str, Any] | None:
    """The record (``step``, ``rank``) of the best iterate kept in ``path``; None when there is none."""
    if not path.is_file():
        return None
    payload = load_checkpoint(path)
    if "rank" not in payload:
        raise ValueError(f"{path} holds weights without a best iterate's rank: not a best.pt a run wrote")
    return {"step": int(payload["step"]), "rank": [float(value) for value in payload["rank"]]}
