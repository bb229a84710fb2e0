"""Layer 2, the puzzle as Gymnasium environments: the single env, the batched vector env,
observations, reward-shaping wrappers, domain randomisation. Imports only :mod:`bimgame.sim` and
:mod:`bimgame.util`."""

from bimgame.envs.randomization import Randomization

__all__ = ["Randomization"]
