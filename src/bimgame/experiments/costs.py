"""How long a piece of a reproduction takes and what it occupies: :func:`estimate_seconds` (each
piece kind's estimate from the :class:`~bimgame.experiments.cost_model.CostModel`), which
``bimgame reproduce`` prints before it starts (``--dry-run`` per piece), stores in ``plan.json`` and
uses to weight its progress bar; :func:`piece_cpus`; :func:`cluster_seconds` for a Ray cluster.
"""

from __future__ import annotations

from bimgame.experiments.budgets import Budget
from bimgame.experiments.cost_model import COSTS, CostModel
from bimgame.experiments.grid import Piece
from bimgame.experiments.kinds import kind_of

__all__ = ["CostModel", "COSTS", "estimate_seconds", "piece_cpus", "cluster_seconds", "format_duration"]


def estimate_seconds(piece: Piece, budget: Budget, costs: CostModel = COSTS) -> float:
    """Expected wall time of one piece (its kind's estimate from :class:`CostModel`)."""
    return kind_of(piece).seconds(piece, budget, costs)


def piece_cpus(piece: Piece, budget: Budget) -> int:
    """The CPUs ``piece`` keeps busy, which a cluster reserves for it: an A3C run its workers plus its
    evaluator process (when it evaluates during training); the dataset its expert worker processes;
    a pre-training, DAgger or PPO run its torch threads (the budget's ``torch_threads``)."""
    return kind_of(piece).cpus(piece, budget)


def cluster_seconds(pieces: list[Piece], budget: Budget, cpus: float, costs: CostModel = COSTS) -> float:
    """Expected wall time of ``pieces`` on a cluster of ``cpus`` CPUs: the CPU time they reserve
    (each piece's estimate times its :func:`piece_cpus`) spread over the CPUs, and never less than
    the longest chain of pieces that wait for one another (pieces already finished cost nothing)."""
    if cpus <= 0:
        raise ValueError(f"a cluster needs CPUs to run pieces, got {cpus!r}")
    estimates = {p.id: estimate_seconds(p, budget, costs) for p in pieces}
    chain: dict[str, float] = {}
    for piece in pieces:  # the plan's order puts every piece after the pieces it needs
        chain[piece.id] = estimates[piece.id] + max((chain.get(n, 0.0) for n in piece.needs), default=0.0)
    spread = sum(estimates[p.id] * piece_cpus(p, budget) for p in pieces) / cpus
    return max(spread, max(chain.values(), default=0.0))


def format_duration(seconds: float) -> str:
    """``95`` → ``1.6 min``, ``7200`` → ``2.0 h``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"
