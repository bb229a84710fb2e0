"""A start curriculum for the labyrinth: training episodes start on the printed path near the goal,
moving back along it as the policy learns.

CyberRunner's reward pays for progress along the path and nothing for time, and a policy that
has not yet reached the goal from the layout's start meets the goal bonus only by chance: PPO from
the start learned to collect the first ≈ 19 cm and lose the marble there (1M steps, 0% success).
Starting near the goal and moving back (Backplay, Resnick et al., 2018; Salimans & Chen, 2018: the
maze's :class:`~bimgame.learn.starts.DemoStartCurriculum`) needs no expert on the labyrinth: the
printed path is itself a demonstration of where the marble goes. It is the labyrinth's ``reverse``
curriculum: grown backwards from the goal without expert data, as the maze's
:class:`~bimgame.learn.starts.ReverseCurriculum` grows its starts by random walks.

Starts are points of the path every ``spacing`` metres, the marble at rest on a level board, kept
where the marble is clear of every wall and the rim, at least a marble radius outside every hole's
rim, outside the goal, and where the progress rule places the marble on the path at that arc
length. Stage ``k`` starts an episode at one of those within ``D_k`` metres (of path) of the goal,
uniformly (:class:`~bimgame.learn.start_stages.BackwardStages`: ``D_0 = first_back``, grown by
``growth`` once ``window`` episodes of the stage succeeded at ``threshold``); a share
``true_share`` of the episodes starts from the layout's own start (tag :data:`TRUE_START`). Evaluations
always use the layout's own start.

:class:`DemoPathStarts` is the labyrinth's ``demo`` curriculum: the same stages in metres of path, its
starts the physics states of the expert's successful episodes (``bimgame generate --task LABYRINTH-…``)
instead of the marble at rest. An expert state carries what a start at rest lacks: the marble's
speed, the board's tilt, the way the expert entered a turn. The path curriculum at rest stalled 34 cm
before the goal, where a marble at rest on a level board is not where any good run passes.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.envs.labyrinth_env import path_points_ahead
from bimgame.envs.puzzles import puzzle
from bimgame.expert.labyrinth_datasets import load_labyrinth_demonstrations
from bimgame.learn.start_stages import TRUE_START, BackwardStages, StagedStarts, check_int, check_real
from bimgame.sim.labyrinth import LabyrinthSpec, PathProgress
from bimgame.sim.labyrinth_physics import LabyrinthSim

__all__ = ["TRUE_START", "PathStartCurriculum", "DemoPathStarts"]

#: How closely the progress rule must place a start at its own arc length (m).
_ARC_TOLERANCE = 1e-3


class _StartsAlongThePath(StagedStarts):
    """Starts that lie ``back_of`` metres of path before the goal, physics states in ``states``, drawn
    uniformly among those within the current stage's distance: what both of the labyrinth's
    curricula do once their starts are chosen."""

    spec: LabyrinthSpec
    states: np.ndarray
    back_of: np.ndarray

    def _schedule(
        self,
        spec: LabyrinthSpec,
        first_back: float | None,
        growth: float,
        threshold: float,
        window: int,
        true_share: float,
    ) -> tuple[float | None, float, float, int]:
        """Check the board and the stage schedule's settings, naming this curriculum; keep the board and
        the share of true starts, and return the rest for :meth:`_begin` (once the starts are known)."""
        owner = type(self).__name__
        if not isinstance(spec, LabyrinthSpec):
            raise TypeError(f"{owner}: spec must be a LabyrinthSpec, got {type(spec).__name__}")
        self.spec = spec
        length = spec.path.length
        self.true_share = check_real(owner, "true_share", true_share, 0.0, 1.0)
        return (
            None if first_back is None else check_real(owner, "first_back", first_back, 0.0, length, open_low=True),
            check_real(owner, "growth", growth, 1.0, 100.0, open_low=True),
            check_real(owner, "threshold", threshold, 0.0, 1.0, open_low=True),
            check_int(owner, "window", window, 1),
        )

    def _begin(self, schedule: tuple[float | None, float, float, int]) -> None:
        """The first stage, its schedule :meth:`_schedule`'s, reaching back to the farthest start."""
        first_back, growth, threshold, window = schedule
        self.stages = BackwardStages(
            type(self).__name__, first_back, growth, float(self.back_of.max()), threshold=threshold, window=window
        )

    def __call__(self, index: int, rng: np.random.Generator) -> tuple[np.ndarray | None, int]:
        """The start of env ``index``'s next episode: ``(sim_state, stage)``, or ``(None, TRUE_START)``."""
        if self.true_start(rng):
            return None, TRUE_START
        within = np.flatnonzero(self.back_of <= self.stages.back)
        if not len(within):  # D_0 shorter than the gap between the goal and the nearest start
            within = np.array([int(np.argmin(self.back_of))])
        return self.states[within[int(rng.integers(len(within)))]].copy(), self.stage

    @property
    def path_fractions(self) -> np.ndarray:
        """How far along the path each start lies (K,), as a fraction of the path's length."""
        return 1.0 - self.back_of / self.spec.path.length

    def status(self) -> dict[str, float]:
        """The stage, how far back (m of path) its starts reach, the share of the layout's own starts
        and the success rate of the current stage's window so far."""
        return {**self.stage_status(), "curriculum_start_distance": float(self.stages.back)}


def _placed_on_path(spec: LabyrinthSpec, xy: np.ndarray, arcs: np.ndarray) -> np.ndarray:
    """Which points ``xy`` (K, 2) the env's progress rule, reset there, places at their arc lengths
    ``arcs`` (K,) of the path: a start it would place elsewhere would pay for path it did not follow."""
    tracker = PathProgress(spec)
    return np.array([abs(tracker.reset(p).progress - a) <= _ARC_TOLERANCE for p, a in zip(xy, arcs, strict=True)])


class PathStartCurriculum(_StartsAlongThePath):
    """Starts along the labyrinth's printed path, moved back from the goal stage by stage (module
    docstring). A :class:`~bimgame.envs.vector.StartSampler` for
    ``LabyrinthVectorEnv(start_sampler=…)``, with ``record`` and ``status`` as the maze's curricula.

    Args:
        spec: the labyrinth's board.
        first_back: ``D_0``, metres of path before the goal (> 0); None: every start from the first episode on.
        growth: ``D_{k+1} / D_k`` (> 1).
        threshold: the stage's success rate over ``window`` episodes that ends it, in (0, 1].
        window: episodes of a stage that rate is taken over.
        true_share: share of episodes from the layout's own start, in [0, 1].
        spacing: metres of path between neighbouring starts (> 0).
    """

    def __init__(
        self,
        spec: LabyrinthSpec,
        *,
        first_back: float | None = 0.10,
        growth: float = 1.5,
        threshold: float = 0.8,
        window: int = 100,
        true_share: float = 0.1,
        spacing: float = 0.005,
    ):
        schedule = self._schedule(spec, first_back, growth, threshold, window, true_share)
        length = spec.path.length
        spacing = check_real(type(self).__name__, "spacing", spacing, 0.0, length, open_low=True)
        self.arcs, xy = self._start_points(spacing)
        self.back_of = length - self.arcs  # metres of path from each start to the goal
        self.states = self._at_rest(xy)
        self._begin(schedule)

    def _start_points(self, spacing: float) -> tuple[np.ndarray, np.ndarray]:
        """Arc lengths (K,) and points (K, 2) of the path where a marble may start (module docstring)."""
        spec, path = self.spec, self.spec.path
        arcs = np.arange(0.0, path.length, spacing)
        xy = path_points_ahead(path, arcs, n=1)[:, 0]
        clear = spec.clearance(xy) >= spec.marble_radius + 1e-9
        holes = np.asarray(spec.holes, dtype=np.float64).reshape(-1, 2)
        hole_distance = np.linalg.norm(xy[:, None] - holes[None], axis=-1).min(axis=1) if len(holes) else np.inf
        outside_holes = hole_distance >= spec.hole_radius + spec.marble_radius
        outside_goal = np.linalg.norm(xy - np.asarray(spec.waypoints[-1]), axis=1) > spec.goal_radius
        keep = clear & outside_holes & outside_goal & _placed_on_path(spec, xy, arcs)
        if not keep.any():
            raise ValueError(f"{type(self).__name__}: no point of the path is clear for a start")
        return arcs[keep], xy[keep]

    def _at_rest(self, xy: np.ndarray) -> np.ndarray:
        """The physics state (``LabyrinthSim.get_state()``) of the marble at rest at each point, the
        board level: what ``reset(options={"sim_state": …})`` restores."""
        sim = LabyrinthSim(self.spec)
        try:
            states = []
            for point in xy:
                sim.reset(point)
                states.append(sim.get_state())
        finally:
            sim.close()
        return np.stack(states)


class DemoPathStarts(_StartsAlongThePath):
    """Starts from the expert's demonstrations on the labyrinth, moved back from the goal stage by stage
    in metres of path (module docstring). A :class:`~bimgame.envs.vector.StartSampler` for
    ``LabyrinthVectorEnv(start_sampler=…)``, with ``record`` and ``status`` as :class:`PathStartCurriculum`.

    Every state before a step of a demonstration that reached the goal is a start, ``back_of`` being
    the path still ahead of it by the recorded progress, except states the env's progress rule,
    reset there, would place at another arc length (a marble in a turn's corner can be in sight of the
    next segment before the expert's own tracker moved on to it).

    Args:
        spec: the labyrinth's board (the demonstrations' layout).
        demonstrations: ``(sim_states (T+1, S), progress (T+1,))`` per successful demonstration:
            ``LabyrinthSim.get_state()`` and the path progress (m) before every step and after the last.
        first_back, growth, threshold, window, true_share: the schedule of :class:`PathStartCurriculum`.
        source: what the demonstrations are, for error messages.
    """

    def __init__(
        self,
        spec: LabyrinthSpec,
        demonstrations: Sequence[tuple[np.ndarray, np.ndarray]],
        *,
        first_back: float | None = 0.10,
        growth: float = 1.5,
        threshold: float = 0.8,
        window: int = 100,
        true_share: float = 0.1,
        source: str = "the given demonstrations",
    ):
        schedule = self._schedule(spec, first_back, growth, threshold, window, true_share)
        self.states, arcs = self._demo_states(demonstrations, source)
        self.back_of = spec.path.length - arcs
        self._begin(schedule)

    def _demo_states(
        self, demonstrations: Sequence[tuple[np.ndarray, np.ndarray]], source: str
    ) -> tuple[np.ndarray, np.ndarray]:
        """The usable states (K, S) of the demonstrations before their last step, and their arc lengths (K,)."""
        sim = LabyrinthSim(self.spec)
        size = sim.state_size
        try:
            states, arcs = [], []
            for k, (sim_states, progress) in enumerate(demonstrations):
                sim_states = np.asarray(sim_states, dtype=np.float64)
                progress = np.asarray(progress, dtype=np.float64)
                if sim_states.ndim != 2 or sim_states.shape[1] != size or progress.shape != (len(sim_states),):
                    raise ValueError(
                        f"{source}: demonstration {k} must give sim_states (T+1, {size}) and progress (T+1,), "
                        f"got shapes {sim_states.shape} and {progress.shape}"
                    )
                if not (np.isfinite(sim_states).all() and np.isfinite(progress).all()):
                    raise ValueError(f"{source}: demonstration {k} has values that are not finite")
                xy = sim.layout.board_frame(sim_states[:-1])[0][..., 0, :2]
                keep = _placed_on_path(self.spec, xy, progress[:-1])
                states.append(sim_states[:-1][keep])
                arcs.append(progress[:-1][keep])
        finally:
            sim.close()
        if not states or not sum(len(a) for a in arcs):
            raise ValueError(
                f"{type(self).__name__}: {source} gives no start (no demonstration that reached the goal); "
                "generate one with bimgame generate --task LABYRINTH-…"
            )
        return np.concatenate(states), np.concatenate(arcs)

    @classmethod
    def from_dataset(cls, path: str | Path, task: str, **settings: Any) -> DemoPathStarts:
        """The curriculum of a labyrinth expert dataset directory of ``task``'s layout (read with
        :func:`~bimgame.expert.labyrinth_datasets.load_labyrinth_demonstrations`, which verifies it).
        ``settings``: the constructor's keywords."""
        data_task, demonstrations = load_labyrinth_demonstrations(path)
        wanted = puzzle(task)
        if data_task != wanted.task:
            raise ValueError(
                f"the dataset in {path} holds {data_task} episodes; demonstration starts for {wanted.task} need "
                f"a dataset of {wanted.task} (bimgame generate --task {wanted.task})"
            )
        spec = wanted.spec
        assert isinstance(spec, LabyrinthSpec)
        return cls(spec, demonstrations, source=f"the dataset in {path}", **settings)
