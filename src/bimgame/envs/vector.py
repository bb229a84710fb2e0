"""A batched vector env: all sub-environments are stepped by one ``mujoco.rollout`` call on a
thread pool and observed with vectorised numpy.

It reproduces ``gym.make_vec(id, num_envs, vectorization_mode="sync")`` exactly — same seeds give
the same episodes, rewards, terminations, truncations (time limits are built in) and next-step
autoresets — but without a Python loop over environments, so it is the fast way to feed batched
learners. ``gym.make_vec(id, num_envs)`` returns it by default (``vector_entry_point``).

``autoreset_mode=AutoresetMode.SAME_STEP`` resets a finished env inside the step that ended it (as
Gymnasium's SAME_STEP mode: ``infos["final_obs"]`` and ``infos["final_info"]`` hold the last
observation and info, masked by ``infos["_final_obs"]``), so every step is a real transition — what
the n-step actor-critic learners use.

``randomize=`` (a :class:`~bimgame.envs.randomization.Randomization`) randomises each env's episodes
exactly as a single env seeded the same way would (same draws, same steps and frames; a test checks
it against the sync vector env), each env drawing from its own generator at its resets;
``infos["randomization"]`` holds the draws as (num_envs,) arrays per parameter (nested, with
Gymnasium's ``_key`` masks, as the sync vector env nests a single env's dict). Physics ranges give
every env its own copy of the MuJoCo model, set at its resets and all stepped by the one
``mujoco.rollout`` call, which takes a model per initial state: measured on 64 envs (2 threads),
physics and actuation randomisation keeps 0.90–0.94 of the env steps/s of ``randomize=None`` (~30 µs
per reset to set a model; rebuilding one would cost ~3 ms). Camera ranges, batched numpy on the
frames (0.7 ms per 64 frames alone), add 1.1–1.3 ms per step of 64 pixel envs: 0.71–0.74 of the
pixel rate. ``benchmarks/bench_randomization.py`` measures these.

``start_sampler`` (a :class:`StartSampler`) chooses where episodes start — a start curriculum: at
every reset of an env it returns a physics state to start from, or None for the task's own random
start, and a tag that :attr:`BallInMazeVectorEnv.start_tags` keeps for the episode.

``num_mazes=`` (see :class:`~bimgame.envs.env.BallInMazeEnv`) gives every env its own maze per
episode, drawn from its own generator as a single env draws it; all are stepped by the one
``mujoco.rollout`` call, each on its own model copy switched by
:meth:`~bimgame.sim.physics.MazeSim.set_walls`, and their geodesic distances are computed in one
pass (:class:`~bimgame.sim.maze_rows.MazeRows`). ``benchmarks/bench_mazes.py`` measures the cost.
"""

from __future__ import annotations

import copy
import os
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from bimgame.envs.actions import actions_to_tilt_deltas, sub_env_generators
from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.gate_bearings import GateBearings
from bimgame.envs.mazes import EnvMazes, maze_encoding, maze_raster
from bimgame.envs.observe import Observer
from bimgame.envs.randomization import EpisodeRandomizer
from bimgame.sim.maze import MazeSpec
from bimgame.sim.maze_rows import MazeRows
from bimgame.sim.placement import check_sim_state, sample_start
from bimgame.sim.tasks import TaskState, initial_task_state, task_step
from bimgame.util.settings import is_integer

__all__ = ["BallInMazeVectorEnv", "StartSampler", "check_start_sampler", "sampled_start"]


class StartSampler(Protocol):
    """Chooses the start of each episode of a :class:`BallInMazeVectorEnv` (``start_sampler=``)."""

    def __call__(self, index: int, rng: np.random.Generator) -> tuple[np.ndarray | None, int]:
        """The start of the next episode of env ``index``: ``(state, tag)``, ``state`` a physics
        state (``MazeSim.get_state()``, checked as ``BallInMazeEnv.reset(options={"sim_state": …})``
        checks it) or None for the task's own random start, drawn exactly as without a sampler;
        ``tag`` an integer the env keeps in ``start_tags[index]`` for the episode. Draw every random
        choice from ``rng``, the env's own generator (seeded by ``reset(seed=…)``), so the same seed
        gives the same starts."""
        ...


def check_start_sampler(sampler: StartSampler | None) -> StartSampler | None:
    """``sampler`` itself if it is None or callable (a vector env's ``start_sampler=``), else ``ValueError``."""
    if sampler is not None and not callable(sampler):
        raise ValueError(
            f"start_sampler must be None or a callable (index, rng) -> (state or None, tag), got {sampler!r}"
        )
    return sampler


def sampled_start(sampler: StartSampler, index: int, rng: np.random.Generator) -> tuple[Any, int]:
    """``sampler``'s start for env ``index``: ``(state or None, tag)``, its form checked (the state's
    contents are the env's to check)."""
    result = sampler(index, rng)
    if not (isinstance(result, tuple) and len(result) == 2 and is_integer(result[1])):
        raise ValueError(
            f"start_sampler must return (state or None, integer tag); for env {index} it returned {result!r}"
        )
    state, tag = result
    return state, int(tag)


class BallInMazeVectorEnv(gym.vector.VectorEnv):
    """``num_envs`` copies of :class:`~bimgame.envs.env.BallInMazeEnv` stepped together.

    Args:
        num_envs: number of sub-environments.
        max_episode_steps: time limit (truncation), as ``TimeLimit`` would apply; None for none.
        nthread: threads for ``mujoco.rollout``. Default: 1 below 32 envs (measured: a second
            thread does not pay for its dispatch on small batches), else all cores up to 2.
            Use 1 inside worker processes that already use every core.
        autoreset_mode: ``NEXT_STEP`` (default, as ``gym.make_vec``) or ``SAME_STEP``.
        start_sampler: where episodes start (:class:`StartSampler`), called at every reset of every
            env — the first ``reset()`` and each autoreset — with the env's index and its own
            generator. None (default): the task's random starts.
        state_info: also report ``infos["state"]``, the state observation (B, 7·n…; see
            :class:`~bimgame.envs.observe.Observer`) of the same step as the observation, whatever
            ``obs_mode`` is: privileged information for learners that train pixel policies with the
            simulator's state (auxiliary losses, an asymmetric critic), never an input of the policy.
        **env_kwargs: the keyword arguments of :class:`~bimgame.envs.env.BallInMazeEnv`, including
            ``randomize`` (see above).

    Attributes:
        randomizer: the current episodes' draws (an :class:`~bimgame.envs.randomization.EpisodeRandomizer`,
            one row per env), or None without ``randomize``.
        start_tags: int64 (num_envs,), the tag the sampler gave each env's current episode (0
            without a sampler). Read it *before* calling ``step()``: with ``SAME_STEP`` the step
            that ends an episode also starts the env's next one and overwrites its tag; with
            ``NEXT_STEP`` the tag stays until the following (resetting) step.
    """

    # Gymnasium's API: a class attribute, replaced per instance (with the instance's autoreset mode).
    metadata: dict[str, Any] = {  # noqa: RUF012
        "render_modes": ["rgb_array"],
        "render_fps": 30,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int,
        *,
        max_episode_steps: int | None = None,
        nthread: int | None = None,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        start_sampler: StartSampler | None = None,
        state_info: bool = False,
        **env_kwargs: Any,
    ):
        if not (is_integer(num_envs) and num_envs >= 1):
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        if max_episode_steps is not None and not (is_integer(max_episode_steps) and max_episode_steps >= 1):
            raise ValueError(f"max_episode_steps must be a positive integer or None, got {max_episode_steps!r}")
        modes = {m.name.lower(): m for m in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)}
        modes.update({m.value: m for m in list(modes.values())})
        mode = autoreset_mode.value if isinstance(autoreset_mode, AutoresetMode) else autoreset_mode
        if mode not in modes:
            raise ValueError(f"autoreset_mode must be one of {sorted(modes)}, got {autoreset_mode!r}")
        self.autoreset_mode = modes[mode]
        self.metadata = {**self.metadata, "autoreset_mode": self.autoreset_mode}
        if nthread is None:
            nthread = 1 if num_envs < 32 else max(1, min(2, os.cpu_count() or 1))
        if not (is_integer(nthread) and nthread >= 1):
            raise ValueError(f"nthread must be an integer >= 1, got {nthread!r}")
        self.start_sampler = check_start_sampler(start_sampler)
        if not isinstance(state_info, bool):
            raise ValueError(f"state_info must be True or False, got {state_info!r}")
        self.state_info = state_info
        # One template env validates the arguments and owns the model, observer and spaces.
        self.template = BallInMazeEnv(**env_kwargs)
        self.num_envs = int(num_envs)
        self.max_episode_steps = max_episode_steps
        self.nthread = int(nthread)
        self.render_mode = self.template.render_mode
        self.single_observation_space = self.template.observation_space
        self.single_action_space = self.template.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.sim = self.template.sim
        self.maze = self.template.maze
        self.task = self.template.task
        n = self.template.n_marbles
        self._states = np.zeros((self.num_envs, self.sim.state_size))
        self._task_state = TaskState(
            np.zeros((self.num_envs, n), dtype=np.int64), np.zeros((self.num_envs, n), dtype=bool)
        )
        self._elapsed = np.zeros(self.num_envs, dtype=np.int64)
        self.start_tags = np.zeros(self.num_envs, dtype=np.int64)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._rngs: list[np.random.Generator] = []
        self._has_reset = False
        #: The env's mazes (None: every env shows :attr:`maze`), and each env's current maze number.
        self.mazes: EnvMazes | None = self.template.mazes
        self.maze_numbers = np.zeros(self.num_envs, dtype=np.int64)
        self._env_mazes: list[MazeSpec] = [self.maze] * self.num_envs
        self._state_observer = Observer(self.maze, n, "state")  # the marbles' state: the maze is not in it
        self._encodings: np.ndarray | None = None
        self._backgrounds: np.ndarray | None = None
        self._bearings: GateBearings | None = None
        #: The channel ``info["goal_distance"]`` measures to (the task's goal; 0, the centre, for FULL).
        self.goal_channel = self.task.goal_channel(self.maze)
        self._distance_rows = self._distance_tables()
        if self.mazes is not None:
            if self.template.observer.encoding_size:
                self._encodings = np.zeros((self.num_envs, self.template.observer.encoding_size), dtype=np.float32)
            if self.template.bearings is not None:
                self._bearings = GateBearings(self.mazes.base, self.num_envs, self.mazes.maze_set.rules.max_gates)
            if self.template.obs_mode == "pixels":
                size = self.template.observer.obs_size
                self._backgrounds = np.zeros((self.num_envs, size, size), dtype=np.uint8)
        randomize = self.template.randomize
        self.randomizer = (
            None
            if randomize is None
            else EpisodeRandomizer(
                randomize,
                self.maze,
                self.num_envs,
                self.template.observer.raster if self.template.obs_mode == "pixels" else None,
            )
        )
        self._physical = self.randomizer is not None and self.randomizer.physical
        self._models: list | None = None
        if self._physical or self.mazes is not None:
            # One model per env, each with its episode's physics and maze, all stepped by one rollout call.
            self._models = [copy.copy(self.sim.model) for _ in range(self.num_envs)]
            self._max_tilt = np.full(self.num_envs, self.maze.max_tilt)

    # ------------------------------------------------------------------ API
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        first_mazes = self._first_mazes(options)
        self._rngs = sub_env_generators(seed, self.num_envs, self._rngs)
        self._reset_envs(np.ones(self.num_envs, dtype=bool), first_mazes)
        self._autoreset[:] = False
        self._has_reset = True
        crossings = np.zeros_like(self._task_state.channel)
        positions, velocities = self.sim.layout.board_frame(self._states)
        return self._observe_and_info(positions, velocities, crossings, np.zeros(self.num_envs, dtype=bool))

    def step(self, actions):
        if not self._has_reset:
            raise RuntimeError("call reset() before step()")
        deltas = actions_to_tilt_deltas(actions, self.num_envs, self.template.action_type, self.maze.tilt_step)
        resetting = self._autoreset.copy()
        stepping = ~resetting
        reward = np.zeros(self.num_envs)
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = np.zeros(self.num_envs, dtype=bool)
        crossings = np.zeros_like(self._task_state.channel)
        if stepping.any():
            idx = np.flatnonzero(stepping)
            self._rollout(idx, deltas[idx])
        # One decode of every state serves the task, the observations and the infos; only envs
        # that were reset this step are decoded again.
        positions, velocities = self.sim.layout.board_frame(self._states)
        if stepping.any():
            sub_state = TaskState(self._task_state.channel[idx], self._task_state.reached[idx])
            new_state, r, term, cross = task_step(self.task, self.maze, sub_state, positions[idx, :, :2])
            self._task_state.channel[idx] = new_state.channel
            self._task_state.reached[idx] = new_state.reached
            reward[idx] = r
            terminated[idx] = term
            crossings[idx] = cross
            self._elapsed[idx] += 1
            if self.max_episode_steps is not None:
                truncated[idx] = self._elapsed[idx] >= self.max_episode_steps
        done = terminated | truncated
        final: tuple[np.ndarray, dict[str, Any]] | None = None
        if self.autoreset_mode == AutoresetMode.SAME_STEP:
            if done.any():
                final = self._observe_and_info(positions, velocities, crossings, terminated.copy())
                resetting = done
                crossings = np.where(done[:, None], 0, crossings)
            done = np.zeros_like(done)
        if resetting.any():
            self._reset_envs(resetting)
            positions[resetting], velocities[resetting] = self.sim.layout.board_frame(self._states[resetting])
        self._autoreset = done
        obs, infos = self._observe_and_info(
            positions, velocities, crossings, terminated & ~resetting if final else terminated.copy()
        )
        if final is not None:
            infos["final_obs"], infos["final_info"] = final
            infos["_final_obs"] = infos["_final_info"] = resetting.copy()
        return obs, reward, terminated, truncated, infos

    def render(self) -> tuple[np.ndarray, ...] | None:
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array'")
            return None
        positions, _ = self.sim.layout.board_frame(self._states)
        size = self.template.observer.obs_size
        return tuple(
            maze_raster(self._env_mazes[i], size, None if self.mazes is None else self.mazes.base).rgb(
                positions[i, :, :2], size=self.template.render_size, tilt=self._states[i, self.sim.layout.tilt]
            )
            for i in range(self.num_envs)
        )

    def close_extras(self, **kwargs: Any) -> None:
        self.template.close()

    # ------------------------------------------------------------------ helpers
    def _rollout(self, idx: np.ndarray, deltas: np.ndarray) -> None:
        """Step envs ``idx`` by ``deltas``, with their episodes' actuation and physics when randomised
        (then a model each)."""
        randomizer, models, max_tilt = self.randomizer, None, None
        if randomizer is not None and randomizer.acting:
            deltas = randomizer.tilt_deltas(deltas, idx, self._elapsed[idx])
        if self._models is not None:
            models = [self._models[i] for i in idx]
            if self._physical:
                max_tilt = self._max_tilt[idx]
        self._states[idx] = self.sim.rollout(
            self._states[idx], deltas[:, None], nthread=self.nthread, models=models, max_tilt=max_tilt
        )[:, 0]

    def _first_mazes(self, options: Any) -> np.ndarray | None:
        """The maze numbers of ``reset(options={"maze": …})``, checked; None without options."""
        if not options:
            return None
        allowed = "'maze' (with num_mazes: one maze number per env)"
        if not isinstance(options, dict) or set(options) != {"maze"}:
            shown = sorted(options) if isinstance(options, dict) else repr(options)
            raise ValueError(f"BallInMazeVectorEnv.reset takes only the option {allowed}, got {shown}")
        if self.mazes is None:
            raise ValueError("reset option 'maze' needs a vector env built with num_mazes (it names mazes of the set)")
        numbers = np.asarray(options["maze"])
        if numbers.shape != (self.num_envs,):
            raise ValueError(
                f"options['maze'] must hold {self.num_envs} maze numbers (one per env), got {options['maze']!r}"
            )
        return np.array([self.mazes.check_number(n.item(), "options['maze']") for n in numbers], dtype=np.int64)

    def _reset_envs(self, mask: np.ndarray, mazes: np.ndarray | None = None) -> None:
        """Start new episodes in the envs of ``mask``; ``mazes``: every env's maze number (first reset)."""
        n = self.template.n_marbles
        for i in np.flatnonzero(mask):
            if self.mazes is not None:  # the maze first, as the single env draws it (or the caller's)
                self._switch_env_maze(
                    int(i), self.mazes.maze_set.draw(self._rngs[i]) if mazes is None else int(mazes[i])
                )
            state = None
            if self.start_sampler is not None:
                state, self.start_tags[i] = self._sampled_start(int(i), self.start_sampler)
            if state is None:
                xy = sample_start(self._env_mazes[i], n, self._rngs[i])
                self.sim.reset(xy)
                self._states[i] = self.sim.get_state()
            else:
                # Stepped by mujoco.rollout from a zero warm start, as every state: exactly the
                # single env's reset(options={"sim_state": state}).
                self._states[i], xy = state
            if self.randomizer is not None:  # drawn after the start, as the single env does
                self.randomizer.reset_row(int(i), self._rngs[i])
                if self._physical:
                    assert self._models is not None
                    physics = self.randomizer.physics(int(i))
                    self.sim.set_parameters(self._models[i], **physics)
                    self._max_tilt[i] = physics["max_tilt"]
                    if state is None:  # at rest on the flat board: the marbles' height is their radius
                        self._states[i, self.sim.layout.marble_pos[:, 2]] = physics["marble_radius"]
            start = initial_task_state(self.maze, xy[None], self.task)
            self._task_state.channel[i] = start.channel[0]
            self._task_state.reached[i] = start.reached[0]
            self._elapsed[i] = 0

    def _switch_env_maze(self, index: int, number: int) -> None:
        """Env ``index`` shows maze ``number`` of :attr:`mazes`: its model, tables and pictures."""
        assert self.mazes is not None and self._models is not None and self._distance_rows is not None
        spec = self.mazes.maze(number)
        self.sim.set_walls(spec, self._models[index])
        self._env_mazes[index] = spec
        self.maze_numbers[index] = number
        self._distance_rows.set_row(index, spec)
        if self._encodings is not None:
            self._encodings[index] = maze_encoding(spec)
        if self._bearings is not None:
            self._bearings.set_row(index, spec)
        if self._backgrounds is not None:
            self._backgrounds[index] = self.mazes.raster(spec, self._backgrounds.shape[1]).background

    def _sampled_start(self, index: int, sampler: StartSampler) -> tuple[tuple[np.ndarray, np.ndarray] | None, int]:
        """The sampler's start for env ``index``: ``((state, marble_xy) or None, tag)``, checked."""
        state, tag = sampled_start(sampler, index, self._rngs[index])
        if state is None:
            return None, tag
        name = f"the start_sampler's state for env {index} (tag {tag})"
        return check_sim_state(self._env_mazes[index], self.sim.layout, state, name), tag

    def _distance_tables(self) -> MazeRows | None:
        """Every env's gate tables for the geodesic distances to the centre and to the task's goal, in
        one pass per step (:class:`~bimgame.sim.maze_rows.MazeRows`, faster than the per-maze
        computation even when every env shows the one maze); with random mazes each row is set when
        its env switches maze. None for a board without walls."""
        board = self.maze if self.mazes is None else self.mazes.base
        if not board.walls:
            return None
        targets = (0, self.goal_channel) if self.goal_channel else (0,)
        if self.mazes is not None:
            return MazeRows(board, self.num_envs, self.mazes.maze_set.rules.max_gates, targets)
        rows = MazeRows(board, self.num_envs, max(1, *(len(wall.gates) for wall in board.walls)), targets)
        for index in range(self.num_envs):
            rows.set_row(index, board)
        return rows

    def _distances(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each marble's geodesic distance (B, n) to the centre and to the task's goal channel (the
        same array for FULL), in its env's maze."""
        if self._distance_rows is None:  # no walls: straight to the centre, the only goal
            centre = self.maze.geodesic_distance(x, y)
            return centre, centre
        distances = self._distance_rows.geodesic_distances(x, y)
        return distances[0], distances[-1]

    def _observe_and_info(
        self, positions: np.ndarray, velocities: np.ndarray, crossings: np.ndarray, success: np.ndarray
    ) -> tuple[np.ndarray, dict[str, Any]]:
        tilt = self._states[:, self.sim.layout.tilt]
        obs = self.template.observer.from_kinematics(
            positions,
            velocities,
            tilt,
            self._task_state.channel,
            encodings=self._encodings,
            backgrounds=self._backgrounds,
            bearings=None if self._bearings is None else self._bearings(positions[:, 0, 0], positions[:, 0, 1]),
        )
        if self.randomizer is not None and self.randomizer.observing:
            obs = self.randomizer.pixels(obs, self._elapsed, positions[..., :2])
        centre, goal = self._distances(positions[..., 0], positions[..., 1])
        values: dict[str, Any] = {
            "channel": self._task_state.channel.copy(),
            "gate_crossings": crossings.astype(np.int64),
            "geodesic_distance": centre,
            "goal_distance": goal,
            "is_success": success,
            "tilt": tilt,
        }
        if self.state_info:
            channels = self._task_state.channel
            values["state"] = self._state_observer.from_kinematics(positions, velocities, tilt, channels)
        if self.mazes is not None:
            values["maze"] = self.maze_numbers.copy()
        every_env = np.ones(self.num_envs, dtype=bool)  # Gymnasium's per-key "_key" masks
        if self.randomizer is not None:  # nested as Gymnasium nests a dict info, with its own masks
            values["randomization"] = {
                name: v
                for key, value in self.randomizer.info().items()
                for name, v in ((key, value), (f"_{key}", every_env))
            }
        infos: dict[str, Any] = {}
        for key, value in values.items():
            infos[key] = value
            infos[f"_{key}"] = every_env
        return obs, infos
