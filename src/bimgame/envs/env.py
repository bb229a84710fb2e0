"""Gymnasium environment of the Ball-in-Maze Game and its registration.

See :class:`BallInMazeEnv` for the full description (Gymnasium's documentation layout).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from bimgame.envs.actions import ACTION_TYPES, DISCRETE_TILTS, action_to_tilt_delta
from bimgame.envs.gate_bearings import GateBearings, check_gate_bearings
from bimgame.envs.mazes import EnvMazes, maze_encoding
from bimgame.envs.observe import OBS_MODES, Observer
from bimgame.envs.randomization import EpisodeRandomizer, Randomization, observation_space
from bimgame.sim.generate import GateRules
from bimgame.sim.maze import MazeSpec, MazeSpecError
from bimgame.sim.physics import MazeSim
from bimgame.sim.placement import check_marble_xy, check_n_marbles, check_sim_state, finite_array, sample_start
from bimgame.sim.tasks import Task, initial_task_state, parse_task, task_step_one
from bimgame.util.settings import is_integer, is_real

__all__ = ["BallInMazeEnv", "ACTION_TYPES", "DISCRETE_TILTS", "NO_ACTION", "sample_start", "action_to_tilt_delta"]

#: The "previous action" before an episode's first step (not a valid action): what the networks'
#: previous-action input and the datasets' ``prev_actions`` hold at step 0.
NO_ACTION = -1
#: The keys ``reset(options=...)`` takes, for error messages.
RESET_OPTIONS = "'marble_xy', 'sim_state', 'maze' (with num_mazes)"
_FAST_INTS = (int, np.int64, np.int32)
#: Largest ``render_size``: the raster draws up to this size; MuJoCo's offscreen buffer is 640 pixels.
MAX_RENDER_SIZE = {"raster": 2048, "mujoco": 640}


class BallInMazeEnv(gym.Env):
    """
    ## Description

    A steel marble in MERL's circular maze (Paul & van Baar, "Trajectory-based Learning for
    Ball-in-Maze Games", 2018): four concentric ring walls with gates around a goal region. The
    agent tilts the board; the marble rolls under gravity with friction and collisions, simulated
    by MuJoCo at 150 Hz with actions at 30 Hz.

    ## Action Space

    ``action_type="discrete"`` (default): ``Discrete(5)`` — 0 no-op, 1/2 tilt +/- one step about
    the board's x axis, 3/4 about its y axis. The step is ``tilt_step_deg`` (1° as in the paper);
    the tilt is ramped linearly over the action's 1/30 s and clamped at ``±max_tilt_deg`` (5°).
    Tilting +x raises the board's +y edge; tilting +y lowers its +x edge.
    ``action_type="continuous"``: ``Box(-1, 1, (2,))``, the tilt change about x and y in units of
    ``tilt_step_deg``.

    ## Observation Space

    ``obs_mode="pixels"`` (default): ``Box(0, 255, (1, 84, 84), uint8)``, a grayscale top-down
    view of the board in the board's frame (north up), drawn from the simulator state.
    ``obs_mode="state"``: ``Box((5n + 2,), float32)`` for ``n`` marbles, laid out as
    ``[x_1, y_1, vx_1, vy_1, …, x_n, y_n, vx_n, vy_n, tilt_x, tilt_y, channel_1, …, channel_n]``:
    board-frame positions (m) and velocities (m/s), the board's tilt (rad) and each marble's
    channel (0 = centre … 4 = outermost). With ``num_mazes``, then the episode's maze as each
    wall's openness at 32 angles (:func:`~bimgame.envs.mazes.maze_encoding`, 128 values in [0, 1]);
    with ``gate_bearings=True`` too, then per wall the sine and cosine of the angle from the (first)
    marble to the wall's nearest gate and that gate's half-width (:mod:`~bimgame.envs.gate_bearings`,
    12 values); pixels show the episode's maze.

    ## Rewards

    ``task="FULL"``: +1 for each wall crossed towards the centre, -1 for each crossed outwards.
    ``task="STGk"``: +1 when the marble passes through the k-th wall from the outside, else 0.
    A marble has crossed a wall once its centre has cleared the wall's far face.

    ## Starting State

    Board flat; each marble at rest at a uniformly random angle on the centre circle of the
    outermost channel (marbles at least two diameters apart; ``n_marbles`` beyond what fits there
    is refused at construction). ``reset(options={"marble_xy": ...})`` places them explicitly
    (board-frame metres, shape (n, 2)); a marble overlapping a wall's solid part, the rim or
    another marble is refused (``ValueError`` naming the wall or the marbles). A marble placed at
    its goal already (FULL: the centre; STGk: past the k-th wall) earns nothing for it; if every
    marble is, the first step ends the episode with reward 0.

    ``reset(options={"sim_state": state})`` starts from a whole physics state, a vector from
    ``env.sim.get_state()`` (e.g. a row of an expert dataset's ``infos["sim_state"]``): marbles,
    board and servo targets move on exactly as in the run it was taken from — replaying that run's
    actions reproduces its following states and observations bit for bit. The state must be finite,
    of length ``env.sim.state_size``, with the board's and the target tilt within ``±max_tilt`` and
    the marbles on the floor clear of walls, rim and each other up to what the soft contacts allow
    (:func:`~bimgame.sim.placement.check_sim_state`); else ``ValueError`` naming
    ``options['sim_state']``. The task's state (each marble's channel, whether it reached its goal)
    is derived from the marbles' positions as for ``marble_xy``: a marble inside a gate counts on
    the side of the wall's mid-line it is on (the run itself may still have counted it on the other
    side, until it cleared the wall). ``marble_xy`` and ``sim_state`` exclude each other.

    ## Many mazes

    ``num_mazes`` (None: the one ``maze``) draws each episode's maze as Procgen's ``num_levels``:
    mazes ``start_maze`` … of ``maze_split`` ``"train"`` or ``"test"`` (held out: no training set has
    their hashes; :mod:`bimgame.sim.maze_sets`); 0: a new maze every episode. Each keeps ``maze``'s
    board with 1–4 random gates per wall (``maze_rules``). ``reset(options={"maze": i})`` picks one;
    ``env.maze`` is the episode's maze, ``info["maze"]`` its number; the physics switches in place.

    ## Episode End

    Termination: FULL — the marble reaches the centre; STGk — it passes the k-th wall (with several
    marbles: when all have). Truncation is left to ``TimeLimit`` (registered ids use
    ``MAX_EPISODE_STEPS``: STG1 300, STG2 500, STG3 750, STG4 1000, FULL 1000).
    ``step()`` after a termination (or before the first ``reset()``) raises ``RuntimeError``: call
    ``reset()``. Truncation happens in the ``TimeLimit`` wrapper, which this env does not see: the
    unwrapped env stepped past a time limit simply continues the episode (and ``TimeLimit`` keeps
    reporting ``truncated=True``).

    ## Info

    ``channel`` (n,) int, ``gate_crossings`` (n,) int (+1 inwards / -1 outwards this step),
    ``geodesic_distance`` (n,) float (m, shortest path to the centre through the gates),
    ``goal_distance`` (n,) float (m, shortest path through the gates until the task's goal wall is
    passed: the geodesic distance for FULL),
    ``is_success`` bool (the task's goal reached), ``tilt`` (2,) float (rad). With ``num_mazes``:
    ``maze``, the episode's maze number. With ``randomize``:
    ``randomization``, the current episode's draws (a dict of floats, ``latency`` an int; see
    :class:`~bimgame.envs.randomization.Randomization` for names and units).

    ## Arguments

    ``task`` (FULL, STG1…STG4), ``obs_mode`` (pixels, state), ``action_type`` (discrete,
    continuous), ``tilt_step_deg``, ``max_tilt_deg``, ``maze`` (a :class:`MazeSpec` with at
    least one wall, default MERL's), ``n_marbles`` (1 up to what fits on the outermost channel's
    centre circle two diameters apart: 22 on MERL's maze), ``obs_size`` (pixels, 16..1024, default
    84), ``render_mode`` (None or "rgb_array"), ``render_size`` (16..2048, at most 640 with
    ``renderer="mujoco"``; default 480), ``renderer`` ("raster" — numpy, always available — or
    "mujoco" — MuJoCo's 3D OpenGL renderer), ``randomize`` (None — the default, nothing drawn —
    or a :class:`~bimgame.envs.randomization.Randomization` of ranges, or a dict of its fields:
    domain randomisation, drawn from ``np_random`` at every reset after the start; camera ranges
    need ``obs_mode="pixels"``), ``num_mazes``, ``start_maze``, ``maze_split``, ``maze_rules``,
    ``gate_bearings`` (state observations on many mazes; see Many mazes and Observation Space). Each
    is checked at construction (``ValueError`` naming it and what is allowed).

    ## Version History

    * v0: initial version.
    """

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 30}  # noqa: RUF012 - Gymnasium's API

    def __init__(
        self,
        task: str | Task = "FULL",
        *,
        obs_mode: str = "pixels",
        action_type: str = "discrete",
        tilt_step_deg: float | None = None,
        max_tilt_deg: float | None = None,
        maze: MazeSpec | None = None,
        n_marbles: int = 1,
        obs_size: int = 84,
        render_mode: str | None = None,
        render_size: int = 480,
        renderer: str = "raster",
        randomize: Randomization | Mapping[str, Any] | None = None,
        num_mazes: int | None = None,
        start_maze: int = 0,
        maze_split: str = "train",
        maze_rules: GateRules | None = None,
        gate_bearings: bool = False,
    ):
        spec = maze if maze is not None else MazeSpec.merl()
        if not isinstance(spec, MazeSpec):
            raise TypeError(f"maze must be a MazeSpec, got {type(spec).__name__}")
        changes = {}
        if tilt_step_deg is not None:
            changes["tilt_step"] = math.radians(_positive("tilt_step_deg", tilt_step_deg))
        if max_tilt_deg is not None:
            changes["max_tilt"] = math.radians(_positive("max_tilt_deg", max_tilt_deg))
        try:
            self.maze = spec.replace(**changes) if changes else spec
        except MazeSpecError as error:  # it names the fields in radians: say where they came from
            raise MazeSpecError(
                f"{error} (from tilt_step_deg={tilt_step_deg!r}, max_tilt_deg={max_tilt_deg!r}, in degrees)"
            ) from None
        #: The mazes episodes are drawn from (None: always :attr:`maze`).
        self.mazes = (
            None
            if num_mazes is None
            else EnvMazes.from_options(self.maze, num_mazes, start_maze, maze_split, maze_rules)
        )
        #: The current episode's maze number (None without ``num_mazes``).
        self.maze_number: int | None = None
        self._encoding: list[float] = []  # the state observations' maze encoding (set by switch_maze)
        check_gate_bearings(gate_bearings, num_mazes, obs_mode)
        #: The episode's maze as gate bearings (None unless ``gate_bearings``).
        self.bearings: GateBearings | None = None
        if self.mazes is not None:
            self.maze_number = self.mazes.first_number()
            self.maze = self.mazes.maze(self.maze_number)
        self.task = parse_task(task, self.maze)
        if obs_mode not in OBS_MODES:
            raise ValueError(f"unknown obs_mode {obs_mode!r}; allowed: {', '.join(OBS_MODES)}")
        if action_type not in ACTION_TYPES:
            raise ValueError(f"unknown action_type {action_type!r}; allowed: {', '.join(ACTION_TYPES)}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"unknown render_mode {render_mode!r}; allowed: None, 'rgb_array'")
        if renderer not in ("raster", "mujoco"):
            raise ValueError(f"unknown renderer {renderer!r}; allowed: 'raster', 'mujoco'")
        n_marbles = check_n_marbles(self.maze, n_marbles)  # also refuses a maze without walls
        limit = MAX_RENDER_SIZE[renderer]
        if not (is_integer(render_size) and 16 <= render_size <= limit):
            raise ValueError(
                f"render_size must be an integer in 16..{limit} (renderer={renderer!r}), got {render_size!r}"
            )
        self.randomize = Randomization.from_value(randomize)
        if self.randomize is not None:
            self.randomize.check(self.maze, obs_mode, obs_size)
            if self.mazes is not None and self.randomize.marble_radius is not None:
                raise ValueError(
                    "randomize.marble_radius with num_mazes: random mazes' gates are sized for the nominal "
                    "marble (GateRules.margin); leave marble_radius out of the randomisation"
                )
        self._init_kwargs = dict(
            task=self.task.value,
            obs_mode=obs_mode,
            action_type=action_type,
            maze=self.maze if self.mazes is None else self.mazes.base,
            n_marbles=int(n_marbles),
            obs_size=obs_size,
            render_mode=render_mode,
            render_size=render_size,
            renderer=renderer,
            randomize=self.randomize,
            num_mazes=num_mazes,
            start_maze=start_maze,
            maze_split=maze_split,
            maze_rules=maze_rules,
            gate_bearings=gate_bearings,
        )
        self.obs_mode = obs_mode
        self.action_type = action_type
        self.n_marbles = int(n_marbles)
        self.render_mode = render_mode
        self.render_size = int(render_size)
        self.renderer = renderer
        self.sim = MazeSim(
            self.maze, n_marbles=self.n_marbles, wall_slots=None if self.mazes is None else self.mazes.wall_slots
        )
        self.observer = Observer(
            self.maze,
            self.n_marbles,
            obs_mode,
            obs_size=obs_size,
            layout=self.sim.layout,
            maze_encoding=self.mazes is not None,
            board=None if self.mazes is None else self.mazes.base,
            gate_bearings=gate_bearings,
        )
        if gate_bearings:
            assert self.mazes is not None
            self.bearings = GateBearings(self.mazes.base, 1, self.mazes.maze_set.rules.max_gates)
            self.bearings.set_row(0, self.maze)
        self.observation_space = observation_space(
            self.observer.space, self.randomize, self.maze, self.n_marbles, obs_mode
        )
        #: The current episode's domain randomisation (None without ``randomize``).
        self.randomizer = (
            None
            if self.randomize is None
            else EpisodeRandomizer(self.randomize, self.maze, 1, self.observer.raster if obs_mode == "pixels" else None)
        )
        self._steps = 0  # steps since reset, counted only with randomize (the per-step noise's counter)
        if action_type == "discrete":
            self.action_space = spaces.Discrete(5)
        else:
            self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self._channels: list[int] = [self.maze.outermost_channel] * self.n_marbles
        self._reached: list[bool] = [False] * self.n_marbles
        self._has_reset = False
        self._episode_over = True  # until reset(): step() refuses to run (one bool check per step)
        self._discrete_deltas = [tuple(float(v) for v in row * self.maze.tilt_step) for row in DISCRETE_TILTS]
        self._mujoco_renderer: mujoco.Renderer | None = None

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        # Until this reset succeeds, step() refuses: a refused reset does not leave the previous
        # episode running.
        self._has_reset, self._episode_over = False, True
        super().reset(seed=seed)
        options = {} if options is None else options
        if not isinstance(options, Mapping):
            raise ValueError(f"reset options must be a dict (allowed keys: {RESET_OPTIONS}), got {options!r}")
        unknown = set(options) - {"marble_xy", "sim_state", "maze"}
        if unknown:
            raise ValueError(f"unknown reset options {sorted(unknown)}; allowed: {RESET_OPTIONS} (one of them)")
        if "marble_xy" in options and "sim_state" in options:
            raise ValueError(
                "reset options 'marble_xy' and 'sim_state' exclude each other: give the marbles' "
                "positions (a start at rest) or a whole physics state, not both"
            )
        if self.mazes is not None:  # the maze first: starts are checked against its walls
            number = (
                self.mazes.check_number(options["maze"], "options['maze']")
                if "maze" in options
                else self.mazes.maze_set.draw(self.np_random)
            )
            self.switch_maze(number)
        elif "maze" in options:
            raise ValueError("reset option 'maze' needs an env built with num_mazes (it names a maze of the set)")
        state = None
        if "sim_state" in options:
            state, xy = check_sim_state(self.maze, self.sim.layout, options["sim_state"], "options['sim_state']")
        elif "marble_xy" in options:
            xy = finite_array(
                "options['marble_xy']",
                options["marble_xy"],
                (self.n_marbles, 2),
                f" (x, y in metres, board frame, for each of the {self.n_marbles} marble(s))",
            )
            check_marble_xy(self.maze, xy, "options['marble_xy']")
        else:
            xy = sample_start(self.maze, self.n_marbles, self.np_random)
        if self.randomizer is not None:  # drawn after the start: a seed's starts do not depend on it
            self._start_randomized_episode(self.randomizer)
        if state is not None:
            self.sim.data.qacc_warmstart[:] = 0  # as MazeSim.reset; step() clears it anyway
            self.sim.set_state(state)
        else:
            self.sim.reset(xy)
        start = initial_task_state(self.maze, xy[None], self.task)
        self._channels = start.channel[0].tolist()
        self._reached = start.reached[0].tolist()
        self._has_reset = True
        self._episode_over = False
        kinematics = self.sim.layout.board_frame_one(self.sim.data.qpos, self.sim.data.qvel)
        return self._observe(kinematics), self._info(kinematics, [0] * self.n_marbles, False)

    def step(self, action):
        if self._episode_over:
            if not self._has_reset:
                raise RuntimeError("call reset() before step()")
            raise RuntimeError("the episode has ended (terminated); call reset() before step()")
        if type(action) in _FAST_INTS and 0 <= action < 5 and self.action_type == "discrete":
            delta = self._discrete_deltas[action]  # the common case, validated cheaply
        else:
            delta = action_to_tilt_delta(action, self.action_type, self.maze.tilt_step)
        if self.randomizer is not None:
            if self.randomizer.acting:
                delta = self.randomizer.tilt_deltas(
                    np.array([delta], dtype=np.float64), np.zeros(1, dtype=np.intp), np.array([self._steps])
                )[0]
            self._steps += 1
        sim = self.sim
        sim.step(delta)
        kinematics = sim.layout.board_frame_one(sim.data.qpos, sim.data.qvel)
        reward, terminated, crossings = task_step_one(
            self.task, self.maze, self._channels, self._reached, [math.hypot(k[0], k[1]) for k in kinematics]
        )
        self._episode_over = terminated
        return (self._observe(kinematics), reward, terminated, False, self._info(kinematics, crossings, terminated))

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array'")
            return None
        if self.renderer == "mujoco":
            return self._render_mujoco()
        positions, _ = self.sim.marble_kinematics()
        return self.observer.raster.rgb(positions[:, :2], size=self.render_size, tilt=self.sim.tilt)

    def close(self):
        if self._mujoco_renderer is not None:
            self._mujoco_renderer.close()
            self._mujoco_renderer = None
        self.sim.close()

    def switch_maze(self, number: int) -> None:
        """Show maze ``number`` of :attr:`mazes` from now on (``reset`` does it at every episode)."""
        if self.mazes is None:
            raise ValueError("switch_maze needs an env built with num_mazes")
        spec = self.mazes.maze(number)
        self.sim.set_walls(spec)
        self.maze, self.maze_number = spec, number
        if self.obs_mode == "state":  # what state observations end with (once, not per step); pixels show the maze
            self._encoding = maze_encoding(spec).tolist()
        if self.bearings is not None:
            self.bearings.set_row(0, spec)
        self.observer.set_maze(spec)

    # ------------------------------------------------------------------ helpers
    def _start_randomized_episode(self, randomizer: EpisodeRandomizer) -> None:
        """Draw the episode's randomisation from ``np_random`` and set its physics on the model."""
        randomizer.reset_row(0, self.np_random)
        self._draws = randomizer.row(0)  # the episode's draws, for every step's info
        self._steps = 0
        if randomizer.physical:
            self.sim.set_parameters(**randomizer.physics(0))

    def _observe(self, kinematics: list[tuple[float, float, float, float]]) -> np.ndarray:
        if self.obs_mode == "pixels":
            xy = np.array([k[:2] for k in kinematics])
            if self.randomizer is not None and self.randomizer.observing:
                frame = self.observer.raster.gray(xy[None])[:, None]
                return self.randomizer.pixels(frame, np.array([self._steps]), xy[None])[0]
            return self.observer.raster.gray(xy)[None]
        # The layout of Observer.from_kinematics, built from plain floats (the per-step fast path;
        # tests check the single env against the batched vector env observation by observation).
        tilt = self.sim.data.qpos
        values = [v for k in kinematics for v in k] + [tilt[0], tilt[1]] + self._channels
        if self.mazes is not None:
            values += self._encoding
        if self.bearings is not None:
            values += self.bearings.one(*kinematics[0][:2])
        return np.array(values, dtype=np.float32)

    def _info(self, kinematics, crossings: list[int], success: bool) -> dict[str, Any]:
        goal = self.task.goal_channel(self.maze)
        # To the centre and to the task's goal (the centre for FULL), each marble's channel found once.
        targets = (0, goal) if goal else (0,)
        distances = np.array([self.maze.geodesic_distances_one(k[0], k[1], targets) for k in kinematics])
        info = {
            "channel": np.array(self._channels),
            "gate_crossings": np.array(crossings),
            "geodesic_distance": distances[:, 0],
            "goal_distance": distances[:, -1],
            "is_success": success,
            "tilt": self.sim.data.qpos[:2].copy(),
        }
        if self.maze_number is not None:
            info["maze"] = self.maze_number
        if self.randomizer is not None:
            info["randomization"] = dict(self._draws)
        return info

    def _render_mujoco(self) -> np.ndarray:
        if self._mujoco_renderer is None:
            try:
                self._mujoco_renderer = mujoco.Renderer(self.sim.model, self.render_size, self.render_size)
            except Exception as error:  # no OpenGL context available
                raise RuntimeError(
                    "MuJoCo's 3D renderer needs an OpenGL backend and none could be created "
                    f"({error}). On a headless machine set MUJOCO_GL=egl (with a GPU driver) or "
                    "MUJOCO_GL=osmesa (apt-get install libosmesa6), or use renderer='raster', "
                    "which draws the same board without OpenGL."
                ) from error
        camera = _top_camera(self.maze)
        self._mujoco_renderer.update_scene(self.sim.data, camera=camera)
        return self._mujoco_renderer.render()

    # ------------------------------------------------------------------ pickling
    def __getstate__(self) -> dict:
        return {
            "kwargs": self._init_kwargs,
            "sim_state": self.sim.get_state(),
            "maze_number": self.maze_number,
            "task": (list(self._channels), list(self._reached), self._has_reset, self._episode_over),
            "np_random": None if self._np_random is None else self._np_random.bit_generator.state,
            "randomization": None
            if self.randomizer is None or not self._has_reset
            else (self.randomizer.state(0), self.randomizer.history[0].copy(), self._steps),
        }

    def __setstate__(self, state: dict) -> None:
        type(self).__init__(self, **state["kwargs"])
        if state.get("maze_number") is not None:
            self.switch_maze(state["maze_number"])
        if state.get("randomization") is not None:
            randomizer = self.randomizer
            assert randomizer is not None, "pickled with a randomisation, so built with one from the same kwargs"
            values, history, self._steps = state["randomization"]
            randomizer.set_row(0, values)
            self._draws = randomizer.row(0)
            randomizer.history[0] = history
            if randomizer.physical:
                self.sim.set_parameters(**randomizer.physics(0))
        self.sim.set_state(state["sim_state"])
        self._channels, self._reached, self._has_reset, *over = state["task"]
        self._episode_over = over[0] if over else not self._has_reset  # pickles from before the flag
        if state["np_random"] is not None:
            rng = np.random.Generator(np.random.PCG64())
            rng.bit_generator.state = state["np_random"]
            self._np_random = rng


def _positive(name: str, value: float) -> float:
    if not (is_real(value) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive number, got {value!r}")
    return float(value)


def _top_camera(spec: MazeSpec) -> mujoco.MjvCamera:
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = (0.0, 0.0, 0.0)
    camera.distance = 3.2 * (spec.rim_radius + spec.rim_thickness)
    camera.elevation = -60.0
    camera.azimuth = 90.0
    return camera
