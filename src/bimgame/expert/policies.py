"""Scripted policies, which learn nothing, by name: uniformly random, no-op, a controller that tilts
the board down the geodesic-distance slope (baselines for sanity checks), and the MPC expert of
:mod:`bimgame.expert.mpc` acting on the env's simulator state (for demos and evaluation). Each maps
the env itself to an action; the learned policies (networks acting on observations) are
:mod:`bimgame.learn.actor`'s."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from bimgame.expert.mpc import RandomShootingMPC
from bimgame.sim.maze import MazeSpec

__all__ = ["Policy", "RandomPolicy", "NoopPolicy", "GeodesicPolicy", "ExpertPolicy", "POLICIES", "make_policy"]


class Policy(Protocol):
    """Maps the env (for its true state) to a discrete action."""

    def __call__(self, env) -> int: ...


class RandomPolicy:
    """Uniformly random discrete actions from a seeded generator."""

    def __init__(self, rng: np.random.Generator):
        self.rng = rng

    def __call__(self, env) -> int:
        return int(self.rng.integers(5))


class NoopPolicy:
    """Never tilts the board."""

    def __call__(self, env) -> int:
        return 0


DAMPING = 4.0  # chosen by measurement (STG1 92%, STG2 83% over 12 seeds)
EPS = 3e-3  # gradient probe spacing (m): wide enough to "see" a gate before passing it


class GeodesicPolicy:
    """Tilt towards the direction that shortens the geodesic distance to the task's goal (the
    centre for FULL, the far side of the k-th wall for STGk).

    The desired board-frame acceleration is the negative gradient of the geodesic distance (a
    unit vector) minus a velocity damping term; the target tilt is that direction scaled to the
    tilt limit, and the policy takes the discrete action that moves the commanded tilt towards it
    (largest error axis first). Rolling towards +x needs a tilt about +y of +θ (it lowers the +x
    edge) and towards +y a tilt about +x of -θ (see ``BallInMazeEnv``'s action description).
    """

    def __init__(self, spec: MazeSpec, damping: float = DAMPING, eps: float = EPS):
        self.spec = spec
        self.damping = damping
        self.eps = eps

    def __call__(self, env) -> int:
        sim = env.unwrapped.sim
        to_channel = env.unwrapped.task.goal_channel(self.spec)
        positions, velocities = sim.marble_kinematics()
        x, y = positions[0, 0], positions[0, 1]
        e = self.eps
        geodesic = self.spec.geodesic_distance_one
        gradient = np.array(
            [
                geodesic(x + e, y, to_channel) - geodesic(x - e, y, to_channel),
                geodesic(x, y + e, to_channel) - geodesic(x, y - e, to_channel),
            ]
        ) / (2 * e)
        norm = float(np.hypot(*gradient))
        direction = -gradient / norm if norm > 0 else np.zeros(2)
        desired = direction - self.damping * velocities[0, :2]
        desired_norm = float(np.hypot(*desired))
        if desired_norm > 1:
            desired /= desired_norm
        limit = self.spec.max_tilt
        target = np.array([-desired[1] * limit, desired[0] * limit])  # (about x, about y)
        error = target - sim.target_tilt
        step = self.spec.tilt_step
        axis = int(np.argmax(np.abs(error)))
        if abs(error[axis]) < 0.5 * step:
            return 0
        if axis == 0:
            return 1 if error[0] > 0 else 2
        return 3 if error[1] > 0 else 4


class ExpertPolicy:
    """The random-shooting MPC expert (default settings) acting on the env's true simulator state."""

    def __init__(self, spec: MazeSpec, rng: np.random.Generator):
        self.spec = spec
        self.rng = rng
        self._expert: RandomShootingMPC | None = None

    def __call__(self, env) -> int:
        unwrapped = env.unwrapped
        if self._expert is None or self._expert.task is not unwrapped.task:
            self._expert = RandomShootingMPC(
                self.spec, rng=self.rng, task=unwrapped.task, n_marbles=unwrapped.n_marbles
            )
        return self._expert.act(unwrapped.sim.get_state())


POLICIES = ("random", "noop", "geodesic", "expert")


def make_policy(name: str, spec: MazeSpec, rng: np.random.Generator) -> Policy:
    """A policy by name; raises ``ValueError`` naming the allowed ones."""
    if name == "random":
        return RandomPolicy(rng)
    if name == "noop":
        return NoopPolicy()
    if name == "geodesic":
        return GeodesicPolicy(spec)
    if name == "expert":
        return ExpertPolicy(spec, rng)
    raise ValueError(f"unknown policy {name!r}; allowed: {', '.join(POLICIES)}")
