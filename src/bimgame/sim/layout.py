"""Where the quantities of a physics state live: indices into a flat ``mjSTATE_FULLPHYSICS`` vector
(time, qpos, qvel, act) of a :class:`~bimgame.sim.physics.MazeSim` model, and vectorised decoders of
marble kinematics in the board frame. Split from :mod:`bimgame.sim.physics` (which re-exports
:class:`StateLayout`): observations and start curricula decode states without stepping them."""

from __future__ import annotations

import math

import mujoco
import numpy as np

__all__ = ["StateLayout", "STATE_SPEC", "read_state", "write_state"]

STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS


class StateLayout:
    """Indices of the quantities inside a flat physics state (``mjSTATE_FULLPHYSICS``:
    time, qpos, qvel, act) for a model with ``n_marbles`` marbles, and vectorised decoders that
    work on arrays of states of any leading shape."""

    def __init__(self, model: mujoco.MjModel, n_marbles: int):
        self.n_marbles = n_marbles
        self.size = mujoco.mj_stateSize(model, STATE_SPEC)
        qpos0 = 1
        qvel0 = 1 + model.nq
        act0 = qvel0 + model.nv
        self.tilt = np.array([qpos0, qpos0 + 1])
        self.tilt_rate = np.array([qvel0, qvel0 + 1])
        self.target_tilt = np.array([act0, act0 + 1])
        self.marble_pos = np.array([[qpos0 + 2 + 7 * i + j for j in range(3)] for i in range(n_marbles)])
        self.marble_quat = np.array([[qpos0 + 5 + 7 * i + j for j in range(4)] for i in range(n_marbles)])
        self.marble_vel = np.array([[qvel0 + 2 + 6 * i + j for j in range(3)] for i in range(n_marbles)])
        self.marble_angvel = np.array([[qvel0 + 5 + 6 * i + j for j in range(3)] for i in range(n_marbles)])

    def board_frame(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Marble positions and velocities relative to the board, in the board frame.

        Returns arrays of shape ``states.shape[:-1] + (n_marbles, 3)``. The velocity is the time
        derivative of the board-frame position (the marble's motion as seen by a camera fixed to
        the board).
        """
        a = states[..., self.tilt[0]][..., None]
        b = states[..., self.tilt[1]][..., None]
        da = states[..., self.tilt_rate[0]][..., None]
        db = states[..., self.tilt_rate[1]][..., None]
        p = states[..., self.marble_pos]
        v = states[..., self.marble_vel]
        ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
        # Board angular velocity in world coordinates: da about x, db about Rx(a)·y.
        wx = da
        wy = db * ca
        wz = db * sa
        px, py, pz = p[..., 0], p[..., 1], p[..., 2]
        vx = v[..., 0] - (wy * pz - wz * py)
        vy = v[..., 1] - (wz * px - wx * pz)
        vz = v[..., 2] - (wx * py - wy * px)
        return _to_board(px, py, pz, ca, sa, cb, sb), _to_board(vx, vy, vz, ca, sa, cb, sb)

    def board_frame_one(self, qpos: np.ndarray, qvel: np.ndarray) -> list[tuple[float, float, float, float]]:
        """Scalar :meth:`board_frame` of one model's ``qpos``/``qvel``: per marble
        ``(x, y, vx, vy)`` in the board frame. The single env's per-step fast path: plain floats
        avoid numpy's per-call overhead on tiny arrays (tests check it equals the batched one)."""
        q = qpos.tolist()
        v = qvel.tolist()
        a, b, da, db = q[0], q[1], v[0], v[1]
        ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
        wx, wy, wz = da, db * ca, db * sa
        out = []
        for i in range(self.n_marbles):
            px, py, pz = q[2 + 7 * i], q[3 + 7 * i], q[4 + 7 * i]
            vx = v[2 + 6 * i] - (wy * pz - wz * py)
            vy = v[3 + 6 * i] - (wz * px - wx * pz)
            vz = v[4 + 6 * i] - (wx * py - wy * px)
            out.append(
                (
                    cb * px - sb * (-sa * py + ca * pz),
                    ca * py + sa * pz,
                    cb * vx - sb * (-sa * vy + ca * vz),
                    ca * vy + sa * vz,
                )
            )
        return out


def _to_board(x, y, z, ca, sa, cb, sb) -> np.ndarray:
    """Apply (Rx(a)·Ry(b))ᵀ to world vectors."""
    # First Rx(a)ᵀ.
    y1 = ca * y + sa * z
    z1 = -sa * y + ca * z
    # Then Ry(b)ᵀ.
    xb = cb * x - sb * z1
    zb = sb * x + cb * z1
    return np.stack([xb, y1, zb], axis=-1)


def read_state(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """The full physics state (time, qpos, qvel, act) of ``data`` as a float64 vector: what the
    simulators' ``get_state`` returns."""
    state = np.empty(mujoco.mj_stateSize(model, STATE_SPEC))
    mujoco.mj_getState(model, data, state, STATE_SPEC)
    return state


def write_state(model: mujoco.MjModel, data: mujoco.MjData, state: np.ndarray, source: str) -> None:
    """Restore a state from :func:`read_state` (``source`` names where such states come from, for the
    error) and recompute what follows from it; stepping from it is bit-for-bit reproducible."""
    size = mujoco.mj_stateSize(model, STATE_SPEC)
    state = np.asarray(state, dtype=np.float64)
    if state.shape != (size,) or not np.all(np.isfinite(state)):
        raise ValueError(
            f"state must be a finite float vector of length {size} (from {source}), got shape {state.shape}"
        )
    mujoco.mj_setState(model, data, state, STATE_SPEC)
    mujoco.mj_forward(model, data)
