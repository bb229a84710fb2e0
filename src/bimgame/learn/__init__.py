"""Layer 4, learners: network settings and networks, the batched actor, the rollout collector, A3C
(:mod:`bimgame.learn.a3c`), pre-training, DAgger (:mod:`bimgame.learn.dagger`), run directories,
learning curves. No learner imports another; what they share is in :mod:`bimgame.learn.common`,
:mod:`bimgame.learn.learner_settings`, :mod:`bimgame.learn.nets`, :mod:`bimgame.learn.actor`,
:mod:`bimgame.learn.rollout`, :mod:`bimgame.learn.runs`, :mod:`bimgame.learn.checkpoints` and
:mod:`bimgame.learn.metric_logs`."""
