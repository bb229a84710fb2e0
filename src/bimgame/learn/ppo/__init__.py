"""PPO: proximal policy optimisation (Schulman et al., "Proximal Policy Optimization Algorithms",
2017) with the recurrent networks A3C uses (the paper's Conv-Conv-FC-LSTM on pixels, the MLP-LSTM on
state, optional auxiliary heads).

Each rollout, ``envs_per_worker`` environments act ``n_steps`` steps with the current network
(:class:`~bimgame.learn.rollout.RolloutCollector`, shared with A3C: time-limit bootstrap, LSTM state
carried across rollouts, episodes booked by the step they started at). The rollout's GAE advantages
and value targets come from the network that acted; then ``epochs`` passes of ``minibatches``
minibatches, each a set of whole sequences over which the LSTM is unrolled again — each
environment's rollout from the state it started with, or with ``sequence_length`` its pieces from the
acting network's stored states (masked at episode starts) — minimise the clipped surrogate, the value
loss (optionally clipped) and minus the entropy bonus, with Adam.

Actions are the paper's discrete ones or, with ``action_type="continuous"`` (``--action-type
continuous``), the env's continuous tilt changes under a diagonal Gaussian policy
(:mod:`bimgame.learn.policy_heads`): the loss takes log-probabilities and entropy from the network's
action distribution, whichever it is.

Beyond one process: ``collectors`` child processes step the environments and act while this process
updates (:mod:`~bimgame.learn.ppo.collectors`; with ``policy_lag`` 1 the two overlap); ``workers``
ranks, each with its own environments, average every minibatch's gradient
(:mod:`~bimgame.learn.ppo.parallel`); ``device`` puts the update on a GPU while the
environments and the acting network stay on the CPU (:mod:`bimgame.learn.devices`). Fine-tuning from
π^s (``--init``) can keep it with kickstarting's KL (:class:`~bimgame.learn.ppo.settings.PPOFinetuneSettings`).

Modules: :mod:`~bimgame.learn.ppo.settings` (:class:`PPOConfig` and its parts),
:mod:`~bimgame.learn.ppo.update` (the loss and the update of one rollout),
:mod:`~bimgame.learn.ppo.learner` (one rank: its collector and update),
:mod:`~bimgame.learn.ppo.collectors` (the environments, here or in collector processes),
:mod:`~bimgame.learn.ppo.processes` (messages between processes),
:mod:`~bimgame.learn.ppo.parallel` (the worker processes) and :mod:`~bimgame.learn.ppo.training`
(:func:`train_ppo`: the run directory, logs, checkpoints, resume).

Tasks: the circular maze's and CyberRunner's labyrinth's (``LABYRINTH-EASY`` …, state observations;
:mod:`bimgame.envs.puzzles`). An episode's success is the env's own where it reports one (a labyrinth
episode also ends in a hole). The network's actions are discrete unless ``action_type="continuous"``
(CyberRunner's own actions are continuous), and the env is built with the network's.

Start curricula are A3C's (:mod:`bimgame.learn.curricula`: ``demo`` and ``reverse`` on the maze,
``reverse`` along the printed path on the labyrinth), each rank its own; a resumed run starts its
curriculum again from the first stage. Not yet: A3C's critic warm-up, actor ramp, behaviour cloning
and reward shaping.
"""

from bimgame.learn.ppo.settings import PPOConfig, PPOFinetuneSettings, PPOOptimizationSettings
from bimgame.learn.ppo.training import resolve_ppo_config, train_ppo
from bimgame.learn.ppo.update import ppo_minibatch_loss, ppo_update

__all__ = [
    "PPOConfig",
    "PPOOptimizationSettings",
    "PPOFinetuneSettings",
    "train_ppo",
    "resolve_ppo_config",
    "ppo_update",
    "ppo_minibatch_loss",
]
