"""How long a piece of a reproduction takes: the :class:`CostModel` of per-piece wall times on the
reference machine and :func:`estimate_seconds`, which ``bimgame reproduce`` prints before it starts
(``--dry-run`` per piece), stores in ``plan.json`` and uses to weight its progress bar.

The numbers are estimates from measured runs (each field says where its number comes from), not
guarantees: a concurrent job on the machine slows every piece down.
"""

from __future__ import annotations

import dataclasses
from typing import Mapping

from bimgame.experiments.budgets import Budget
from bimgame.experiments.grid import PIECE_KINDS, Piece
from bimgame.sim.tasks import Task

__all__ = ["CostModel", "COSTS", "estimate_seconds", "piece_cpus", "cluster_seconds", "format_duration"]


@dataclasses.dataclass(frozen=True)
class CostModel:
    """Per-piece wall-time estimates on an otherwise idle two-core machine (the reference machine
    of the README); a concurrent job slows every piece down. Each field says where its number comes
    from; the totals were checked against whole runs of the ``quick`` budget."""

    a3c_sps: Mapping[str, float] = dataclasses.field(default_factory=lambda: {
        "state": 9_000.0, "pixels": 3_900.0, "pixels-bf16": 4_500.0})
    """A3C environment steps/s with 2 workers × 16 envs, scaled by workers/2 (state: 9,900 measured
    in the quick budget's runs on the idle machine, 2,000–3,000 while other training jobs ran;
    pixels: 3,942 for the paper's network in float32 in benchmarks/bench_a3c.py on the idle machine
    (1,870 under load); pixels-bf16: 4,506 for the network with auxiliary heads and asymmetric critic
    there, 3,200–4,300 in 1M-step STG1 runs with other work on the machine)."""
    a3c_overhead_s: float = 6.0
    """Per A3C run: starting the worker processes, the final evaluation, the curves figure."""
    expert_episode_s: Mapping[str, float] = dataclasses.field(default_factory=lambda: {
        "FULL": 2.3, "STG1": 0.6, "STG2": 1.0, "STG3": 1.5, "STG4": 2.0})
    """One MPC expert episode on one core (FULL: 80 episodes took 90 s on two idle cores; STG1:
    ≈ 40 decisions of ≈ 16 ms; STG2–4 interpolated)."""
    expert_label_s: float = 0.016
    """One MPC decision (DAgger's label for one visited state)."""
    expert_steps: Mapping[str, float] = dataclasses.field(default_factory=lambda: {
        "FULL": 200.0, "STG1": 40.0, "STG2": 90.0, "STG3": 130.0, "STG4": 200.0})
    """Mean length of an expert episode (the dataset's size in steps)."""
    train_frame_s: Mapping[str, float] = dataclasses.field(default_factory=lambda: {
        "state": 1.5e-4, "pixels": 8e-4, "pixels-bf16": 5.5e-4})
    """Pre-training and DAgger: one frame through forward and backward, one thread (pixels: the
    README's ≈ 750 µs per sample at batch 16; pixels-bf16: the 0.6–0.7× that bf16 autocast measured
    for a segment's forward and backward; state: rough, from the quick budget's pre-trainings)."""
    pretrain_epochs_expected: float = 15.0
    """Epochs until early stopping typically ends a pre-training."""
    eval_step_s: Mapping[str, float] = dataclasses.field(default_factory=lambda: {
        "state": 4e-3, "pixels": 1.2e-2, "pixels-bf16": 1.0e-2})
    """One batched evaluation step (all episodes of an evaluation side by side; rough)."""
    piece_overhead_s: float = 2.0
    """Per pre-training or DAgger piece: loading the dataset, building the network."""
    dagger_length_share: float = 0.35
    """DAgger after its first iteration: mean rollout length as a share of the time limit (the
    learner's failures run to it; 0.3 measured on STG1 in the quick budget)."""


COSTS = CostModel()


def _eval_seconds(task: str, obs: str, episodes: int, costs: CostModel) -> float:
    """A greedy and a sampled batched evaluation that may run to the time limit."""
    return 0.0 if episodes == 0 else 2 * Task(task).time_limit * costs.eval_step_s[obs]


def estimate_seconds(piece: Piece, budget: Budget, costs: CostModel = COSTS) -> float:
    """Expected wall time of one piece (see :class:`CostModel`)."""
    # The rates of the network's compute: pixels in bfloat16 have their own measured rates.
    obs = "pixels-bf16" if budget.obs == "pixels" and budget.precision == "bf16" else budget.obs
    if piece.kind == "dataset":
        per_episode = costs.expert_episode_s[budget.dataset_task]
        return costs.piece_overhead_s + budget.dataset_episodes * per_episode / min(budget.dataset_workers, 2)
    task = piece.task or budget.dataset_task
    frames = budget.dataset_episodes * costs.expert_steps[task] * 0.8  # 20% held out
    if piece.kind == "pretrain-policy":
        epochs = min(budget.pretrain_epochs, costs.pretrain_epochs_expected)
        return (costs.piece_overhead_s + epochs * frames * costs.train_frame_s[obs]
                + _eval_seconds(task, obs, budget.pretrain_eval_episodes, costs))
    if piece.kind == "pretrain-value":
        epochs = min(budget.value_epochs, 2 * costs.pretrain_epochs_expected)
        return costs.piece_overhead_s + epochs * frames * costs.train_frame_s[obs] / 3  # feed-forward
    if piece.kind == "a3c":
        sps = costs.a3c_sps[obs] * min(budget.workers, 2) / 2
        return costs.a3c_overhead_s + budget.steps_for(task) / sps
    if piece.kind == "dagger":
        seconds = costs.piece_overhead_s
        aggregated = 0.0
        for iteration in range(budget.dagger_iterations):
            # Iteration 0 follows the expert; later ones mostly the learner, whose failures run long.
            length = costs.expert_steps[task] if iteration == 0 else costs.dagger_length_share * Task(task).time_limit
            labels = budget.dagger_episodes * length
            aggregated += labels
            seconds += (labels * costs.expert_label_s + budget.dagger_epochs * aggregated * costs.train_frame_s[obs]
                        + _eval_seconds(task, obs, budget.dagger_eval_episodes, costs))
        return seconds
    raise ValueError(f"unknown piece kind {piece.kind!r}; allowed: {', '.join(PIECE_KINDS)}")


def piece_cpus(piece: Piece, budget: Budget) -> int:
    """The CPUs ``piece`` keeps busy, which a cluster reserves for it: an A3C run its workers plus its
    evaluator process (when it evaluates during training); the dataset its expert worker processes;
    a pre-training or DAgger run its torch threads (the budget's ``torch_threads``)."""
    if piece.kind == "a3c":
        return budget.workers + (1 if budget.eval_every > 0 else 0)
    if piece.kind == "dataset":
        return budget.dataset_workers
    return budget.torch_threads


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
