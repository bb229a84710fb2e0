"""Layer 2, the puzzle as Gymnasium environments: the single env, the batched vector env,
observations, reward-shaping wrappers. Imports only :mod:`bimgame.sim` and :mod:`bimgame.util`."""
