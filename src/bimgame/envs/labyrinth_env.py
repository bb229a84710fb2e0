"""Gymnasium environment of CyberRunner's labyrinth (the BRIO board).

See :class:`LabyrinthEnv` for the full description (Gymnasium's documentation layout). Facts cited
below come from Bi & D'Andrea, "Sample-Efficient Learning to Solve a Real-World Labyrinth Game Using
Data-Augmented Model-Based Reinforcement Learning" (arXiv 2312.09906) and its repository
``thomasbi1/cyberrunner``: ``cyberrunner_dreamer/cyberrunner_dreamer/env.py`` at commit
``6bdf8ee512ee24aa7801fcbe437d68a05d35df69`` (reward, episode end, observation), ``path.py`` at
``7b63cbe3d4bc1371dc94942ce4b7e5b573928383`` (path points 0.2 mm apart, the relative path) and
``cyberrunner_state_estimation/core/measurements.py`` (the 64 × 64 sub-image at 1 mm per pixel).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from bimgame.envs.actions import action_to_tilt_delta
from bimgame.envs.labyrinth_cyberrunner import PATH_AHEAD, PATH_SPACING, check_motion
from bimgame.envs.labyrinth_observer import LabyrinthObserver
from bimgame.envs.labyrinth_surroundings import check_surroundings
from bimgame.sim.labyrinth import LabyrinthSpec, PathStep, WaypointPath
from bimgame.sim.labyrinth_box_sight import path_box_sight
from bimgame.sim.labyrinth_layouts import LAYOUT_NAMES
from bimgame.sim.labyrinth_physics import LabyrinthSim
from bimgame.sim.labyrinth_render import LabyrinthRaster, board_grid
from bimgame.sim.labyrinth_tracker import ScalarPathProgress
from bimgame.util.settings import is_integer, is_real

__all__ = [
    "LabyrinthEnv",
    "LABYRINTH_ACTION_TYPES",
    "LABYRINTH_OBS_MODES",
    "LABYRINTH_CONTROL_RATES",
    "LABYRINTH_EPISODE_SECONDS",
    "labyrinth_max_episode_steps",
    "path_points_ahead",
    "PATH_WIDTH",
    "OBSERVATION_EXTRAS",
]

LABYRINTH_ACTION_TYPES = ("continuous", "discrete")
LABYRINTH_OBS_MODES = ("state", "pixels", "cyberrunner", "cyberrunner_flat")
#: The switches that add to an observation mode (``surroundings`` to state, ``motion`` to CyberRunner's and pixels):
#: what a network that reads them needs its envs built with.
OBSERVATION_EXTRAS = ("surroundings", "motion")
#: Action rates (Hz): CyberRunner's camera and control (55) and MERL's maze's (30).
LABYRINTH_CONTROL_RATES = (30, 55)
#: How an episode is judged off the path: ``tolerance`` (default: no path segment within the
#: board's ``path_tolerance`` in sight, the progress rule's test) or ``cyberrunner`` (CyberRunner's
#: test: no path point in the marble's free box, :mod:`bimgame.sim.labyrinth_box_sight`).
LABYRINTH_OFF_PATH_RULES = ("tolerance", "cyberrunner")
#: Episode time limit (s): CyberRunner's 3000 steps at 55 Hz (``env.py``: ``self.steps == 3000``).
LABYRINTH_EPISODE_SECONDS = 3000 / 55
#: Reward per metre of path progress: CyberRunner pays 0.004 / 16 per path point (``env.py``) and
#: its path points are 0.2 mm apart (``path.py``: ``distance=0.0002``; ``path_0002_hard.pkl``).
PROGRESS_SCALE = 0.004 / 16 / 0.0002
#: Bonus on reaching the goal (``env.py``: ``reward_on_goal=0.5``) and the reward of a failing step
#: (``reward_on_fail=0.0``).
GOAL_BONUS, FAIL_REWARD = 0.5, 0.0
#: Width (m) of the printed path line drawn in pixel observations (``path_width``'s default).
PATH_WIDTH = 0.002


def labyrinth_max_episode_steps(control_hz: float) -> int:
    """Steps in :data:`LABYRINTH_EPISODE_SECONDS` at ``control_hz``: 3000 at 55 Hz, 1636 at 30 Hz."""
    return round(LABYRINTH_EPISODE_SECONDS * control_hz)


def path_points_ahead(
    path: WaypointPath, progress: float | np.ndarray, n: int = PATH_AHEAD, spacing: float = PATH_SPACING
):
    """The ``n`` path points at arc lengths ``progress + k * spacing`` (k = 0 … n-1; clamped at the
    goal), (n, 2) m; for an array of progresses (B,), (B, n, 2) (the batched env's)."""
    s = np.clip(np.asarray(progress)[..., None] + spacing * np.arange(n), 0.0, path.length)
    k = np.clip(np.searchsorted(path.cumulative, s, side="right") - 1, 0, path.n_segments - 1)
    t = (s - path.cumulative[k]) / path.lengths[k]
    return path.starts[k] + t[..., None] * path.vectors[k]


def _finite(name: str, value: Any, low: float = -math.inf, high: float = math.inf) -> float:
    if not (is_real(value) and math.isfinite(value) and low <= value <= high):
        raise ValueError(f"{name} must be a finite number in [{low:g}, {high:g}], got {value!r}")
    return float(value)


class LabyrinthEnv(gym.Env):
    """
    ## Description

    CyberRunner's labyrinth (Bi & D'Andrea, ETH Zurich, 2023): the BRIO wooden labyrinth, a
    0.276 m × 0.231 m board with walls and holes, tilted about two axes so that a 12 mm steel marble
    follows the printed path from start to goal without falling into a hole. Three layouts, easy,
    medium and hard (:mod:`bimgame.sim.labyrinth_layouts`, cited); MuJoCo physics on two servoed
    hinges (:class:`~bimgame.sim.labyrinth_physics.LabyrinthSim`) at 30 or 55 Hz actions. CyberRunner
    learned the hard layout on the real board in ≈ 1M steps (5 h) and beat the human record, 14.48 s
    against 15.41 s.

    ## Action Space

    ``action_type="continuous"`` (default, as CyberRunner's): ``Box(-1, 1, (2,), float32)``, the
    commanded tilt *rate* about the board's x and y axes as a fraction of ``max_tilt_rate_deg``
    (default 30°/s): one action changes the target tilt by ``action * max_tilt_rate / control_hz``,
    ramped over its substeps, clamped at ``±max_tilt`` (10°). CyberRunner's action is the motors'
    velocity (``env.py``: ``max_angle_vel = 200`` Dynamixel velocity units, ≈ 275°/s of the knob
    shafts if these are the XL330 motors' raw units of 0.229 rpm, ``docs/01_hardware_setup.md``);
    the gearing from knob to board tilt is not published, so the rate is a parameter. 30°/s because the
    board's floor moves at (rate × distance from the pivot): random changes of 2° per 55 Hz action
    (110°/s) threw the marble over 15 mm walls, 0.5° per action (27°/s) kept it within 1.4 mm of
    the floor (:mod:`bimgame.sim.labyrinth_physics`); 30°/s is 0.55° per 55 Hz action and exactly
    the circular maze's 1° step per 30 Hz action, and reaches the full 10° in 1/3 s; random
    full-rate (±1) actions for 4000 steps on the hard board lifted the marble at most 0.9 mm (55 Hz)
    and 2.5 mm (30 Hz) off the floor.
    ``action_type="discrete"``: ``Discrete(5)`` — 0 no-op, 1/2 one full-rate step (+/-) about x,
    3/4 about y.

    ## Observation Space

    ``obs_mode="state"`` (default): ``Box((17,), float32)``: marble x, y (m, board frame, origin at
    the board's centre, x right, y up), vx, vy (m/s), board tilt about x and y (rad), progress along
    the path as a fraction of its length, then 5 path points 12 mm apart relative to the marble
    (x, y each, m), the first at the marble's projection on the path (CyberRunner's relative path).
    With ``surroundings=True``, 16 more (33): the 4 nearest holes relative to the marble and the wall
    distances along 8 directions (:mod:`bimgame.envs.labyrinth_surroundings`).
    ``obs_mode="pixels"``: ``Box(0, 255, (1, obs_size, obs_size), uint8)``, a top-down grayscale view
    of the whole board, north up, drawn with numpy (:mod:`bimgame.sim.labyrinth_render`: floor,
    printed path, black holes, light walls, white marble). With ``motion=True``
    ``(2, obs_size, obs_size)``: the previous observation's frame, then this one's (a two-frame stack;
    :mod:`bimgame.envs.labyrinth_pixels`).
    ``obs_mode="cyberrunner"``: CyberRunner's own observation, a ``Dict``: ``"image"``
    ``Box(0, 255, (1, 64, 64), uint8)``, a grayscale window 64 mm wide centred on the marble at 1 mm
    per pixel, north up, outside the board showing the outside (CyberRunner's is a colour camera
    crop, (64, 64, 3)); ``"states"`` ``Box((4,), float32)``: tilt x and y / 10°, marble x / 0.276 m
    and y / 0.231 m from the board's lower-left corner (CyberRunner's normalisation, our axes'
    signs); ``"goal"`` ``Box((10,), float32)``: the relative path of ``"state"``, its k-th point
    divided by k × 12 mm (k = 1 … 5), as CyberRunner's.
    ``obs_mode="cyberrunner_flat"``: the same observation as one ``Box((4110,), float32)`` vector (what
    a learner's network reads, one tensor per step): the crop's 4096 pixels row by row (0–255), then
    ``"states"``, then ``"goal"`` (:func:`~bimgame.envs.labyrinth_cyberrunner.flatten_cyberrunner`;
    :func:`~bimgame.envs.labyrinth_cyberrunner.unflatten_cyberrunner` inverts it). With ``motion=True``
    both forms end with the marble's observed velocity, ``"motion"`` (2; 4112 flat): its position's
    change since the previous observation (:mod:`bimgame.envs.labyrinth_cyberrunner`; not CyberRunner's).

    ## Rewards

    CyberRunner's: ``progress_scale`` (1.25) per metre of progress along the path (0.004/16 per path
    point, points 0.2 mm apart), negative when the marble rolls back; progress follows
    :class:`~bimgame.sim.labyrinth.PathProgress`, which pays nothing for skipped path (the attributed
    segment advances at most one per step and only to a segment in sight). Reaching the goal adds
    ``goal_bonus`` (0.5). A failing step (hole, or off the path with ``end_off_path``) pays
    ``fail_reward`` (0.0) instead of its progress, as CyberRunner's ``reward_on_fail``.

    ## Starting State

    Board flat and at rest; the marble at rest at the layout's start (the path's first waypoint)
    plus an offset drawn uniformly from ``[-start_noise, start_noise]²`` (default 2 mm) from
    ``np_random`` — the real marble is put there by hand or a feeder, never exactly (a choice: the
    spread is not published). ``reset(options={"marble_xy": (x, y)})`` places it explicitly;
    ``reset(options={"sim_state": state})`` restores a whole physics state from ``env.sim.get_state()``.
    The path segment is then the nearest in sight of the marble.

    ## Episode End

    Termination with success when the marble is on the path's last segment within ``goal_radius``
    (10 mm) of the goal; with failure when its centre is over a hole (it falls), or — with
    ``end_off_path`` (default True, as CyberRunner's) — when it is off the path by ``off_path_rule``:
    ``"tolerance"`` (default; no path segment near it in sight: :class:`~bimgame.sim.labyrinth.PathProgress`)
    or ``"cyberrunner"`` (CyberRunner's own test, more lenient on open floor and stricter beside
    holes: no path point in the marble's free box, :mod:`bimgame.sim.labyrinth_box_sight`; progress
    is still the tolerance rule's). CyberRunner also ended an episode whose
    progress jumped more than 60 mm in one step; the progress rule here makes such jumps impossible.
    Truncation by ``TimeLimit``: the registered ids ``BiMGame/Labyrinth-{Easy,Medium,Hard}-v0`` run
    at 55 Hz with 3000 steps, CyberRunner's limit (54.5 s); at 30 Hz pass
    ``max_episode_steps=labyrinth_max_episode_steps(30)`` (1636 steps, the same time).
    ``step()`` after a termination raises ``RuntimeError``.

    ## Info

    ``is_success`` bool, ``progress`` float (m along the path), ``progress_fraction``, ``segment``
    int, ``over_hole`` bool, ``off_path`` bool, ``tilt`` (2,) rad.

    ## Arguments

    ``layout`` ("easy", "medium", "hard"), ``action_type``, ``control_hz`` (30 or 55),
    ``obs_mode``, ``obs_size`` (pixels, 16..1024, default 84), ``render_mode`` (None or
    "rgb_array"), ``render_size`` (16..2048, default 480), ``max_tilt_rate_deg`` (0 < rate ≤ 180),
    ``progress_scale``, ``goal_bonus``, ``fail_reward``, ``end_off_path``, ``off_path_rule``
    (``LABYRINTH_OFF_PATH_RULES``), ``start_noise`` (m,
    0..5 mm), ``path_width`` (m, the printed path line in pixels; 0 hides it), ``board`` (a
    :class:`~bimgame.sim.labyrinth.LabyrinthSpec` overriding ``layout``), ``surroundings`` (state
    only: append the holes and walls around the marble), ``motion`` (cyberrunner: append the
    marble's observed velocity; pixels: the previous frame before this one). Each is checked at
    construction (``ValueError`` naming it and what is allowed).

    ## Version History

    * v0: initial version.
    """

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 55}  # noqa: RUF012 - Gymnasium's API

    def __init__(
        self,
        layout: str = "hard",
        *,
        action_type: str = "continuous",
        control_hz: float = 55,
        obs_mode: str = "state",
        obs_size: int = 84,
        render_mode: str | None = None,
        render_size: int = 480,
        max_tilt_rate_deg: float = 30.0,
        progress_scale: float = PROGRESS_SCALE,
        goal_bonus: float = GOAL_BONUS,
        fail_reward: float = FAIL_REWARD,
        end_off_path: bool = True,
        off_path_rule: str = "tolerance",
        start_noise: float = 0.002,
        path_width: float = PATH_WIDTH,
        board: LabyrinthSpec | None = None,
        surroundings: bool = False,
        motion: bool = False,
    ):
        if board is None:
            if layout not in LAYOUT_NAMES:
                raise ValueError(f"unknown layout {layout!r}; allowed: {', '.join(LAYOUT_NAMES)}")
            board = LabyrinthSpec.layout(layout)
        elif not isinstance(board, LabyrinthSpec):
            raise ValueError(f"board must be a LabyrinthSpec or None, got {type(board).__name__}")
        if action_type not in LABYRINTH_ACTION_TYPES:
            raise ValueError(f"unknown action_type {action_type!r}; allowed: {', '.join(LABYRINTH_ACTION_TYPES)}")
        if isinstance(control_hz, bool) or control_hz not in LABYRINTH_CONTROL_RATES:
            raise ValueError(f"control_hz must be one of {LABYRINTH_CONTROL_RATES} (Hz), got {control_hz!r}")
        if obs_mode not in LABYRINTH_OBS_MODES:
            raise ValueError(f"unknown obs_mode {obs_mode!r}; allowed: {', '.join(LABYRINTH_OBS_MODES)}")
        if not (is_integer(obs_size) and 16 <= obs_size <= 1024):
            raise ValueError(f"obs_size must be an integer in 16..1024, got {obs_size!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"unknown render_mode {render_mode!r}; allowed: None, 'rgb_array'")
        if not (is_integer(render_size) and 16 <= render_size <= 2048):
            raise ValueError(f"render_size must be an integer in 16..2048, got {render_size!r}")
        check_surroundings(surroundings, obs_mode)
        check_motion(motion, obs_mode)
        if not isinstance(end_off_path, (bool, np.bool_)):
            raise ValueError(f"end_off_path must be True or False, got {end_off_path!r}")
        if off_path_rule not in LABYRINTH_OFF_PATH_RULES:
            raise ValueError(f"unknown off_path_rule {off_path_rule!r}; allowed: {', '.join(LABYRINTH_OFF_PATH_RULES)}")
        rate = _finite("max_tilt_rate_deg", max_tilt_rate_deg, 0.0, 180.0)
        if rate == 0:
            raise ValueError("max_tilt_rate_deg must be a finite number in (0, 180] (°/s), got 0")
        #: The board (``spec`` is Gymnasium's registration record, so the board has another name).
        self.board = board
        self.layout_name = board.name
        self.action_type, self.obs_mode, self.render_mode = action_type, obs_mode, render_mode
        self.control_hz, self.obs_size, self.render_size = int(control_hz), int(obs_size), int(render_size)
        self.max_tilt_rate = math.radians(rate)
        self.progress_scale = _finite("progress_scale", progress_scale)
        self.goal_bonus = _finite("goal_bonus", goal_bonus)
        self.fail_reward = _finite("fail_reward", fail_reward)
        self.end_off_path = bool(end_off_path)
        self.off_path_rule = off_path_rule
        #: CyberRunner's free-box map (``off_path_rule="cyberrunner"``), None with the tolerance rule.
        self.path_sight = path_box_sight(board) if off_path_rule == "cyberrunner" else None
        self.start_noise = _finite("start_noise", start_noise, 0.0, 0.005)
        _finite("path_width", path_width, 0.0, 0.02)
        self._check_start()
        self._kwargs = dict(
            layout=layout, action_type=action_type, control_hz=control_hz, obs_mode=obs_mode, obs_size=obs_size,
            render_mode=render_mode, render_size=render_size, max_tilt_rate_deg=max_tilt_rate_deg,
            progress_scale=progress_scale, goal_bonus=goal_bonus, fail_reward=fail_reward,
            end_off_path=end_off_path, off_path_rule=off_path_rule, start_noise=start_noise, path_width=path_width,
            board=board, surroundings=surroundings, motion=motion,
        )  # fmt: skip
        self.sim = LabyrinthSim(board, control_hz=self.control_hz)
        self.path = board.path
        self.tracker = ScalarPathProgress(board)  # PathProgress's rule, scalar: the per-step fast path
        self.motion = motion
        #: Tilt change (rad) of one full-rate action.
        self.tilt_step = self.max_tilt_rate / self.control_hz
        if action_type == "discrete":
            self.action_space: spaces.Space = spaces.Discrete(5)
        else:
            self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.observer = LabyrinthObserver(
            board,
            self.tracker,
            obs_mode=obs_mode,
            obs_size=self.obs_size,
            path_width=path_width,
            surroundings=surroundings,
            motion=motion,
            control_hz=self.control_hz,
        )
        self.surroundings = self.observer.surroundings  # the holes and walls around the marble, or None
        self._render_raster: LabyrinthRaster | None = None
        self._path_width = path_width
        self.observation_space = self.observer.space()
        self._has_reset = False
        self._episode_over = True
        self._last: PathStep | None = None
        self._kinematics: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # marble x, y, vx, vy
        self._previous_xy = np.zeros(2)  # the marble's position at the previous observation (motion)

    # ------------------------------------------------------------------ construction helpers
    def _check_start(self) -> None:
        """The start square must keep the marble clear of walls, rim and holes."""
        corners = np.asarray(self.board.start) + self.start_noise * np.array([[-1, -1], [-1, 1], [1, -1], [1, 1]])
        clear = self.board.clearance(corners).min() >= self.board.marble_radius
        if not clear or self.board.over_hole(corners).any() or self.board.over_hole(self.board.start):
            raise ValueError(
                f"start_noise {self.start_noise!r} m lets the marble start in a wall, the rim or a hole of layout "
                f"{self.layout_name!r}: choose a smaller start_noise (0..0.005 m)"
            )

    # ------------------------------------------------------------------ Gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"marble_xy", "sim_state"}
        if unknown or ("marble_xy" in options and "sim_state" in options):
            raise ValueError(f"reset options must be at most one of 'marble_xy', 'sim_state'; got {sorted(options)}")
        if "sim_state" in options:
            try:
                self.sim.set_state(options["sim_state"])
            except ValueError as error:
                raise ValueError(f"options['sim_state']: {error}") from None
        else:
            if "marble_xy" in options:
                xy = np.asarray(options["marble_xy"], dtype=np.float64)
            else:
                xy = np.asarray(self.board.start) + self.np_random.uniform(-self.start_noise, self.start_noise, 2)
            try:
                self.sim.reset(xy)
            except ValueError as error:
                raise ValueError(f"options['marble_xy']: {error}") from None
        self._kinematics = self.sim.layout.board_frame_one(self.sim.data.qpos, self.sim.data.qvel)[0]
        if self.motion:
            self._previous_xy = np.array(self._kinematics[:2])
        self._last = self._by_rule(self.tracker.reset(self._kinematics[:2]))
        self._has_reset, self._episode_over = True, False
        return self._observe(), self._info(self._last, False)

    def step(self, action):
        if self._episode_over:
            if not self._has_reset:
                raise RuntimeError("call reset() before step()")
            raise RuntimeError("the episode has ended (terminated); call reset() before step()")
        sim = self.sim
        sim.step(action_to_tilt_delta(action, self.action_type, self.tilt_step))
        if self.motion:
            self._previous_xy = np.array(self._kinematics[:2])
        self._kinematics = sim.layout.board_frame_one(sim.data.qpos, sim.data.qvel)[0]
        step = self._last = self._by_rule(self.tracker.update(self._kinematics[:2]))
        failed = step.over_hole or (self.end_off_path and step.off_path)
        success = step.goal and not step.over_hole
        reward = self.fail_reward if failed else self.progress_scale * step.delta
        if success:
            reward += self.goal_bonus
        terminated = bool(failed or success)
        self._episode_over = terminated
        return self._observe(), float(reward), terminated, False, self._info(step, success)

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array'")
            return None
        if self._render_raster is None:
            grid = board_grid(self.board, self.render_size)
            self._render_raster = LabyrinthRaster(self.board, grid, path_width=self._path_width)
        return self._render_raster.rgb(self.sim.marble_xy())

    def close(self):
        self.sim.close()

    def observe_state(self, sim_state: np.ndarray, progress: float, previous_state: np.ndarray | None = None) -> Any:
        """The observation (of this env's ``obs_mode``) that :meth:`reset` or :meth:`step` returns in
        physics state ``sim_state`` (from ``env.sim.get_state()``) with the marble at ``progress``
        (m along the path, ``info["progress"]``): what re-renders another observation of a recorded
        episode (:mod:`bimgame.expert.labyrinth_datasets`). ``previous_state``: the physics state at
        the previous observation, which the marble's ``motion`` is measured from (None: an episode's
        first observation, no motion). Leaves the env's own state untouched."""
        if not (is_real(progress) and math.isfinite(progress)):
            raise ValueError(f"progress must be a finite number (m along the path), got {progress!r}")
        qpos, kinematics = self._state_kinematics("sim_state", sim_state)
        previous = kinematics if previous_state is None else self._state_kinematics("previous_state", previous_state)[1]
        return self.observer.observe(kinematics, qpos[:2], float(progress), np.array(previous[:2]))

    def state_observation(self) -> np.ndarray:
        """The 17 state values (``obs_mode="state"``'s, without surroundings) at the env's current step,
        whatever it observes: the privileged state that a pixel learner's auxiliary heads predict."""
        if self._last is None:
            raise RuntimeError("call reset() before state_observation()")
        return self.observer.state_values(self._kinematics, self.sim.data.qpos[:2], self._last.progress)

    def _state_kinematics(self, name: str, sim_state: np.ndarray) -> tuple[np.ndarray, tuple[float, ...]]:
        """The joint positions and the marble's board-frame (x, y, vx, vy) of a physics state, checked."""
        state = np.asarray(sim_state, dtype=np.float64)
        if state.shape != (self.sim.state_size,) or not np.all(np.isfinite(state)):
            raise ValueError(
                f"{name} must be a finite float vector of length {self.sim.state_size} "
                f"(LabyrinthSim.get_state), got shape {state.shape}"
            )
        # The flat state is (time, qpos, qvel, act): the same numbers the env reads from the sim's data.
        nq, nv = self.sim.model.nq, self.sim.model.nv
        qpos, qvel = state[1 : 1 + nq], state[1 + nq : 1 + nq + nv]
        return qpos, self.sim.layout.board_frame_one(qpos, qvel)[0]

    # ------------------------------------------------------------------ helpers
    def _observe(self) -> Any:
        assert self._last is not None
        return self.observer.observe(self._kinematics, self.sim.data.qpos[:2], self._last.progress, self._previous_xy)

    def off_path(self, xy: np.ndarray | Sequence[float], tolerance_off: np.ndarray | bool) -> np.ndarray:
        """Whether marbles at ``xy`` (..., 2) are off the path by the env's ``off_path_rule``:
        ``tolerance_off`` (the progress rule's verdict) or, with ``"cyberrunner"``, no path point in the
        marble's free box (:mod:`bimgame.sim.labyrinth_box_sight`). The batched env asks it too."""
        if self.path_sight is None:
            return np.asarray(tolerance_off, dtype=bool)
        return np.logical_not(self.path_sight.on_path(xy))

    def _by_rule(self, step: PathStep) -> PathStep:
        """The tracker's ``step`` with ``off_path`` by the env's rule (what ends the episode)."""
        if self.path_sight is None:
            return step
        return dataclasses.replace(step, off_path=bool(self.off_path(self._kinematics[:2], step.off_path)))

    def _info(self, step: PathStep, success: bool) -> dict[str, Any]:
        return {
            "is_success": bool(success),
            "progress": step.progress,
            "progress_fraction": step.progress / self.path.length,
            "segment": step.segment,
            "over_hole": step.over_hole,
            "off_path": step.off_path,
            "tilt": self.sim.data.qpos[:2].copy(),
        }

    # ------------------------------------------------------------------ pickling
    def __getstate__(self) -> dict:
        tracker = (self.tracker.segment, self.tracker.progress)
        rng = None if self._np_random is None else self._np_random.bit_generator.state
        return {
            "kwargs": self._kwargs,
            "sim_state": self.sim.get_state(),
            "episode": (tracker, self._last, self._has_reset, self._episode_over),
            "np_random": rng,
        }

    def __setstate__(self, state: dict) -> None:
        type(self).__init__(self, **state["kwargs"])
        self.sim.set_state(state["sim_state"])
        self._kinematics = self.sim.layout.board_frame_one(self.sim.data.qpos, self.sim.data.qvel)[0]
        (self.tracker.segment, self.tracker.progress), self._last, self._has_reset, self._episode_over = state[
            "episode"
        ]
        if state["np_random"] is not None:
            rng = np.random.Generator(np.random.PCG64())
            rng.bit_generator.state = state["np_random"]
            self._np_random = rng
