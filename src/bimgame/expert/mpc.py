"""Random-shooting model-predictive control with the simulator as its model (Paul & van Baar 2018).

At every step, from the current simulator state, the expert samples K action sequences of H steps,
rolls all of them out with :meth:`~bimgame.sim.physics.MazeSim.rollout` (``mujoco.rollout``), scores each
by its summed planning reward and applies the first action of the best.

Planning rewards are progress towards the goal, summed over the horizon:
``Σ_t d(s_t) − d(s_{t+1})`` with ``d`` the marble's radial distance from the centre (``"radial"``,
the paper's, written there with the opposite sign) or its geodesic distance through the gates
(``"geodesic"``) to the task's goal: the centre for FULL, the far side of the k-th wall for STGk.
The sum telescopes to ``d(s_0) − d(s_H)``, so only the final states of the rollouts are scored —
exactly the same ranking as summing per step, at a fraction of the cost.

Sampling: ``"uniform"`` draws each of the H actions independently; ``"hold"`` draws an action and
holds it for a random 3–5 steps (the board needs several consecutive steps to reach a useful
tilt). benchmarks/bench_expert.py compares the settings; the defaults (radial, hold, K=10, H=20)
are the best of that table.

The expert acts on the true simulator state (``act(state) -> action``), so it can label states
visited by any policy (DAgger) as long as the caller has that state.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from bimgame.envs.env import DISCRETE_TILTS, BallInMazeEnv
from bimgame.sim.maze import MazeSpec
from bimgame.sim.maze_sets import UNLIMITED_MAZE_NUMBERS
from bimgame.sim.physics import MazeSim
from bimgame.sim.tasks import Task, parse_task
from bimgame.util.settings import is_integer

__all__ = ["MPCConfig", "RandomShootingMPC", "SAMPLINGS", "PLANNING_REWARDS", "run_expert_episode"]

SAMPLINGS = ("uniform", "hold")
PLANNING_REWARDS = ("radial", "geodesic")


@dataclasses.dataclass(frozen=True)
class MPCConfig:
    """Settings of the random-shooting expert (defaults chosen in benchmarks/bench_expert.py)."""

    n_samples: int = 10
    """K: action sequences sampled per decision (the paper's K=10)."""
    horizon: int = 20
    """H: steps per sampled sequence."""
    sampling: str = "hold"
    """"uniform" (independent actions) or "hold" (each action held for hold_min..hold_max steps)."""
    hold_min: int = 3
    """"hold" sampling: shortest run of one action (steps)."""
    hold_max: int = 5
    """"hold" sampling: longest run of one action (steps)."""
    reward: str = "radial"
    """Planning reward: "radial" (the paper's) or "geodesic" progress towards the centre."""
    nthread: int = 1
    """Threads for the rollouts (1 inside worker processes)."""

    def __post_init__(self) -> None:
        for name in ("n_samples", "horizon", "hold_min", "hold_max", "nthread"):
            value = getattr(self, name)
            if not (is_integer(value) and value >= 1):
                raise ValueError(f"MPCConfig.{name} must be a positive integer, got {value!r}")
        if self.hold_max < self.hold_min:
            raise ValueError(f"MPCConfig.hold_max ({self.hold_max}) must be >= hold_min ({self.hold_min})")
        if self.sampling not in SAMPLINGS:
            raise ValueError(f"unknown MPCConfig.sampling {self.sampling!r}; allowed: {', '.join(SAMPLINGS)}")
        if self.reward not in PLANNING_REWARDS:
            raise ValueError(f"unknown MPCConfig.reward {self.reward!r}; allowed: {', '.join(PLANNING_REWARDS)}")

    @property
    def sim_steps_per_decision(self) -> int:
        """Simulator steps one decision rolls out: K sequences of H steps."""
        return self.n_samples * self.horizon


class RandomShootingMPC:
    """The MPC expert. ``act(state)`` returns a discrete action (0..4) for a physics state from
    :meth:`MazeSim.get_state`; every random draw comes from ``rng``.

    Args:
        maze: the maze it plans in (must match the env it controls; default MERL's).
        config: K, H, sampling and planning reward.
        rng: the seeded generator for the sampled sequences.
        task: what the geodesic reward measures progress towards: the centre (FULL, STG4) or,
            for STGk, passing the k-th wall (any of its gates will do).
        n_marbles: marbles in the model.
    """

    def __init__(
        self,
        maze: MazeSpec | None = None,
        config: MPCConfig | None = None,
        *,
        rng: np.random.Generator,
        task: str | Task = "FULL",
        n_marbles: int = 1,
    ):
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy Generator (np.random.default_rng(seed)), got {type(rng).__name__}")
        self.maze = maze if maze is not None else MazeSpec.merl()
        self.config = config if config is not None else MPCConfig()
        self.rng = rng
        self.task = parse_task(task, self.maze)
        self.to_channel = self.task.goal_channel(self.maze)
        self.sim = MazeSim(self.maze, n_marbles=n_marbles)
        self._tilts = DISCRETE_TILTS * self.maze.tilt_step

    def sample_sequences(self) -> np.ndarray:
        """(K, H) discrete actions drawn per the sampling scheme."""
        c = self.config
        if c.sampling == "uniform":
            return self.rng.integers(5, size=(c.n_samples, c.horizon))
        # Hold: per sequence, segments of random length each with one random action.
        max_segments = -(-c.horizon // c.hold_min)
        lengths = self.rng.integers(c.hold_min, c.hold_max + 1, size=(c.n_samples, max_segments))
        actions = self.rng.integers(5, size=(c.n_samples, max_segments))
        segment = np.minimum(
            (np.cumsum(lengths, axis=1)[:, :, None] <= np.arange(c.horizon)).sum(axis=1), max_segments - 1
        )
        return np.take_along_axis(actions, segment, axis=1)

    def distance(self, states: np.ndarray) -> np.ndarray:
        """Planning distance of each state (summed over marbles): radial or geodesic."""
        positions, _ = self.sim.layout.board_frame(states)
        x, y = positions[..., 0], positions[..., 1]
        if self.config.reward == "radial":
            d = np.hypot(x, y)
        else:
            d = self.maze.geodesic_distance(x, y, self.to_channel)
        return d.sum(axis=-1)

    def plan(self, state: np.ndarray) -> tuple[int, dict[str, Any]]:
        """Best first action from ``state`` and what the planner saw (scores of all K sequences)."""
        state = np.asarray(state, dtype=np.float64)
        if state.shape != (self.sim.state_size,):
            raise ValueError(f"state must have shape ({self.sim.state_size},) (MazeSim.get_state), got {state.shape}")
        sequences = self.sample_sequences()
        finals = self.sim.rollout(state, self._tilts[sequences], nthread=self.config.nthread)[:, -1]
        scores = self.distance(state[None])[0] - self.distance(finals)
        best = int(np.argmax(scores))
        return int(sequences[best, 0]), {"scores": scores, "sequence": sequences[best]}

    def act(self, state: np.ndarray) -> int:
        """The expert's action for a physics state."""
        return self.plan(state)[0]

    def close(self) -> None:
        self.sim.close()


def run_expert_episode(
    task: str,
    seed: int,
    config: MPCConfig | None = None,
    *,
    maze: MazeSpec | None = None,
    maze_number: int | None = None,
    max_steps: int | None = None,
    randomize: Any = None,
) -> dict[str, Any]:
    """One episode of the MPC expert on ``task`` from ``reset(seed=seed)``; ``randomize`` (a
    :class:`~bimgame.envs.randomization.Randomization`) plays it on a randomised board while the
    expert plans with the nominal model.

    ``maze_number``: play training maze number ``maze_number`` (:func:`bimgame.sim.maze_sets.maze_number`
    on ``maze``'s board, default MERL's) exactly as an env built with ``num_mazes`` plays it after
    ``reset(seed=seed, options={"maze": maze_number})`` — its physics, and state observations that
    end with the maze's encoding (:func:`~bimgame.envs.mazes.maze_encoding`) — so that the episode is
    one a learner on those mazes could have seen; the expert plans in that maze. None: ``maze`` itself.

    Returns arrays (T = episode length): ``actions`` (T,) int64, ``rewards`` (T,) float64,
    ``terminations``/``truncations`` (T,) bool, ``observations`` (T+1, obs_dim) float32 state
    observations, ``sim_states`` (T+1, state_size) float64 physics states (enough to re-render
    the pixel observation exactly), ``channels`` (T+1, n) int64, and scalars ``seed``, ``success``;
    with ``maze_number`` also the scalar ``maze``, that number.
    """
    task_enum = parse_task(task)
    maze = maze if maze is not None else MazeSpec.merl()
    options: dict[str, Any] = {}
    if maze_number is None:
        env = BallInMazeEnv(task_enum, obs_mode="state", maze=maze, randomize=randomize)
    else:
        if not (is_integer(maze_number) and 0 <= maze_number < UNLIMITED_MAZE_NUMBERS):
            raise ValueError(
                f"maze_number must be an integer in 0..{UNLIMITED_MAZE_NUMBERS - 1} (a training maze), "
                f"got {maze_number!r}"
            )
        # A set of this one maze: the env checks the number, builds the slotted physics every env
        # with num_mazes has, and needs the option (else it would draw the maze from its generator).
        env = BallInMazeEnv(
            task_enum, obs_mode="state", maze=maze, randomize=randomize, num_mazes=1, start_maze=maze_number
        )
        options["maze"] = maze_number
    obs, info = env.reset(seed=seed, options=options)
    expert = RandomShootingMPC(env.maze, config, rng=np.random.default_rng(seed), task=task_enum)
    limit = max_steps if max_steps is not None else task_enum.time_limit
    observations, sim_states, channels = [obs], [env.sim.get_state()], [info["channel"]]
    actions, rewards, terminations, truncations = [], [], [], []
    for step in range(limit):
        action = expert.act(sim_states[-1])
        obs, reward, terminated, _, info = env.step(action)
        truncated = not terminated and step == limit - 1
        actions.append(action)
        rewards.append(reward)
        terminations.append(terminated)
        truncations.append(truncated)
        observations.append(obs)
        sim_states.append(env.sim.get_state())
        channels.append(info["channel"])
        if terminated:
            break
    expert.close()
    env.close()
    episode: dict[str, Any] = {
        "actions": np.array(actions, dtype=np.int64),
        "rewards": np.array(rewards, dtype=np.float64),
        "terminations": np.array(terminations, dtype=bool),
        "truncations": np.array(truncations, dtype=bool),
        "observations": np.array(observations, dtype=np.float32),
        "sim_states": np.array(sim_states, dtype=np.float64),
        "channels": np.array(channels, dtype=np.int64),
        "seed": np.int64(seed),
        "success": np.bool_(bool(terminations and terminations[-1])),
    }
    if maze_number is not None:
        episode["maze"] = np.int64(maze_number)
    return episode
