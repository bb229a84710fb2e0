"""A batched vector env of CyberRunner's labyrinth: N boards stepped by one ``mujoco.rollout`` call.

:class:`LabyrinthVectorEnv` is the labyrinth's counterpart of
:class:`~bimgame.envs.vector.BallInMazeVectorEnv`: what a learner's
:class:`~bimgame.learn.rollout.RolloutCollector` steps. It reproduces N
:class:`~bimgame.envs.labyrinth_env.LabyrinthEnv` (as ``gym.make`` builds them, with their time
limit) exactly — sub-env i reset with ``seed + i``, as Gymnasium's and ``BallInMazeVectorEnv``'s
vector envs seed them, gives bit-identical observations, rewards, terminations and truncations (a
test checks it step by step across episode ends) — without a Python loop over MuJoCo data:

- physics: one :meth:`~bimgame.sim.labyrinth_physics.LabyrinthSim.rollout` call per step, every
  board from its own state (bit-identical to :meth:`~bimgame.sim.labyrinth_physics.LabyrinthSim.step`);
- bookkeeping, vectorised numpy over the boards: the board-frame decode
  (:meth:`~bimgame.sim.layout.StateLayout.board_frame`), the path-progress rule
  (:meth:`~bimgame.sim.labyrinth.WaypointPath.advance`, the batched form of the single env's
  :class:`~bimgame.sim.labyrinth_tracker.ScalarPathProgress`), holes, goal, reward, time limit and
  the state observation (:func:`~bimgame.envs.labyrinth_env.path_points_ahead`). Measured on a loaded
  2-core machine, the batched rule beat a loop over 32 scalar trackers (≈ 0.7 ms against 1.0 ms a
  step) and scales better (128 boards: 1.5 ms against 4.9 ms); at 8 boards the loop is faster
  (0.2 ms against 0.6 ms), but physics (≈ 1.3 ms) dominates there anyway. Exact equality with the
  single env's scalar arithmetic holds because every operation is the same IEEE one in the same
  order (numpy's and libm's sin/cos agreed on 10⁶ samples here; a test checks the whole chain);
- resets (rare) run per board on the template env's sim and a scalar tracker, the single env's
  own code; pixel and CyberRunner observations draw each board's frame with its raster.

Speed (``benchmarks/bench_labyrinth.py``, one thread, a loaded 2-core machine): 32 boards of the
hard layout ran ≈ 6.7–8.2k env steps/s, 1.5–1.9× the single env's and 1.3–1.8× the circular maze's
``BallInMazeVectorEnv`` of 32 STG1 envs; about half the time is the physics.

Autoreset: ``SAME_STEP`` (the default, what the learners use) resets a finished board inside the
step that ended it, ``infos["final_obs"]`` / ``infos["final_info"]`` holding the finished step's
observation and info (masked by ``infos["_final_obs"]``); ``NEXT_STEP`` resets it at the next step
(Gymnasium's default). Infos hold the single env's keys as (N, …) arrays — ``is_success``,
``progress``, ``progress_fraction``, ``segment``, ``over_hole``, ``off_path``, ``tilt`` (rad; a
labyrinth episode also terminates by failing, so only ``is_success`` says it reached the goal) — plus
``task_reward`` (the step's reward) and, with ``state_info=True``,
``state``, the state observation (17,) whatever ``obs_mode`` is; every key has Gymnasium's ``_key``
mask.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from bimgame.envs.actions import actions_to_tilt_deltas, sub_env_generators
from bimgame.envs.labyrinth_cyberrunner import cyberrunner_observation, flatten_cyberrunner, marble_motion
from bimgame.envs.labyrinth_env import (
    LabyrinthEnv,
    labyrinth_max_episode_steps,
    path_points_ahead,
)
from bimgame.envs.labyrinth_pixels import pixel_observation
from bimgame.envs.vector import StartSampler, check_start_sampler, sampled_start
from bimgame.sim.labyrinth_render import LabyrinthRaster, board_grid
from bimgame.util.settings import is_integer

__all__ = ["LabyrinthVectorEnv"]

#: The autoreset modes, by name ("same_step", as ``training_env`` passes it) and by value ("SameStep").
_MODES = {key: m for m in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP) for key in (m.name.lower(), m.value)}


class LabyrinthVectorEnv(gym.vector.VectorEnv):
    """``num_envs`` copies of :class:`~bimgame.envs.labyrinth_env.LabyrinthEnv` stepped together.

    Args:
        num_envs: number of boards.
        layout: "easy", "medium" or "hard" (CyberRunner's boards).
        obs_mode: "state", "pixels", "cyberrunner" or "cyberrunner_flat" (see :class:`LabyrinthEnv`; the
            flat form is (N, 4110) float32, :func:`~bimgame.envs.labyrinth_cyberrunner.flatten_cyberrunner`;
            4112 with ``motion=True``).
        action_type: "continuous" (tilt rates in [-1, 1]², shape (N, 2)) or "discrete" (N integers 0..4).
        control_hz: 55 (CyberRunner's) or 30.
        max_episode_steps: time limit (truncation), as ``TimeLimit`` applies it; None: the registered
            ids' CyberRunner limit of 54.5 s, :func:`labyrinth_max_episode_steps` (3000 steps at 55 Hz,
            1636 at 30 Hz).
        nthread: threads of the ``mujoco.rollout`` call (1, the default, inside learner processes
            that share the cores).
        autoreset_mode: ``SAME_STEP`` (default) or ``NEXT_STEP`` (an ``AutoresetMode`` or its value).
        state_info: also report ``infos["state"]``, the state observation, whatever ``obs_mode`` is
            (privileged information for an asymmetric critic or auxiliary losses).
        start_sampler: where episodes start (a :class:`~bimgame.envs.vector.StartSampler`, e.g.
            :class:`~bimgame.learn.path_starts.PathStartCurriculum`), called at every reset of every
            board, the first ``reset()`` without options and each autoreset, with the board's index
            and its own generator; its state is a ``LabyrinthSim.get_state()`` vector, None the
            layout's own start (drawn as without a sampler). None (default): the layout's start.
        **env_kwargs: the other keyword arguments of :class:`LabyrinthEnv` (``start_noise``,
            ``progress_scale``, ``end_off_path``, ``board``, …), checked by it.

    Attributes:
        template: a :class:`LabyrinthEnv` built with the same arguments: its spaces, action type, sim.
        board: the :class:`~bimgame.sim.labyrinth.LabyrinthSpec`; ``maze`` is the same object (the
            name the collector reads ``max_tilt`` from).
        start_tags: int64 (N,), the tag ``start_sampler`` gave each board's current episode (0
            without a sampler); read it before ``step()``, as :class:`~bimgame.envs.vector.BallInMazeVectorEnv`'s.
    """

    # Gymnasium's API: a class attribute, replaced per instance (with the instance's autoreset mode).
    metadata: dict[str, Any] = {  # noqa: RUF012
        "render_modes": ["rgb_array"],
        "render_fps": 55,
        "autoreset_mode": AutoresetMode.SAME_STEP,
    }

    def __init__(
        self,
        num_envs: int,
        layout: str = "hard",
        *,
        obs_mode: str = "state",
        action_type: str = "continuous",
        control_hz: float = 55.0,
        max_episode_steps: int | None = None,
        nthread: int = 1,
        autoreset_mode: AutoresetMode | str = AutoresetMode.SAME_STEP,
        state_info: bool = False,
        start_sampler: StartSampler | None = None,
        **env_kwargs: Any,
    ):
        if not (is_integer(num_envs) and num_envs >= 1):
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        if max_episode_steps is not None and not (is_integer(max_episode_steps) and max_episode_steps >= 1):
            raise ValueError(f"max_episode_steps must be a positive integer or None, got {max_episode_steps!r}")
        if not (is_integer(nthread) and nthread >= 1):
            raise ValueError(f"nthread must be an integer >= 1, got {nthread!r}")
        mode = autoreset_mode.value if isinstance(autoreset_mode, AutoresetMode) else autoreset_mode
        if mode not in _MODES:
            raise ValueError(
                f"autoreset_mode must be one of {sorted(_MODES)} (AutoresetMode.SAME_STEP or NEXT_STEP), "
                f"got {autoreset_mode!r}"
            )
        if not isinstance(state_info, bool):
            raise ValueError(f"state_info must be True or False, got {state_info!r}")
        # The template checks every other argument (ValueError naming it and what is allowed).
        self.template = LabyrinthEnv(
            layout, obs_mode=obs_mode, action_type=action_type, control_hz=control_hz, **env_kwargs
        )
        self.autoreset_mode = _MODES[mode]
        self.metadata = {
            **self.metadata,
            "render_fps": self.template.control_hz,
            "autoreset_mode": self.autoreset_mode,
        }
        self.num_envs = int(num_envs)
        self.nthread = int(nthread)
        self.state_info = state_info
        self.start_sampler = check_start_sampler(start_sampler)
        self.max_episode_steps = (
            labyrinth_max_episode_steps(self.template.control_hz) if max_episode_steps is None else max_episode_steps
        )
        self.render_mode = self.template.render_mode
        self.single_observation_space = self.template.observation_space
        self.single_action_space = self.template.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.sim = self.template.sim
        self.board = self.maze = self.template.board
        self.path = self.board.path
        self.obs_mode, self.action_type = self.template.obs_mode, self.template.action_type
        n = self.num_envs
        self.start_tags = np.zeros(n, dtype=np.int64)
        self._states = np.zeros((n, self.sim.state_size))
        self._kinematics = np.zeros((n, 4))  # marble x, y, vx, vy (board frame)
        self._previous_xy = np.zeros((n, 2))  # the marble's position at the previous observation (motion)
        self._segment = np.zeros(n, dtype=np.int64)
        self._progress = np.zeros(n)
        self._off_path = np.zeros(n, dtype=bool)
        self._over_hole = np.zeros(n, dtype=bool)
        self._success = np.zeros(n, dtype=bool)
        self._elapsed = np.zeros(n, dtype=np.int64)
        self._autoreset = np.zeros(n, dtype=bool)
        self._rngs: list[np.random.Generator] = []
        self._has_reset = False
        self._render_raster: LabyrinthRaster | None = None

    # ------------------------------------------------------------------ API
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None):
        """Start every board's episode. ``seed``: an int (board i gets ``seed + i``, as Gymnasium's
        vector envs seed their sub-envs), a list of N ints or Nones, or None (fresh entropy at the
        first reset, else the boards' generators go on). ``options``: at most one of
        ``"marble_xy"`` (N, 2) m and ``"sim_state"`` (N, state_size), each board's start, as the
        single env's options of the same names."""
        starts = self._check_options(options)
        self._rngs = sub_env_generators(seed, self.num_envs, self._rngs)
        self._reset_envs(np.ones(self.num_envs, dtype=bool), starts)
        self._autoreset[:] = False
        self._has_reset = True
        return self._observe_and_info(np.zeros(self.num_envs))

    def step(self, actions: Any):
        """Step every board by its action: one ``mujoco.rollout`` call, then the rules, batched."""
        if not self._has_reset:
            raise RuntimeError("call reset() before step()")
        deltas = actions_to_tilt_deltas(actions, self.num_envs, self.action_type, self.template.tilt_step)
        resetting = self._autoreset.copy()
        stepping = ~resetting
        n = self.num_envs
        reward = np.zeros(n)
        terminated = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        idx = np.flatnonzero(stepping)
        if len(idx):
            if self.template.motion:
                self._previous_xy[idx] = self._kinematics[idx, :2]
            self._states[idx] = self.sim.rollout(self._states[idx], deltas[idx, None], nthread=self.nthread)[:, 0]
            positions, velocities = self.sim.layout.board_frame(self._states[idx])
            self._kinematics[idx] = np.concatenate([positions[:, 0, :2], velocities[:, 0, :2]], axis=1)
            reward[idx], terminated[idx] = self._rules(idx)
            self._elapsed[idx] += 1
            truncated[idx] = self._elapsed[idx] >= self.max_episode_steps
        done = terminated | truncated
        final: tuple[Any, dict[str, Any]] | None = None
        if self.autoreset_mode == AutoresetMode.SAME_STEP:
            if done.any():
                final = self._observe_and_info(reward)
                resetting = done
            done = np.zeros_like(done)
        if resetting.any():
            self._reset_envs(resetting)
        self._autoreset = done
        obs, infos = self._observe_and_info(reward)
        if final is not None:
            infos["final_obs"], infos["final_info"] = final
            infos["_final_obs"] = infos["_final_info"] = resetting.copy()
        return obs, reward, terminated, truncated, infos

    def render(self) -> tuple[np.ndarray, ...] | None:
        """Each board's top-down RGB frame (``render_mode="rgb_array"``)."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array'")
            return None
        if self._render_raster is None:
            grid = board_grid(self.board, self.template.render_size)
            self._render_raster = LabyrinthRaster(self.board, grid, path_width=self.template._path_width)
        return tuple(self._render_raster.rgb(xy) for xy in self._kinematics[:, :2])

    def close_extras(self, **kwargs: Any) -> None:
        self.template.close()

    # ------------------------------------------------------------------ stepping helpers
    def _rules(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Path progress, holes, goal, reward and termination of boards ``idx`` after their physics
        step: :meth:`LabyrinthEnv.step`'s rules, operation for operation, on arrays."""
        env, board = self.template, self.board
        xy = self._kinematics[idx, :2]
        old = self._progress[idx]
        segment, progress, off = self.path.advance(xy, self._segment[idx], old)
        off = env.off_path(xy, off)
        over = board.over_hole(xy)
        goal = (segment == self.path.n_segments - 1) & board.reached_goal(xy)
        self._segment[idx], self._progress[idx] = segment, progress
        self._off_path[idx], self._over_hole[idx] = off, over
        failed = over | (off & env.end_off_path)
        success = goal & ~over
        reward = np.where(failed, env.fail_reward, env.progress_scale * (progress - old))
        reward = np.where(success, reward + env.goal_bonus, reward)
        self._success[idx] = success
        return reward, failed | success

    def _check_options(self, options: dict[str, Any] | None) -> tuple[str, np.ndarray] | None:
        """``reset``'s options, checked: ``(name, (N, …) array)`` or None."""
        if not options:
            return None
        if not isinstance(options, dict) or len(options) != 1 or not set(options) <= {"marble_xy", "sim_state"}:
            shown = sorted(options) if isinstance(options, dict) else repr(options)
            raise ValueError(f"reset options must be at most one of 'marble_xy', 'sim_state'; got {shown}")
        ((name, value),) = options.items()
        width = 2 if name == "marble_xy" else self.sim.state_size
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            array = np.full(0, np.nan)
        if array.shape != (self.num_envs, width):
            raise ValueError(f"options[{name!r}] must have shape ({self.num_envs}, {width}) (one row per env)")
        return name, array

    def _reset_envs(self, mask: np.ndarray, starts: tuple[str, np.ndarray] | None = None) -> None:
        """New episodes on the boards of ``mask``, each exactly as :meth:`LabyrinthEnv.reset` starts
        one (same draws from the board's generator, same sim reset, same tracker): ``starts`` the
        first reset's options."""
        env, sim = self.template, self.sim
        for i in np.flatnonzero(mask):
            if starts is None:
                self._start(int(i))
            else:
                name, rows = starts
                try:
                    sim.set_state(rows[i]) if name == "sim_state" else sim.reset(rows[i])
                except ValueError as error:
                    raise ValueError(f"options[{name!r}][{i}]: {error}") from None
            self._states[i] = sim.get_state()
            kinematics = sim.layout.board_frame_one(sim.data.qpos, sim.data.qvel)[0]
            self._kinematics[i] = kinematics
            self._previous_xy[i] = kinematics[:2]
            step = env.tracker.reset(kinematics[:2])
            self._segment[i], self._progress[i] = step.segment, step.progress
            off = bool(env.off_path(kinematics[:2], step.off_path))
            self._off_path[i], self._over_hole[i], self._success[i] = off, step.over_hole, False
            self._elapsed[i] = 0

    def _start(self, i: int) -> None:
        """Board ``i``'s sim at the start of a new episode: the sampler's state (its tag kept), or the
        layout's start with its noise drawn from the board's generator."""
        sampled = None
        if self.start_sampler is not None:
            sampled, self.start_tags[i] = sampled_start(self.start_sampler, i, self._rngs[i])
        if sampled is None:
            noise = self.template.start_noise
            self.sim.reset(np.asarray(self.board.start) + self._rngs[i].uniform(-noise, noise, 2))
            return
        try:
            self.sim.set_state(sampled)
        except (TypeError, ValueError) as error:
            raise ValueError(f"the start_sampler's state for board {i} (tag {self.start_tags[i]}): {error}") from None

    # ------------------------------------------------------------------ observations
    def _state_obs(self, ahead: np.ndarray) -> np.ndarray:
        """(N, 17) float32 state observations (:class:`LabyrinthEnv`'s ``obs_mode="state"``)."""
        tilt = self._states[:, self.sim.layout.tilt]
        relative = (ahead - self._kinematics[:, None, :2]).reshape(self.num_envs, -1)
        progress = self._progress / self.path.length
        return np.concatenate([self._kinematics, tilt, progress[:, None], relative], axis=1).astype(np.float32)

    def _observe(self, ahead: np.ndarray) -> Any:
        """The N boards' observations in ``obs_mode``, batched."""
        if self.obs_mode == "state":
            surroundings = self.template.observer.surroundings
            state = self._state_obs(ahead)
            return (
                state if surroundings is None else np.concatenate([state, surroundings.of(self._kinematics[:, :2])], 1)
            )
        raster = self.template.observer.raster  # the single env's own raster (pixels or CyberRunner's sheet)
        assert raster is not None
        xy = self._kinematics[:, :2]
        if self.obs_mode == "pixels":
            return pixel_observation(raster, xy, self._previous_xy if self.template.motion else None)
        tilt = self._states[:, self.sim.layout.tilt]
        relative = (ahead - xy[:, None, :]).reshape(self.num_envs, -1)
        motion = marble_motion(xy, self._previous_xy, self.template.control_hz) if self.template.motion else None
        obs = cyberrunner_observation(raster, self.board.board_size, xy, tilt, relative, motion)
        return flatten_cyberrunner(obs) if self.obs_mode == "cyberrunner_flat" else obs

    def _observe_and_info(self, reward: np.ndarray) -> tuple[Any, dict[str, Any]]:
        """The current observations and infos (every key with its ``_key`` mask); ``reward`` is the
        step's, reported as ``task_reward``."""
        ahead = path_points_ahead(self.path, self._progress)
        values: dict[str, Any] = {
            "is_success": self._success.copy(),
            "progress": self._progress.copy(),
            "progress_fraction": self._progress / self.path.length,
            "segment": self._segment.copy(),
            "over_hole": self._over_hole.copy(),
            "off_path": self._off_path.copy(),
            "tilt": self._states[:, self.sim.layout.tilt],
            "task_reward": reward.copy(),
        }
        if self.state_info:
            values["state"] = self._state_obs(ahead)
        every_env = np.ones(self.num_envs, dtype=bool)
        infos: dict[str, Any] = {}
        for key, value in values.items():
            infos[key], infos[f"_{key}"] = value, every_env
        return self._observe(ahead), infos
