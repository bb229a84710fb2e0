"""PPO: proximal policy optimisation (Schulman et al., "Proximal Policy Optimization Algorithms",
2017) with the recurrent networks A3C uses (the paper's Conv-Conv-FC-LSTM on pixels, the MLP-LSTM on
state, optional auxiliary heads).

Each rollout, ``envs_per_worker`` environments act ``n_steps`` steps with the current network
(:class:`~bimgame.learn.rollout.RolloutCollector`, shared with A3C: time-limit bootstrap, LSTM state
carried across rollouts, episodes booked by the step they started at). The rollout's GAE advantages
and value targets come from the network that acted; then ``epochs`` passes of ``minibatches``
minibatches, each a set of whole environment sequences over which the LSTM is unrolled again from
the rollout's initial state (masked at episode starts), minimise the clipped surrogate, the value
loss (optionally clipped) and minus the entropy bonus, with Adam.

Actions are the paper's discrete ones or, with ``action_type="continuous"`` (``--action-type
continuous``), the env's continuous tilt changes under a diagonal Gaussian policy
(:mod:`bimgame.learn.policy_heads`): the loss takes log-probabilities and entropy from the network's
action distribution, whichever it is.

Modules: :mod:`~bimgame.learn.ppo.settings` (:class:`PPOConfig` and its optimisation part),
:mod:`~bimgame.learn.ppo.update` (the loss and the update of one rollout) and
:mod:`~bimgame.learn.ppo.training` (:func:`train_ppo`: the run directory, logs, checkpoints, resume).

Not yet: environments stepped in worker processes, a GPU device, and the fine-tuning terms and start
curricula A3C has (``--init`` does start from π^s).
"""

from bimgame.learn.ppo.settings import PPOConfig, PPOOptimizationSettings
from bimgame.learn.ppo.training import resolve_ppo_config, train_ppo
from bimgame.learn.ppo.update import ppo_minibatch_loss, ppo_update

__all__ = [
    "PPOConfig",
    "PPOOptimizationSettings",
    "train_ppo",
    "resolve_ppo_config",
    "ppo_update",
    "ppo_minibatch_loss",
]
