"""What the labyrinth's planner (:class:`~bimgame.expert.labyrinth_mpc.LabyrinthMPC`) rolls its sampled
sequences out in: a protocol, so the simulator (the expert) and a model fitted from experience
(:mod:`bimgame.learn.model_based`) plug into the same planner and score alike."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["PlanningModel"]


@runtime_checkable
class PlanningModel(Protocol):
    """What the planner needs of its model: :class:`~bimgame.sim.labyrinth_physics.LabyrinthSim` is one
    (its full physics state), :class:`bimgame.learn.model_based.MarbleModel` another (the marble's
    observed state)."""

    @property
    def state_size(self) -> int:
        """Length of the state vector the model rolls out from."""
        ...

    def rollout(self, state: np.ndarray, controls: np.ndarray, nthread: int = 1) -> np.ndarray:
        """(K, H, state_size) states after each of the (K, H, 2) tilt changes (rad) from ``state``."""
        ...

    def marble_xy_of(self, states: np.ndarray) -> np.ndarray:
        """The marble's board-frame (x, y) (m) of states (..., state_size): (..., 2)."""
        ...

    def close(self) -> None:
        """Free what the model holds."""
        ...
