"""The :class:`CostModel`: per-piece wall-time rates on the reference machine, from which each piece
kind (:mod:`bimgame.experiments.kinds`) estimates how long it takes. The numbers are estimates from
measured runs (where each comes from: ``docs/budgets.md``), not guarantees: a concurrent job on the
machine slows every piece down.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

from bimgame.experiments.budgets import Budget
from bimgame.sim.tasks import Task

__all__ = ["CostModel", "COSTS", "compute_rates", "eval_seconds"]


@dataclasses.dataclass(frozen=True)
class CostModel:
    """Per-piece wall-time estimates on an otherwise idle two-core machine (the reference machine
    of the README); a concurrent job slows every piece down. Each field says where its number comes
    from; the totals were checked against whole runs of the ``quick`` budget."""

    a3c_sps: Mapping[str, float] = dataclasses.field(
        default_factory=lambda: {"state": 9_000.0, "pixels": 3_900.0, "pixels-bf16": 4_500.0}
    )
    """A3C environment steps/s with 2 workers × 16 envs, scaled by workers/2 (state: 9,900 measured
    in the quick budget's runs on the idle machine, 2,000–3,000 while other training jobs ran;
    pixels: 3,942 for the paper's network in float32 in benchmarks/bench_a3c.py on the idle machine
    (1,870 under load); pixels-bf16: 4,506 for the network with auxiliary heads and asymmetric critic
    there, 3,200–4,300 in 1M-step STG1 runs with other work on the machine)."""
    a3c_overhead_s: float = 6.0
    """Per A3C run: starting the worker processes, the final evaluation, the curves figure."""
    ppo_sps: Mapping[str, float] = dataclasses.field(
        default_factory=lambda: {"state": 2_500.0, "pixels": 650.0, "pixels-bf16": 750.0}
    )
    """PPO environment steps/s in its one process with 16 envs and PPO's defaults (4 epochs of 4
    minibatches of 16-step sequences), evaluations apart (state: 2,100–2,900 in
    benchmarks/bench_learners.py's 300k-step STG1 runs, where A3C made 4,700–5,700 on the same
    machine; whole 128-step sequences made 2,400–2,500 on a faster machine where A3C made
    10,000–11,200; pixels-bf16: 0.30 of the state rate, as measured side by side with one torch
    thread on a loaded machine, 296 against 1,000 steps/s in short STG1 runs with auxiliary heads; pixels:
    A3C's float32/bf16 ratio, 0.87, applied to that)."""
    ppo_overhead_s: float = 4.0
    """Per PPO run: building the network and environments, the curves figure (its evaluations are
    counted apart: they stop its training while they run)."""
    expert_episode_s: Mapping[str, float] = dataclasses.field(
        default_factory=lambda: {"FULL": 2.3, "STG1": 0.6, "STG2": 1.0, "STG3": 1.5, "STG4": 2.0}
    )
    """One MPC expert episode on one core (FULL: 80 episodes took 90 s on two idle cores; STG1:
    ≈ 40 decisions of ≈ 16 ms; STG2–4 interpolated)."""
    expert_label_s: float = 0.016
    """One MPC decision (DAgger's label for one visited state)."""
    expert_steps: Mapping[str, float] = dataclasses.field(
        default_factory=lambda: {"FULL": 200.0, "STG1": 40.0, "STG2": 90.0, "STG3": 130.0, "STG4": 200.0}
    )
    """Mean length of an expert episode (the dataset's size in steps)."""
    train_frame_s: Mapping[str, float] = dataclasses.field(
        default_factory=lambda: {"state": 1.5e-4, "pixels": 8e-4, "pixels-bf16": 5.5e-4}
    )
    """Pre-training and DAgger: one frame through forward and backward, one thread (pixels: the
    README's ≈ 750 µs per sample at batch 16; pixels-bf16: the 0.6–0.7× that bf16 autocast measured
    for a segment's forward and backward; state: rough, from the quick budget's pre-trainings)."""
    pretrain_epochs_expected: float = 15.0
    """Epochs until early stopping typically ends a pre-training."""
    eval_step_s: Mapping[str, float] = dataclasses.field(
        default_factory=lambda: {"state": 4e-3, "pixels": 1.2e-2, "pixels-bf16": 1.0e-2}
    )
    """One batched evaluation step (all episodes of an evaluation side by side; rough)."""
    piece_overhead_s: float = 2.0
    """Per pre-training or DAgger piece: loading the dataset, building the network."""
    dagger_length_share: float = 0.35
    """DAgger after its first iteration: mean rollout length as a share of the time limit (the
    learner's failures run to it; 0.3 measured on STG1 in the quick budget)."""


COSTS = CostModel()


def eval_seconds(task: str, obs: str, episodes: int, costs: CostModel) -> float:
    """A greedy and a sampled batched evaluation that may run to the time limit."""
    return 0.0 if episodes == 0 else 2 * Task(task).time_limit * costs.eval_step_s[obs]


def compute_rates(budget: Budget) -> str:
    """The key of the rates of ``budget``'s networks' compute in the model's per-observation tables:
    pixels in bfloat16 have their own measured rates."""
    return "pixels-bf16" if budget.obs == "pixels" and budget.network.precision == "bf16" else budget.obs
