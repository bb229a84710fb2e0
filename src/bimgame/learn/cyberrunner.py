"""CyberRunner's observation of the labyrinth as a learner's network reads it (``obs="cyberrunner"``):
which network settings apply to it, and the network's sizes.

The learners move one tensor per step, so the env gives the observation in its flat form
(:func:`~bimgame.envs.labyrinth_cyberrunner.flatten_cyberrunner`: the 64×64 crop, then tilt and position, then
the path ahead; :meth:`~bimgame.envs.puzzles.Puzzle.vector_env` steps ``cyberrunner`` as
``cyberrunner_flat``) and the network's :class:`~bimgame.learn.encoders.CyberRunnerEncoder` splits it
again. The pixel network's extras are the circular maze's and are refused by name (:data:`NOT_CYBERRUNNER`);
``precision`` (bf16 autocast of the encoder), ``tilt_input``, ``asymmetric_critic`` (which reads
the labyrinth's 17-value state) and ``motion`` (the marble's observed velocity after the path ahead:
:mod:`bimgame.envs.labyrinth_cyberrunner`) apply.
"""

from __future__ import annotations

from typing import Any

from bimgame.envs.labyrinth_cyberrunner import cyberrunner_flat_size
from bimgame.learn.nets import NetConfig
from bimgame.sim.labyrinth import LabyrinthSpec

__all__ = ["NOT_CYBERRUNNER", "check_cyberrunner_network", "cyberrunner_net_config"]

#: The network switches that do not apply to CyberRunner's observations, and why.
NOT_CYBERRUNNER = {
    "keypoints": "the CyberRunner encoder has no keypoints (pixels only)",
    "subtract_background": "it subtracts the empty board from a whole-board 84×84 frame (pixels only)",
    "aux_heads": "the observation already holds the state the auxiliary heads would predict (the marble's "
    "position and the path points ahead; asymmetric_critic reads the labyrinth's state)",
    "maze_encoding": "the encoding is of a circular maze's walls",
}


def check_cyberrunner_network(owner: str, network: Any) -> None:
    """Raise ``ValueError`` naming ``owner``'s first setting of ``network`` (a
    :class:`~bimgame.learn.common.NetworkSettings`) that does not apply to CyberRunner's observations
    (nothing unless its ``obs`` is ``cyberrunner``)."""
    if network.obs != "cyberrunner":
        return
    for name, why in NOT_CYBERRUNNER.items():
        if getattr(network, name):
            raise ValueError(f"{owner}.{name} does not apply to obs 'cyberrunner': {why}")
    if network.maze_frame != "board":
        raise ValueError(f"{owner}.maze_frame does not apply to obs 'cyberrunner': it turns a circular maze's encoding")


def cyberrunner_net_config(network: Any, spec: Any, privileged: dict[str, Any]) -> NetConfig:
    """The :class:`~bimgame.learn.nets.NetConfig` of ``network`` (a
    :class:`~bimgame.learn.common.NetworkSettings` with ``obs="cyberrunner"``, its sizes filled in) on
    CyberRunner's flat observations of the labyrinth ``spec`` (a circular maze's is refused: it has no
    such observation); ``privileged`` the asymmetric critic's NetConfig settings ({} without one)."""
    if not isinstance(spec, LabyrinthSpec):
        raise ValueError("obs 'cyberrunner' is CyberRunner's observation of the labyrinth, not of a circular maze")
    sizes = {name: getattr(network, name) for name in ("features", "hidden", "tilt_input", "action_type", "precision")}
    shape = (cyberrunner_flat_size(network.motion),)
    return NetConfig(encoder="cyberrunner", obs_shape=shape, **sizes, **privileged)
