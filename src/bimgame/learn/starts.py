"""Start curricula: where a learner's training episodes start, moved from near the goal back to the
task's own starts as the policy learns.

Both are :class:`~bimgame.envs.vector.StartSampler` s for ``BallInMazeVectorEnv(start_sampler=…)``,
plus what the learner feeds back and logs:

- ``record(tag, success)``: call it for every finished training episode, with the tag its episode
  started with (``env.start_tags[i]``, read *before* the step that ends it: with SAME_STEP autoreset
  that step already starts the next episode and overwrites the tag) and whether it reached the goal.
- ``status()``: numbers to log (the stage, how far back starts lie, the share of true starts).

The tag :data:`TRUE_START` marks the task's own start distribution (the sampler returned None).

- :class:`DemoStartCurriculum`: Backplay (Resnick et al., 2018) / "Learning Montezuma's Revenge from
  a single demonstration" (Salimans & Chen, 2018): start from expert states a few steps before the
  demonstration reached the goal, going further back once the policy succeeds from there.
- :class:`ReverseCurriculum`: "Reverse Curriculum Generation for Reinforcement Learning" (Florensa
  et al., 2017), without expert data: starts found by random walks back from just outside the goal,
  kept while the policy succeeds from them sometimes but not always.

Each owns its state and is meant for one process (an A3C worker owns one); every random choice is
drawn from the generator the env passes in, so a seeded env gives the same starts.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.envs.env import DISCRETE_TILTS
from bimgame.expert.datasets import load_dataset
from bimgame.learn.start_stages import TRUE_START, BackwardStages, StagedStarts, check_int, check_real, check_tag
from bimgame.sim.layout import StateLayout
from bimgame.sim.maze import MazeSpec
from bimgame.sim.physics import MazeSim
from bimgame.sim.placement import check_marble_xy, check_sim_state
from bimgame.sim.tasks import Task, parse_task

__all__ = ["TRUE_START", "DemoStartCurriculum", "ReverseCurriculum"]


def _layout(maze: MazeSpec, n_marbles: int) -> StateLayout:
    """The state layout of ``maze`` with ``n_marbles`` marbles (from a sim built and closed at once)."""
    sim = MazeSim(maze, n_marbles=n_marbles)
    layout = sim.layout
    sim.close()
    return layout


class DemoStartCurriculum(StagedStarts):
    """Starts from expert demonstrations, moved back from the goal stage by stage (Backplay).

    Each demonstration is cut at ``t_goal``, the first step at which every marble is at the task's
    goal (``channel <= task.goal_channel(maze)``), by the recorded channels or by the position
    itself (a marble inside a gate counts on the side of the wall's mid-line it is on, as the env
    counts a start: so no start is at the goal already). Episodes that never reach it are skipped.

    Stage k starts an episode ``d`` steps before ``t_goal`` of a uniformly chosen demonstration,
    ``d`` uniform in ``1..D_k`` and clipped to ``t_goal`` (``d = t_goal``: the demonstration's own
    first state), with ``D_0 = first_back`` and ``D_{k+1} = ceil(D_k · growth)``: a share of the
    starts stays close to the goal, as easier reminders. A share ``true_share`` of the episodes start
    from the task's own start distribution (tag :data:`TRUE_START`). Once the last ``window`` recorded
    episodes of the current stage (tag = the stage's index) succeeded at a rate of at least
    ``threshold``, the next stage begins. After the stage whose ``D_k`` reaches the longest
    ``t_goal`` comes the final one, where every start is a true start (:attr:`finished`).
    ``first_back=None``: every state of every demonstration from the first episode on.

    Args:
        episodes: ``(sim_states (T+1, S), channels (T+1, n))`` per demonstration: the physics states
            (``MazeSim.get_state()``) and each marble's channel before every step and after the last.
        task: the task the starts are for (its goal cuts the demonstrations).
        maze: the maze (default: MERL's).
        first_back, growth, threshold, window, true_share: the schedule above.
        source: what the episodes are, for error messages.
    """

    def __init__(
        self,
        episodes: Sequence[tuple[np.ndarray, np.ndarray]],
        task: str | Task = "FULL",
        maze: MazeSpec | None = None,
        *,
        first_back: int | None = 30,
        growth: float = 2.0,
        threshold: float = 0.8,
        window: int = 100,
        true_share: float = 0.1,
        source: str = "the given episodes",
    ):
        owner = "DemoStartCurriculum"
        self.maze = maze if maze is not None else MazeSpec.merl()
        self.task = parse_task(task, self.maze)
        self.first_back = None if first_back is None else check_int(owner, "first_back", first_back, 1)
        self.growth = check_real(owner, "growth", growth, 1.0, math.inf, open_low=True, allowed="a finite number > 1")
        self.threshold = check_real(owner, "threshold", threshold, 0.0, 1.0, open_low=True)
        self.window = check_int(owner, "window", window, 1)
        self.true_share = check_real(owner, "true_share", true_share, 0.0, 1.0)
        goal = self.task.goal_channel(self.maze)
        self._demos: list[np.ndarray] = []  # per usable demonstration, its states before t_goal
        layout: StateLayout | None = None
        for k, (states, channels) in enumerate(episodes):
            states = np.asarray(states, dtype=np.float64)
            channels = np.asarray(channels)
            if (
                channels.ndim != 2
                or states.ndim != 2
                or len(states) != len(channels)
                or not len(states)
                or channels.shape[1] < 1
            ):
                raise ValueError(
                    f"{source}: episode {k} must give sim_states (T+1, S) and channels (T+1, n) "
                    f"with the same number of rows, got shapes {states.shape} and {channels.shape}"
                )
            if layout is None:
                layout = _layout(self.maze, channels.shape[1])
            if channels.shape[1] != layout.n_marbles:
                raise ValueError(
                    f"{source}: episode {k} has {channels.shape[1]} marble(s), episode 0 "
                    f"{layout.n_marbles}: the demonstrations must have the same number"
                )
            if states.shape[1] != layout.size or not np.isfinite(states).all():
                raise ValueError(
                    f"{source}: episode {k}'s sim_states must be finite MazeSim.get_state() vectors "
                    f"of length {layout.size} ({layout.n_marbles} marble(s)), got shape {states.shape}"
                )
            positions, _ = layout.board_frame(states)
            at_goal = (channels <= goal).all(axis=1) | (
                self.maze.channel_of(positions[..., 0], positions[..., 1]) <= goal
            ).all(axis=1)
            reached = np.flatnonzero(at_goal)
            if len(reached) and reached[0] > 0:
                self._demos.append(states[: reached[0]].copy())
        if layout is None or not self._demos:  # no episode at all, or none reaching the goal
            raise ValueError(
                f"none of the {len(episodes)} episodes of {source} reaches the goal of task {self.task.value} "
                f"(every marble in channel <= {goal}) after its first state: no demonstration to start from; "
                f"use episodes of a task that passes at least {self.task.walls_to_pass(self.maze)} wall(s) "
                "(FULL passes them all)"
            )
        self.n_marbles = layout.n_marbles
        longest = max(len(d) for d in self._demos)
        self.stages = BackwardStages(
            owner, self.first_back, self.growth, longest, threshold=self.threshold, window=self.window, whole=True
        )

    @classmethod
    def from_dataset(
        cls, path: str | Path, task: str | Task = "FULL", maze: MazeSpec | None = None, **settings: Any
    ) -> DemoStartCurriculum:
        """The curriculum of a bimgame expert dataset directory (``bimgame.expert.datasets``; read
        with :func:`~bimgame.expert.datasets.load_dataset`, which verifies it): its episodes'
        ``infos['sim_state']`` and ``infos['channel']``. ``settings``: the constructor's keywords."""
        dataset = load_dataset(path)
        episodes = []
        for episode in dataset.iterate_episodes():
            infos = episode.infos or {}
            if "sim_state" not in infos or "channel" not in infos:
                raise ValueError(
                    f"episode {episode.id} of the dataset in {path} has no infos['sim_state'] / "
                    "infos['channel'] (not a bimgame expert dataset?)"
                )
            episodes.append((np.asarray(infos["sim_state"], dtype=np.float64), np.asarray(infos["channel"])))
        return cls(episodes, task, maze, source=f"the dataset in {path}", **settings)

    # ------------------------------------------------------------------ sampler
    @property
    def backs(self) -> list[int]:
        """``D_k`` of each stage (steps before a demonstration's goal)."""
        return [int(back) for back in self.stages.backs]

    @property
    def demos(self) -> int:
        """How many demonstrations reach the goal (the ones starts are taken from)."""
        return len(self._demos)

    def goal_step(self, demo: int) -> int:
        """``t_goal`` of usable demonstration ``demo``: its states before the goal."""
        return len(self._demos[demo])

    def __call__(self, index: int, rng: np.random.Generator) -> tuple[np.ndarray | None, int]:
        """The start of env ``index``'s next episode: ``(state, stage)``, or ``(None, TRUE_START)``."""
        if self.true_start(rng):
            return None, TRUE_START
        demo = self._demos[int(rng.integers(len(self._demos)))]
        back = min(int(rng.integers(1, int(self.stages.back) + 1)), len(demo))
        return demo[len(demo) - back].copy(), self.stage

    def status(self) -> dict[str, float]:
        """The stage, how far back (steps) its starts go, the share of true starts and the success
        rate of the current stage's window so far."""
        return {**self.stage_status(), "curriculum_steps_back": float(self.stages.back)}


class ReverseCurriculum:
    """Starts grown backwards from the goal by random walks (reverse curriculum generation), for
    one marble.

    Seeds: the marble at rest on the centre circle of the channel just outside the task's goal, at
    the angle of each gate of the goal's wall, board flat. Every start has an id (its tag, >= 0)
    and counts of tries and successes (:meth:`record`). A start tried at least ``min_tries`` times
    is *good* if its success rate lies in ``[low, high]``, *mastered* above, *too hard* below.

    Sampling: with probability ``true_share`` a true start (:data:`TRUE_START`); with probability
    ``replay_share`` a mastered start, uniformly (once there is one), so the policy keeps them;
    otherwise a start of the active pool, uniformly among those handed out fewer than ``min_tries``
    times (all of them once none is). The first active pool is the seeds. Once every active start
    has ``min_tries`` recorded tries, the next sample rebuilds it: mastered starts join the replay
    set, too-hard ones leave, good ones stay (counts cleared, at most ``pool_size`` of them), and
    ``pool_size`` new starts are drawn from the states visited by random walks ("Brownian motion":
    ``walk_steps`` uniformly random discrete actions) from the good starts — or, if none is good,
    from the starts mastered in this round, else from every mastered start, else from the seeds.
    Walk states at or after the goal (by the walk's channels or by position) are left out.

    Args:
        task: the task (its goal channel and wall).
        maze: the maze (default: MERL's).
        walk_steps, pool_size, min_tries, low, high, true_share, replay_share: as above.
    """

    def __init__(
        self,
        task: str | Task = "FULL",
        maze: MazeSpec | None = None,
        *,
        walk_steps: int = 30,
        pool_size: int = 100,
        min_tries: int = 3,
        low: float = 0.1,
        high: float = 0.9,
        true_share: float = 0.1,
        replay_share: float = 0.1,
    ):
        owner = "ReverseCurriculum"
        self.maze = maze if maze is not None else MazeSpec.merl()
        self.task = parse_task(task, self.maze)
        self.walk_steps = check_int(owner, "walk_steps", walk_steps, 1)
        self.pool_size = check_int(owner, "pool_size", pool_size, 1)
        self.min_tries = check_int(owner, "min_tries", min_tries, 1)
        self.low = check_real(owner, "low", low, 0.0, 1.0)
        self.high = check_real(owner, "high", high, 0.0, 1.0)
        if self.low > self.high:
            raise ValueError(f"{owner}.low ({low!r}) must not exceed {owner}.high ({high!r})")
        self.true_share = check_real(owner, "true_share", true_share, 0.0, 1.0)
        self.replay_share = check_real(owner, "replay_share", replay_share, 0.0, 1.0)
        if self.true_share + self.replay_share > 1.0:
            raise ValueError(
                f"{owner}.true_share + replay_share must be at most 1, got {true_share!r} + {replay_share!r}"
            )
        self.goal = self.task.goal_channel(self.maze)
        self._sim = MazeSim(self.maze, n_marbles=1)
        self._states: list[np.ndarray] = []
        self._xy: list[np.ndarray] = []
        self.tries: list[int] = []
        self.successes: list[int] = []
        self._issued: list[int] = []
        radius = self.maze.channel_centre_radius(self.goal + 1)
        for gate in self.maze.walls[self.goal].gates:
            xy = np.array([[radius * math.cos(gate.angle), radius * math.sin(gate.angle)]])
            check_marble_xy(self.maze, xy, f"the seed at gate {math.degrees(gate.angle):.1f}°")
            self._sim.reset(xy)
            self._add(self._sim.get_state(), xy)
        self.seeds = list(range(len(self._states)))
        self.active = list(self.seeds)
        self.mastered: list[int] = []
        self.rebuilds = 0
        self._good_last = 0

    def _add(self, state: np.ndarray, xy: np.ndarray) -> int:
        self._states.append(state)
        self._xy.append(xy)
        self.tries.append(0)
        self.successes.append(0)
        self._issued.append(0)
        return len(self._states) - 1

    def state(self, tag: int) -> np.ndarray:
        """The physics state of start ``tag`` (a copy)."""
        return self._states[tag].copy()

    # ------------------------------------------------------------------ sampler
    def __call__(self, index: int, rng: np.random.Generator) -> tuple[np.ndarray | None, int]:
        """The start of env ``index``'s next episode: ``(state, start id)``, or ``(None, TRUE_START)``."""
        if all(self.tries[i] >= self.min_tries for i in self.active):
            self._rebuild(rng)
        u = rng.random()
        if u < self.true_share:
            return None, TRUE_START
        if u < self.true_share + self.replay_share and self.mastered:
            tag = self.mastered[int(rng.integers(len(self.mastered)))]
        else:
            fresh = [i for i in self.active if self._issued[i] < self.min_tries]
            pool = fresh or self.active
            tag = pool[int(rng.integers(len(pool)))]
        self._issued[tag] += 1
        return self._states[tag].copy(), tag

    def record(self, tag: int, success: bool) -> None:
        """Count a finished episode of start ``tag`` (:data:`TRUE_START` episodes are not counted)."""
        tag = check_tag("ReverseCurriculum", tag)
        if tag == TRUE_START:
            return
        if not 0 <= tag < len(self._states):
            raise ValueError(
                f"ReverseCurriculum.record: unknown start tag {tag}; this curriculum's tags are "
                f"{TRUE_START} (a true start) and 0..{len(self._states) - 1}"
            )
        self.tries[tag] += 1
        self.successes[tag] += bool(success)

    def status(self) -> dict[str, float]:
        """Rebuilds so far, pool sizes, the share of true starts and the mean geodesic distance (m)
        from the active starts to the goal (how far back the curriculum reaches)."""
        xy = np.array([self._xy[i][0] for i in self.active])
        distance = self.maze.geodesic_distance(xy[:, 0], xy[:, 1], to_channel=self.goal)
        return {
            "curriculum_stage": float(self.rebuilds),
            "curriculum_pool": float(len(self.active)),
            "curriculum_good": float(self._good_last),
            "curriculum_mastered": float(len(self.mastered)),
            "curriculum_start_distance": float(np.mean(distance)),
            "true_start_share": self.true_share,
        }

    # ------------------------------------------------------------------ growing the pool
    def _rebuild(self, rng: np.random.Generator) -> None:
        good, newly_mastered = [], []
        for i in self.active:
            rate = self.successes[i] / self.tries[i]
            if rate > self.high:
                newly_mastered.append(i)
            elif rate >= self.low:
                good.append(i)
        self.mastered += newly_mastered
        if len(good) > self.pool_size:
            good = sorted(int(i) for i in rng.choice(good, size=self.pool_size, replace=False))
        sources = good or newly_mastered or self.mastered or self.seeds
        new = [
            self._add(state, xy) for state, xy in self.expand([self._states[i] for i in sources], self.pool_size, rng)
        ]
        if not new:  # every walk reached the goal at once: try the sources again, as new starts
            new = [self._add(self._states[i].copy(), self._xy[i]) for i in sources[: self.pool_size]]
        for i in good:
            self.tries[i] = self.successes[i] = self._issued[i] = 0
        self.active = good + new
        self._good_last = len(good)
        self.rebuilds += 1

    def expand(
        self,
        sources: Sequence[np.ndarray],
        count: int,
        rng: np.random.Generator,
    ) -> list[tuple[np.ndarray, np.ndarray]]:
        """Up to ``count`` new starts ``(state, marble_xy (1, 2))``, drawn uniformly without
        replacement from the states visited by ``count`` random walks of :attr:`walk_steps` steps,
        each from a uniformly chosen state of ``sources``. States at or after the goal — the walk
        has reached it (tracked with the tasks' hysteresis) or the position counts as reached — are
        left out, and so is any state :func:`~bimgame.sim.placement.check_sim_state` refuses."""
        starts = np.asarray(sources, dtype=np.float64)[rng.integers(len(sources), size=count)]
        actions = rng.integers(0, len(DISCRETE_TILTS), size=(count, self.walk_steps))
        visited = self._sim.rollout(starts, DISCRETE_TILTS[actions] * self.maze.tilt_step)
        layout = self._sim.layout
        positions = layout.board_frame(visited)[0][..., 0, :2]  # (count, walk_steps, 2): one marble
        start_xy = layout.board_frame(starts)[0][:, 0, :2]
        channel = self.maze.channel_of(start_xy[:, 0], start_xy[:, 1])
        reached = np.zeros((count, self.walk_steps), dtype=bool)
        for t in range(self.walk_steps):
            channel = self.maze.update_channel(channel, positions[:, t, 0], positions[:, t, 1])
            reached[:, t] = channel <= self.goal
        reached = np.logical_or.accumulate(reached, axis=1)
        reached |= self.maze.channel_of(positions[..., 0], positions[..., 1]) <= self.goal
        chosen: list[tuple[np.ndarray, np.ndarray]] = []
        candidates = np.flatnonzero(~reached.ravel())
        for flat in rng.permutation(candidates):
            walk, step = divmod(int(flat), self.walk_steps)
            try:
                chosen.append(check_sim_state(self.maze, layout, visited[walk, step], "a random-walk state"))
            except ValueError:
                continue
            if len(chosen) == count:
                break
        return chosen

    def close(self) -> None:
        """Release the private simulator's rollout runner."""
        self._sim.close()

    # ------------------------------------------------------------------ pickling (e.g. to a worker process)
    def __getstate__(self) -> dict[str, Any]:
        return {key: value for key, value in self.__dict__.items() if key != "_sim"}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._sim = MazeSim(self.maze, n_marbles=1)
