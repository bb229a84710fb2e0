"""A3C: asynchronous advantage actor-critic (Mnih et al., "Asynchronous Methods for Deep
Reinforcement Learning", ICML 2016) with a recurrent network, as the BiMGame paper trained it.

``workers`` processes each own a copy of the environment (``envs_per_worker`` of them, stepped as
one batch) and a local copy of the network. Each repeatedly

1. copies the shared weights into its local network,
2. acts for ``n_steps`` steps (one batched no-grad forward per step),
3. computes n-step returns (or GAE), the policy-gradient, value and entropy losses over the segment
   — unrolling the LSTM from the state it had at the segment's start, so the gradient is exactly
   that of the policy that acted,
4. clips the gradient norm and applies it to the *shared* weights with the *shared* optimiser
   statistics, without locks (Hogwild).

With ``envs_per_worker=1`` this is exactly the paper's A3C. A separate evaluator process
periodically runs greedy and sampled episodes with the shared weights. The parent process only
orchestrates: it logs what workers report, shows progress, writes checkpoints, and stops everything
on Ctrl-C, on a non-finite loss, or when the step budget is spent.

Why our own implementation: no maintained library ships recurrent A3C for PyTorch (RLlib removed
A3C; Stable-Baselines3 has no recurrent A2C).

The package's modules, one job each: :mod:`~bimgame.learn.a3c.settings` (:class:`A3CConfig` and
its optimisation part), :mod:`~bimgame.learn.a3c.update` (the network, shared optimiser, loss and
Hogwild update the processes share), :mod:`~bimgame.learn.a3c.workers` (the worker and evaluator
processes), :mod:`~bimgame.learn.a3c.parent` (the parent's side of a session) and
:mod:`~bimgame.learn.a3c.training` (:func:`train`: the run directory, resume, the final evaluation).
The public API is importable from the package.
"""

from bimgame.learn.a3c.settings import OPTIMIZERS, A3CConfig, OptimizationSettings
from bimgame.learn.a3c.training import resolve_config, train
from bimgame.learn.a3c.update import (
    a3c_segment_loss,
    apply_update,
    make_optimizer,
    network_for,
    shared_optimizer_state,
)
from bimgame.learn.learner_settings import MAX_STEPS, START_CURRICULA
from bimgame.learn.rewards import EnvWrapper
from bimgame.learn.run_dir import TrainingError, TrainResult

__all__ = [
    "A3CConfig",
    "OptimizationSettings",
    "TrainingError",
    "TrainResult",
    "train",
    "resolve_config",
    "network_for",
    "make_optimizer",
    "OPTIMIZERS",
    "START_CURRICULA",
    "MAX_STEPS",
    "EnvWrapper",
    "a3c_segment_loss",
    "apply_update",
    "shared_optimizer_state",
]
