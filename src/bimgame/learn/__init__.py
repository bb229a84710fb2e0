"""Layer 4, learners: network settings and networks, the batched actor, A3C, pre-training, DAgger,
run directories, learning curves. No learner imports another; what they share is in
:mod:`bimgame.learn.common`, :mod:`bimgame.learn.nets`, :mod:`bimgame.learn.actor` and
:mod:`bimgame.learn.runs`."""
