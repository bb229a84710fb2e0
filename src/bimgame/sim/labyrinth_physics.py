"""MuJoCo physics of a :class:`~bimgame.sim.labyrinth.LabyrinthSpec`: the rectangular board on the
circular maze's two nested hinges (:mod:`bimgame.sim.physics`), stepped one action at a time.

Model (generated as MJCF text by :func:`labyrinth_mjcf`). As for the circular maze, the board hangs
on ``tilt_x`` (about the world x axis) and, inside it, ``tilt_y`` (about the board's y axis), pivoting
at the floor's surface at the board's centre; each hinge is driven by an integrator position servo
plus a velocity servo with the same control as feed-forward, so the control is the commanded tilt
*rate* and one action ramps the target tilt linearly over its substeps. The servo gains and the
board, contact and static-friction constants are :mod:`bimgame.sim.mjcf`'s (the board is stiffly
position-controlled, so its inertia only sets how tightly it follows the command). Inner walls and
the rim (four boxes around the playable area) are boxes; every contact is an explicit ``<pair>``
of the marble with the floor, a wall or a rim piece (all geoms ``contype=conaffinity=0``).

Holes. The floor is one solid box: MuJoCo has no box with a hole (a floor tiled around 8–40 holes,
or meshes, would multiply the geoms and make contacts at the holes' edges depend on tiling). A
marble falls when its centre is over a hole, which :meth:`~bimgame.sim.labyrinth.LabyrinthSpec.over_hole`
checks from the board-frame position (:meth:`LabyrinthSim.over_hole`); an episode ends there, so
what the marble would do inside the hole never matters.

Rates. Actions at ``control_hz`` (CyberRunner's 55 Hz, or the circular maze's 30 Hz); the physics
step is the largest whole fraction of an action no longer than 1/``PHYSICS_HZ`` (150 Hz): 5 substeps
at 150 Hz for 30 Hz actions, 3 substeps at 165 Hz for 55 Hz.

Tilt rate. The board's floor moves at (tilt rate × distance from the pivot), so fast tilting throws
the marble: random changes of up to 2° per 55 Hz action (110°/s) raised its bottom up to 18 mm off
the floor, above the 15 mm walls, while 0.5° per action (27°/s) kept it within 1.4 mm. The real motors' rate
limit is not published as an angle rate; an env should bound the tilt rate
(:class:`~bimgame.envs.labyrinth_env.LabyrinthEnv` caps it at 30°/s).

Determinism. The solver's warm start is cleared at the start of every action step, so a step is a
pure function of the physics state ``(time, qpos, qvel, act)`` (:meth:`LabyrinthSim.get_state`):
the same state and actions give bit-identical states.

Rollouts. :meth:`LabyrinthSim.rollout` runs K open-loop sequences of H actions from one state with
``mujoco.rollout`` (the planner's model, :mod:`bimgame.expert.labyrinth_mpc`), one rollout call per
action step with each row's rate computed from its own servo target exactly as :meth:`LabyrinthSim.step`
does (as :meth:`bimgame.sim.physics.MazeSim.rollout`): the states are bit-identical to stepping.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.sim.layout import StateLayout, read_state, write_state
from bimgame.sim.mjcf import (
    CONTACT_SOLIMP,
    CONTACT_SOLREF,
    FLOOR_THICKNESS,
    PHYSICS_HZ,
    STATIC_FRICTION_SOLIMP,
    contact_condim,
    hinged_board_mjcf,
    servo_mjcf,
)
from bimgame.sim.placement import finite_array

__all__ = ["LabyrinthSim", "labyrinth_mjcf", "substeps_for", "CONTROL_RATES"]

_CONTROL_SPEC = int(mujoco.mjtState.mjSTATE_CTRL)

#: Action rates (Hz) the labyrinth is meant for: CyberRunner's camera and control (55) and MERL's (30).
CONTROL_RATES = (30.0, 55.0)


def substeps_for(control_hz: float) -> int:
    """Physics steps per action: the fewest that keep the physics step at most 1/``PHYSICS_HZ``."""
    if isinstance(control_hz, bool) or not (
        isinstance(control_hz, (int, float)) and math.isfinite(control_hz) and 0 < control_hz <= PHYSICS_HZ
    ):
        raise ValueError(
            f"control_hz must be a number in (0, {PHYSICS_HZ:g}] Hz (e.g. {CONTROL_RATES}), got {control_hz!r}"
        )
    return max(1, math.ceil(PHYSICS_HZ / control_hz - 1e-9))


def _box(name: str, centre: tuple[float, float, float], half: tuple[float, float, float], cls: str) -> str:
    return (
        f'<geom name="{name}" class="{cls}" pos="{centre[0]:.9g} {centre[1]:.9g} {centre[2]:.9g}" '
        f'size="{half[0]:.9g} {half[1]:.9g} {half[2]:.9g}"/>'
    )


def _board_geoms(spec: LabyrinthSpec) -> list[str]:
    """Floor, rim (four boxes, left and right ones spanning the corners) and inner walls."""
    hx, hy = spec.board_size[0] / 2, spec.board_size[1] / 2
    t, rh = spec.rim_thickness, spec.rim_height
    geoms = [
        _box("floor", (0.0, 0.0, -FLOOR_THICKNESS / 2), (hx + t, hy + t, FLOOR_THICKNESS / 2), "floor"),
        _box("rim_left", (-hx - t / 2, 0.0, rh / 2), (t / 2, hy + t, rh / 2), "wall"),
        _box("rim_right", (hx + t / 2, 0.0, rh / 2), (t / 2, hy + t, rh / 2), "wall"),
        _box("rim_bottom", (0.0, -hy - t / 2, rh / 2), (hx, t / 2, rh / 2), "wall"),
        _box("rim_top", (0.0, hy + t / 2, rh / 2), (hx, t / 2, rh / 2), "wall"),
    ]
    h = spec.wall_height
    for k, (x0, y0, x1, y1) in enumerate(spec.walls):
        geoms.append(
            _box(f"wall{k}", ((x0 + x1) / 2, (y0 + y1) / 2, h / 2), ((x1 - x0) / 2, (y1 - y0) / 2, h / 2), "wall")
        )
    return geoms


def labyrinth_mjcf(spec: LabyrinthSpec, physics_hz: float = PHYSICS_HZ) -> str:
    """MJCF text of ``spec``'s board with one marble (placed at the origin; see :meth:`LabyrinthSim.reset`)."""
    f = spec.friction
    geoms = _board_geoms(spec)
    pair_attrs = (
        f'condim="{contact_condim(f)}" friction="{f.slide:.9g} {f.slide:.9g} {f.spin:.9g} {f.roll:.9g} {f.roll:.9g}" '
        f'solref="{CONTACT_SOLREF}" solimp="{CONTACT_SOLIMP}"'
    )
    pairs = [f'<pair geom1="marble" geom2="{g.split(chr(34))[1]}" {pair_attrs}/>' for g in geoms]
    return f"""<mujoco model="bimgame_labyrinth_{spec.name}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{1.0 / physics_hz:.12g}" integrator="implicitfast" cone="elliptic"/>
  <default>
    <default class="floor"><geom type="box" contype="0" conaffinity="0" rgba="0.75 0.6 0.4 1"/></default>
    <default class="wall"><geom type="box" contype="0" conaffinity="0" rgba="0.55 0.4 0.25 1"/></default>
  </default>
  <worldbody>
    <light pos="0 0 0.6" dir="0 0 -1" directional="true"/>
    {hinged_board_mjcf(geoms)}
    <body name="marble" pos="0 0 {spec.marble_radius:.9g}">
      <joint name="marble" type="free" frictionloss="{f.static:.9g}" solimpfriction="{STATIC_FRICTION_SOLIMP}"/>
      <geom name="marble" type="sphere" size="{spec.marble_radius:.9g}" mass="{spec.marble_mass:.9g}"
            contype="0" conaffinity="0" rgba="0.85 0.85 0.9 1"/>
    </body>
  </worldbody>
  <contact>
    {(chr(10) + "    ").join(pairs)}
  </contact>
  {servo_mjcf(spec.max_tilt)}
</mujoco>
"""


class LabyrinthSim:
    """The physics of one labyrinth: a MuJoCo model and data, stepped one action at a time.

    Args:
        spec: the board (default: CyberRunner's hard layout).
        control_hz: action rate (Hz); the physics substeps follow (:func:`substeps_for`).
    """

    def __init__(self, spec: LabyrinthSpec | None = None, *, control_hz: float = 55.0):
        self.substeps = substeps_for(control_hz)
        self.control_hz = float(control_hz)
        self.spec = spec if spec is not None else LabyrinthSpec.layout("hard")
        if not isinstance(self.spec, LabyrinthSpec):
            raise TypeError(f"spec must be a LabyrinthSpec, got {type(self.spec).__name__}")
        self.physics_hz = self.control_hz * self.substeps
        self.model = mujoco.MjModel.from_xml_string(labyrinth_mjcf(self.spec, self.physics_hz))
        self.data = mujoco.MjData(self.model)
        self.control_dt = self.substeps * self.model.opt.timestep
        self.layout = StateLayout(self.model, 1)
        self.max_tilt = self.spec.max_tilt
        self._runner: mj_rollout.Rollout | None = None
        self._runner_threads = 0
        self._rollout_datas: list[mujoco.MjData] = []  # one per rollout thread, kept with the runner

    # ------------------------------------------------------------------ state
    @property
    def state_size(self) -> int:
        return self.layout.size

    def get_state(self) -> np.ndarray:
        """The full physics state (time, qpos, qvel, act) as a float64 vector."""
        return read_state(self.model, self.data)

    def set_state(self, state: np.ndarray) -> None:
        """Restore a state from :meth:`get_state`; stepping from it is bit-for-bit reproducible."""
        write_state(self.model, self.data, state, "LabyrinthSim.get_state")

    def reset(self, marble_xy: Sequence[float] | np.ndarray, tilt: Sequence[float] = (0.0, 0.0)) -> None:
        """Put the marble at rest at board-frame ``marble_xy`` (m), and the board and servo targets at
        ``tilt`` (rad, clamped to ``±max_tilt``). Refuses a marble overlapping a wall or the rim."""
        xy = finite_array("marble_xy", marble_xy, (2,), " (x, y, m)")
        tilt_arr = np.clip(finite_array("tilt", tilt, (2,)), -self.max_tilt, self.max_tilt)
        clearance = float(self.spec.clearance(xy))
        if clearance < self.spec.marble_radius - 1e-9:  # touching is allowed (round-off)
            raise ValueError(
                f"marble_xy {tuple(xy)} puts the marble into a wall or the rim: its centre must be at least the "
                f"marble radius ({self.spec.marble_radius} m) from them, is {clearance:.6g} m"
            )
        state = np.zeros(self.layout.size)
        state[self.layout.tilt] = tilt_arr
        state[self.layout.target_tilt] = tilt_arr
        ca, sa = math.cos(tilt_arr[0]), math.sin(tilt_arr[0])
        cb, sb = math.cos(tilt_arr[1]), math.sin(tilt_arr[1])
        x, y, z = float(xy[0]), float(xy[1]), self.spec.marble_radius
        x1, z1 = cb * x + sb * z, -sb * x + cb * z  # board -> world: Rx(a)·Ry(b)·p
        state[self.layout.marble_pos[0]] = (x1, ca * y - sa * z1, sa * y + ca * z1)
        state[self.layout.marble_quat[0]] = (1.0, 0.0, 0.0, 0.0)
        self.data.qacc_warmstart[:] = 0
        self.set_state(state)

    # ------------------------------------------------------------------ stepping
    def step(self, tilt_delta: Sequence[float] | np.ndarray) -> None:
        """Advance one action step, ramping the commanded tilt by ``tilt_delta`` (rad, (2,)),
        clamped to ``±max_tilt``, linearly over the substeps."""
        data = self.data
        ax, ay = data.act.tolist()[:2]
        limit, dt = self.max_tilt, self.control_dt
        rx = (min(max(ax + float(tilt_delta[0]), -limit), limit) - ax) / dt
        ry = (min(max(ay + float(tilt_delta[1]), -limit), limit) - ay) / dt
        if rx != rx or ry != ry:  # NaN: MuJoCo would reset the whole state with only a warning
            raise ValueError(f"tilt_delta must be finite numbers (rad), got {tilt_delta!r}")
        data.ctrl[:] = (rx, rx, ry, ry)
        data.qacc_warmstart[:] = 0.0
        mujoco.mj_step(self.model, data, nstep=self.substeps)

    def rollout(self, state: np.ndarray, controls: np.ndarray, nthread: int = 1) -> np.ndarray:
        """Roll out K open-loop sequences of H actions from one physics state with ``mujoco.rollout``.

        Args:
            state: (state_size,) the start (:meth:`get_state`), or (K, state_size) one start per row
                (what a batched env steps); the sim's own data is left untouched.
            controls: (K, H, 2) commanded tilt change per action (rad), what :meth:`step` takes (the
                env's action times its tilt step), or (H, 2) for one sequence.
            nthread: MuJoCo's rollout threads over the K rows (1: the calling thread, the right choice
                inside worker processes and on a shared machine).

        Returns:
            (K, H, state_size) the state after each action; bit-identical to :meth:`set_state` then H
            calls of :meth:`step` per row.
        """
        start = np.asarray(state, dtype=np.float64)
        deltas = np.asarray(controls, dtype=np.float64)
        deltas = deltas[None] if deltas.ndim == 2 else deltas
        if start.ndim not in (1, 2) or start.shape[-1] != self.layout.size or not np.all(np.isfinite(start)):
            raise ValueError(
                f"state must be a finite float vector of length {self.layout.size} (LabyrinthSim.get_state) or "
                f"(K, {self.layout.size}) of them, got shape {start.shape}"
            )
        if deltas.ndim != 3 or deltas.shape[-1] != 2 or not np.all(np.isfinite(deltas)):
            raise ValueError(f"controls must be finite tilt changes (rad) of shape (K, H, 2), got shape {deltas.shape}")
        if start.ndim == 2 and start.shape[0] != deltas.shape[0]:
            raise ValueError(f"{start.shape[0]} start states for {deltas.shape[0]} control sequences: give one per row")
        if not (isinstance(nthread, (int, np.integer)) and not isinstance(nthread, bool) and nthread >= 1):
            raise ValueError(f"nthread must be a positive integer, got {nthread!r}")
        k, horizon = deltas.shape[:2]
        nthread = min(int(nthread), k)
        if self._runner is None or self._runner_threads != nthread:
            if self._runner is not None:
                self._runner.close()
            self._runner = mj_rollout.Rollout(nthread=0 if nthread == 1 else nthread)
            self._runner_threads = nthread
            self._rollout_datas = [mujoco.MjData(self.model) for _ in range(nthread)]
        datas = self._rollout_datas
        out = np.empty((k, horizon, self.layout.size))
        current = np.array(np.broadcast_to(start, (k, self.layout.size)))  # a copy: the caller's stays
        warmstart = np.zeros((k, self.model.nv))
        control = np.empty((k, self.substeps, self.model.nu))
        states_out = np.empty((k, self.substeps, self.layout.size))
        models = [self.model] * k
        target, limit, dt = self.layout.target_tilt, self.max_tilt, self.control_dt
        for t in range(horizon):
            # The rate from each row's own servo target, operation for operation as :meth:`step`
            # (add, clamp, subtract, divide in IEEE doubles): that keeps the two bit-identical.
            ramp = current[:, target]
            rate = (np.clip(ramp + deltas[:, t], -limit, limit) - ramp) / dt
            control[:, :, 0] = control[:, :, 1] = rate[:, None, 0]
            control[:, :, 2] = control[:, :, 3] = rate[:, None, 1]
            self._runner.rollout(
                models,
                datas,
                current,
                control,
                control_spec=_CONTROL_SPEC,
                skip_checks=True,
                nstep=self.substeps,
                initial_warmstart=warmstart,
                state=states_out,
            )
            current = states_out[:, -1].copy()
            out[:, t] = current
        return out

    # ------------------------------------------------------------------ observation helpers
    def marble_kinematics(self) -> tuple[np.ndarray, np.ndarray]:
        """The marble's board-frame position and velocity (m, m/s), each (3,)."""
        position, velocity = self.layout.board_frame(self.get_state())
        return position[0], velocity[0]

    def marble_xy_of(self, states: np.ndarray) -> np.ndarray:
        """The marble's board-frame (x, y) (m) in physics states (..., state_size), e.g. a rollout's: (..., 2)."""
        positions, _ = self.layout.board_frame(np.asarray(states, dtype=np.float64))
        return positions[..., 0, :2]

    def marble_xy(self) -> np.ndarray:
        """The marble's board-frame (x, y) (m)."""
        x, y, _, _ = self.layout.board_frame_one(self.data.qpos, self.data.qvel)[0]
        return np.array([x, y])

    def over_hole(self) -> bool:
        """Whether the marble's centre is over a hole (it falls: the episode is lost)."""
        return bool(self.spec.over_hole(self.marble_xy()))

    @property
    def tilt(self) -> np.ndarray:
        """Current board tilt (rad) about x and y."""
        return self.data.qpos[:2].copy()

    @property
    def target_tilt(self) -> np.ndarray:
        """Commanded tilt (rad) about x and y at the end of the current ramp."""
        return self.data.act[:2].copy()

    def close(self) -> None:
        """Release the rollout runner, if any (kept for MazeSim's interface)."""
        if self._runner is not None:
            self._runner.close()
            self._runner = None
