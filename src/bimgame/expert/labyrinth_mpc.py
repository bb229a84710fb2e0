"""Random-shooting MPC on CyberRunner's labyrinth, with the simulator as its model.

At every step, from the true physics state, the expert samples K sequences of H actions, rolls all
of them out with :meth:`~bimgame.sim.labyrinth_physics.LabyrinthSim.rollout` (``mujoco.rollout``),
scores each and applies the first action of the best (as :mod:`bimgame.expert.mpc` on the circular
maze). The score is the env's reward along the sequence, with failures made expensive:

- path progress (m) times ``progress_scale``, by the env's own no-shortcut rule:
  :meth:`~bimgame.sim.labyrinth.WaypointPath.advance` batched over the K sequences, applied state by
  state along the H states from the env's current segment, so skipping path pays nothing here either;
- minus ``hole_penalty`` if a state of the sequence has the marble's centre within ``hole_radius +
  hole_margin`` of a hole (the episode would end there: progress counts up to that state only), and
  minus ``off_path_penalty`` if it leaves the path; both scaled by ``1 + (steps left) / H`` so that
  among failing sequences a later failure ranks higher (the planner keeps braking while it can);
- plus ``goal_bonus`` (and the same earliness factor) when a state reaches the goal;
- minus ``path_weight`` times the marble's mean distance (m) from its path segment over the H states:
  without it the marble, pinned by the planner's short-sighted greed, got stuck in a dead-end pocket
  beside the hard board's path (between two holes, 21 mm off the line but still within the 25 mm
  tolerance), where every sequence of 0.55 s that gets out first loses progress.

Sampling. ``"hold"``: each sequence is runs of ``hold_min``..``hold_max`` steps of one action — for
continuous actions a tilt-rate vector whose components are drawn from ``rate_levels`` evenly spaced
levels in [-1, 1] (5: -1, -0.5, 0, 0.5, 1), for discrete actions one of the 5 actions; ``"uniform"``:
independent uniform actions every step. With ``keep_best`` the previous decision's best sequence,
shifted by one step, is one of the K candidates (the plan is refined rather than redrawn).
``"mppi"`` (model-predictive path integral control, Williams et al., 2017; continuous actions only):
the expert keeps a mean plan (H, 2), shifted by one step each decision; K sequences are that plan
plus Gaussian noise of ``noise_std`` held in runs of ``hold_min``..``hold_max`` steps (the first
sequence is the plan itself), clipped to [-1, 1], and the new plan is their average weighted by
``exp(score / temperature)``; its first action is applied. A weighted mean of many sequences rather
than one sequence's first action: asked again from the same state and plan, it moves little, so a
learner cloning it is fitted to a smoother, less noisy teacher. Without a remembered plan (an
episode's first decision, a fresh expert) the plan is refined ``cold_iterations`` times from zero.

Several searches (``n_plans`` = P > 1): P independent searches of K sequences each, rolled out in
one call; the action is the mean of their best sequences' first actions (on discrete actions the
most frequent). One search's first action is close to a random pick among the many sequences that
score alike (from one hard-board state, independent K = 16 searches agree within 0.25 on 13% of
pairs, spread 0.46 per component; K = 64: 24%, 0.37): a learner that clones it is fitted to noise.
The mean of P = 4 searches of K = 16, the cost of K = 64, spreads 0.23 and agrees on 43% of pairs.

Model. By default the planner's model is the simulator itself and the expert acts on the true
simulator state; any other model of the :class:`PlanningModel` protocol (``model=``) can take its
place, acting on that model's own state vector: :mod:`bimgame.learn.model_based` plans with a marble
model fitted from the learner's own transitions.

The env's path segment (``info["segment"]``) is passed
along, or the expert follows it itself from consecutive states (:meth:`LabyrinthMPC.reset`).

Measured (benchmarks/bench_expert_labyrinth.py; ``benchmarks/results/expert_labyrinth_sweep.json``:
hard layout, 55 Hz, seed 1, 3 episodes a setting unless said, hold sampling 5–15 steps, 5 levels):

====  ==  ===========  ========  ================  =====================
K     H   path_weight  success   completion (s)    ms/decision (loaded)
====  ==  ===========  ========  ================  =====================
16    30  5            3/3       16.8, 18.1, 18.4  210
32    30  5            3/3       16.3, 16.7, 17.2  450
32    45  5            1/1       20.2              610
32    30  0            0/1       (93% at 3000)     —
====  ==  ===========  ========  ================  =====================

The defaults are the first row (K=32 is ≈ 1.5 s faster at twice the cost; a longer horizon was
slower). The ms per decision were measured on 2 cores at a load average of 9–13. With them the
benchmark (seed 0) solved the hard layout 19/20 (median 17.9 s), medium 10/10 and easy 10/10; the
one failure was the pocket above (stuck at 93% until the time limit); path_weight 20 got that
episode out (20.3 s, one episode: not yet measured over a set).

MPPI (σ = 0.5, λ = 0.005, same seed): hard 10/10 at K = 16, median 22.97 s, and 5/5 at K = 64,
median 19.33 s — slower than "hold", but its
labels are steadier: asked again after planning along the same 10 recorded states, K = 64 labels
spread 0.16 against 0.19 for the mean of 4 "hold" searches of the same cost
(``benchmarks/bench_labyrinth_label_noise.py --warmup 10``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from bimgame.envs.actions import DISCRETE_TILTS
from bimgame.envs.labyrinth_env import LABYRINTH_ACTION_TYPES, LabyrinthEnv
from bimgame.expert.planning_model import PlanningModel
from bimgame.sim.labyrinth import LabyrinthSpec, WaypointPath
from bimgame.sim.labyrinth_physics import LabyrinthSim
from bimgame.sim.labyrinth_tracker import ScalarPathProgress
from bimgame.util.settings import is_integer, is_real

__all__ = ["LabyrinthMPCConfig", "LabyrinthMPC", "LABYRINTH_SAMPLINGS", "run_labyrinth_expert_episode"]

LABYRINTH_SAMPLINGS = ("hold", "uniform", "mppi")
#: Most sequences rolled out per decision (n_samples × n_plans): one ``mujoco.rollout`` call holds
#: them all, (N, H, state) float64 states, ≈ 160 MB at N = 65,536 and H = 30.
MAX_SEQUENCES = 65_536


@dataclasses.dataclass(frozen=True)
class LabyrinthMPCConfig:
    """Settings of the labyrinth's random-shooting expert (defaults from bench_expert_labyrinth.py's sweep)."""

    n_samples: int = 16
    """K: action sequences sampled per decision (16 solved the hard board in the sweep at half the
    cost of 32, which finished ≈ 1.5 s sooner)."""
    n_plans: int = 1
    """P: independent searches of K sequences each per decision, whose first actions are averaged
    (continuous actions; on discrete ones the most frequent, ties to the best-scoring search's).
    One search's first action is nearly a random draw among the many good ones (independent K = 16
    searches from one state agree within 0.25 on 13% of pairs): a learner cloning it regresses
    to their mean through noise. The mean of P searches is a P-times less noisy label, at P times
    the planning cost; each search refines its own plan (``keep_best``)."""
    horizon: int = 30
    """H: actions per sequence (30 at 55 Hz: 0.55 s, enough to stop the marble from a walking pace)."""
    sampling: str = "hold"
    """"hold" (runs of one action, hold_min..hold_max steps), "uniform" (independent actions) or
    "mppi" (a remembered mean plan refined by score-weighted averaging; continuous actions only)."""
    hold_min: int = 5
    """"hold": shortest run of one action (steps)."""
    hold_max: int = 15
    """"hold": longest run of one action (steps)."""
    rate_levels: int = 5
    """"hold", continuous actions: levels of each tilt-rate component, evenly spaced in [-1, 1] (odd: 0 is one)."""
    keep_best: bool = True
    """Whether the last decision's best sequence, shifted by one step, is one of the K candidates
    ("hold", "uniform"; "mppi" always keeps its plan)."""
    noise_std: float = 0.5
    """"mppi": standard deviation of the perturbations of the plan (tilt-rate fractions)."""
    temperature: float = 0.005
    """"mppi": λ (reward units) of the weights exp(score / λ): small follows the best sequences only,
    large averages all (a sequence's progress over H = 30 steps is worth ≈ 0.05–0.15). On the hard
    board λ = 0.02 stalled in all three episodes tried (K = 32 and 64), twice at 36% of the path and
    once at 93%, until the time limit (the average of sequences that pass a hole on either side is
    one that passes on neither); λ = 0.005 solved both it tried at K = 32 and 10/10 at K = 16."""
    cold_iterations: int = 3
    """"mppi": refinements of the plan from zero when there is none to remember."""
    hole_penalty: float = 10.0
    """Score (reward units) taken from a sequence that puts the marble over a hole."""
    hole_margin: float = 0.0
    """Extra distance (m) around each hole that the planner treats as the hole."""
    off_path_penalty: float = 10.0
    """Score taken from a sequence that leaves the path (the env ends such an episode too)."""
    path_weight: float = 5.0
    """Score taken per metre of the marble's mean distance from its path segment over the horizon:
    keeps it near the printed line, away from holes and out of dead-end pockets beside the path."""
    nthread: int = 1
    """MuJoCo rollout threads (1 inside worker processes or on a shared machine)."""

    def __post_init__(self) -> None:
        for name in (
            "n_samples",
            "n_plans",
            "horizon",
            "hold_min",
            "hold_max",
            "rate_levels",
            "nthread",
            "cold_iterations",
        ):
            value = getattr(self, name)
            if not (is_integer(value) and value >= 1):
                raise ValueError(f"LabyrinthMPCConfig.{name} must be a positive integer, got {value!r}")
        if self.rate_levels < 2:
            raise ValueError(f"LabyrinthMPCConfig.rate_levels must be an integer >= 2, got {self.rate_levels!r}")
        if self.hold_max < self.hold_min:
            raise ValueError(
                f"LabyrinthMPCConfig.hold_max ({self.hold_max}) must be an integer >= hold_min ({self.hold_min})"
            )
        if self.n_samples * self.n_plans > MAX_SEQUENCES:
            raise ValueError(
                f"LabyrinthMPCConfig: n_samples × n_plans must be at most {MAX_SEQUENCES:,} sequences a decision, "
                f"got {self.n_samples} × {self.n_plans}"
            )
        if self.sampling not in LABYRINTH_SAMPLINGS:
            raise ValueError(
                f"unknown LabyrinthMPCConfig.sampling {self.sampling!r}; allowed: {', '.join(LABYRINTH_SAMPLINGS)}"
            )
        if not isinstance(self.keep_best, (bool, np.bool_)):
            raise ValueError(f"LabyrinthMPCConfig.keep_best must be True or False, got {self.keep_best!r}")
        for name in ("hole_penalty", "hole_margin", "off_path_penalty", "path_weight"):
            value = getattr(self, name)
            if not (is_real(value) and math.isfinite(value) and value >= 0):
                raise ValueError(f"LabyrinthMPCConfig.{name} must be a finite number >= 0, got {value!r}")
        for name in ("noise_std", "temperature"):
            value = getattr(self, name)
            if not (is_real(value) and math.isfinite(value) and value > 0):
                raise ValueError(f"LabyrinthMPCConfig.{name} must be a finite number > 0, got {value!r}")

    @property
    def sim_steps_per_decision(self) -> int:
        """Simulator steps one decision rolls out: K · P sequences of H steps."""
        return self.n_samples * self.n_plans * self.horizon


class LabyrinthMPC:
    """The labyrinth's MPC expert: ``act(state)`` is an action of the env's action space for a
    physics state from :meth:`LabyrinthSim.get_state`; every random draw comes from ``rng``.

    Build it with :meth:`for_env` to match an env (board, rate, action type, reward constants).

    Args:
        board: the labyrinth it plans in.
        config: K, H, sampling and penalties.
        rng: the seeded generator of the sampled sequences.
        action_type: "continuous" (tilt-rate fractions in [-1, 1]²) or "discrete" (0..4).
        control_hz: action rate (Hz) of the env it controls.
        max_tilt_rate_deg: the env's full tilt rate (°/s): one full action changes the tilt by it / control_hz.
        progress_scale, goal_bonus: the env's reward per metre of progress and for the goal.
        model: what the sequences are rolled out in (None: a :class:`LabyrinthSim` of ``board`` at
            ``control_hz``, the expert); states passed to :meth:`act` are this model's.
    """

    def __init__(
        self,
        board: LabyrinthSpec,
        config: LabyrinthMPCConfig | None = None,
        *,
        rng: np.random.Generator,
        action_type: str = "continuous",
        control_hz: float = 55,
        max_tilt_rate_deg: float = 30.0,
        progress_scale: float = 1.25,
        goal_bonus: float = 0.5,
        model: PlanningModel | None = None,
    ):
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy Generator (np.random.default_rng(seed)), got {type(rng).__name__}")
        if action_type not in LABYRINTH_ACTION_TYPES:
            raise ValueError(f"unknown action_type {action_type!r}; allowed: {', '.join(LABYRINTH_ACTION_TYPES)}")
        self.config = config if config is not None else LabyrinthMPCConfig()
        if not isinstance(self.config, LabyrinthMPCConfig):
            raise TypeError(f"config must be a LabyrinthMPCConfig, got {type(self.config).__name__}")
        if self.config.sampling == "mppi" and action_type == "discrete":
            raise ValueError(
                "LabyrinthMPCConfig.sampling 'mppi' averages sequences and needs continuous actions; "
                f"with discrete actions use one of: {', '.join(s for s in LABYRINTH_SAMPLINGS if s != 'mppi')}"
            )
        self.board, self.rng, self.action_type = board, rng, action_type
        if model is not None and not isinstance(model, PlanningModel):
            raise TypeError(
                "model must have state_size, rollout, marble_xy_of and close (PlanningModel), "
                f"got {type(model).__name__}"
            )
        #: The planner's model (the name predates models other than the simulator).
        self.sim: PlanningModel = model if model is not None else LabyrinthSim(board, control_hz=control_hz)
        self.path = board.path
        self.tilt_step = math.radians(max_tilt_rate_deg) / control_hz
        self.progress_scale, self.goal_bonus = float(progress_scale), float(goal_bonus)
        self.levels = np.linspace(-1.0, 1.0, self.config.rate_levels)
        self._holes = np.asarray(board.holes, dtype=np.float64).reshape(-1, 2)
        self._tracker = ScalarPathProgress(board)
        self._tracking = False
        self._best: np.ndarray | None = None
        self._mean: np.ndarray | None = None  # "mppi": each search's remembered plan, (P, H, 2)

    @classmethod
    def for_env(cls, env: Any, config: LabyrinthMPCConfig | None = None, *, rng: np.random.Generator) -> LabyrinthMPC:
        """An expert matching ``env`` (a :class:`LabyrinthEnv`, possibly wrapped)."""
        inner = env.unwrapped
        if not isinstance(inner, LabyrinthEnv):
            raise TypeError(f"env must be a LabyrinthEnv (possibly wrapped), got {type(inner).__name__}")
        return cls(
            inner.board,
            config,
            rng=rng,
            action_type=inner.action_type,
            control_hz=inner.control_hz,
            max_tilt_rate_deg=math.degrees(inner.max_tilt_rate),
            progress_scale=inner.progress_scale,
            goal_bonus=inner.goal_bonus,
        )

    # ------------------------------------------------------------------ sampling
    def sample_sequences(self) -> np.ndarray:
        """(K·P, H, 2) continuous rate fractions or (K·P, H) discrete actions, per the sampling
        scheme ("mppi": the perturbations of the plan, not yet added to it): search p's K sequences
        are rows p·K .. p·K + K - 1."""
        c = self.config
        k, h = c.n_samples * c.n_plans, c.horizon
        if c.sampling == "uniform":
            if self.action_type == "discrete":
                return self.rng.integers(5, size=(k, h))
            return self.rng.uniform(-1.0, 1.0, size=(k, h, 2))
        n_runs = -(-h // c.hold_min)
        lengths = self.rng.integers(c.hold_min, c.hold_max + 1, size=(k, n_runs))
        run = np.minimum((np.cumsum(lengths, axis=1)[:, :, None] <= np.arange(h)).sum(axis=1), n_runs - 1)
        if self.action_type == "discrete":
            return np.take_along_axis(self.rng.integers(5, size=(k, n_runs)), run, axis=1)
        if c.sampling == "mppi":  # Gaussian perturbations held in runs, as "hold" holds its levels
            values = self.rng.normal(0.0, c.noise_std, size=(k, n_runs, 2))
        else:
            values = self.levels[self.rng.integers(len(self.levels), size=(k, n_runs, 2))]
        return np.take_along_axis(values, run[:, :, None], axis=1)

    def tilt_deltas(self, sequences: np.ndarray) -> np.ndarray:
        """(K, H, 2) tilt changes (rad) of sampled sequences, as the env turns its actions into sim steps."""
        if self.action_type == "discrete":
            return DISCRETE_TILTS[sequences] * self.tilt_step
        return sequences * self.tilt_step

    # ------------------------------------------------------------------ scoring
    def score(self, states: np.ndarray, segment: int, progress: float) -> np.ndarray:
        """Score (reward units) of each of K rolled-out sequences, (K, H, state_size), starting from
        path ``segment`` and ``progress`` (m): see the module docstring."""
        c = self.config
        k, h = states.shape[:2]
        xy = self.sim.marble_xy_of(states)  # (K, H, 2)
        radius = self.board.hole_radius + c.hole_margin
        if len(self._holes):
            d2 = ((xy[:, :, None, :] - self._holes) ** 2).sum(axis=-1)
            hole = np.any(d2 <= radius**2, axis=-1)
        else:
            hole = np.zeros((k, h), dtype=bool)
        goal_close = self.board.reached_goal(xy)
        last = self.path.n_segments - 1
        path = self._local_path(xy)
        seg = np.full(k, segment, dtype=np.intp)
        prog = np.full(k, progress, dtype=np.float64)
        alive = np.ones(k, dtype=bool)
        score = np.zeros(k)
        segments = np.empty((k, h), dtype=np.intp)  # the segment of each state (frozen after an end)
        for t in range(h):
            new_seg, new_prog, off = path.advance(xy[:, t], seg, prog)
            earliness = 1.0 + (h - t) / h
            fell, left = alive & hole[:, t], alive & ~hole[:, t] & off
            score -= earliness * (c.hole_penalty * fell + c.off_path_penalty * left)
            moving = alive & ~fell & ~left
            seg, prog = np.where(moving, new_seg, seg), np.where(moving, new_prog, prog)
            reached = moving & (seg == last) & goal_close[:, t]
            score += earliness * self.goal_bonus * reached
            alive = moving & ~reached
            segments[:, t] = seg
        if c.path_weight:
            # States after a sequence's end count at its last segment (a constant of that sequence's
            # fate, already scored): the mean then weighs every sequence over the same H states.
            _, distance = path.project(xy, segments)
            score -= c.path_weight * distance.mean(axis=1)
        return score + self.progress_scale * (prog - progress)

    def _local_path(self, xy: np.ndarray) -> WaypointPath:
        """The board's path with only the walls that can block a line of sight from these positions:
        those meeting the positions' bounding box grown by the path tolerance. Exact: a segment in
        sight has its foot point within the tolerance of the marble, so the line of sight lies in that
        box, and a wall outside it cannot cross it. It makes the scoring ≈ 3× cheaper on the hard board."""
        grow = self.path.tolerance
        lo, hi = xy.reshape(-1, 2).min(axis=0) - grow, xy.reshape(-1, 2).max(axis=0) + grow
        walls = self.path.walls
        near = (walls[:, 2] >= lo[0]) & (walls[:, 0] <= hi[0]) & (walls[:, 3] >= lo[1]) & (walls[:, 1] <= hi[1])
        local = WaypointPath.__new__(WaypointPath)
        local.__dict__.update(self.path.__dict__)
        local.walls = walls[near]
        return local

    # ------------------------------------------------------------------ acting
    def reset(self) -> None:
        """Forget the last plan and the followed segment (a new episode)."""
        self._tracking, self._best, self._mean = False, None, None

    def _segment_of(self, state: np.ndarray, segment: int | None) -> tuple[int, float]:
        """The path segment and progress (m) of ``state``'s marble: on ``segment`` if given, else the
        expert's own tracker following consecutive states (the nearest segment in sight at first)."""
        x, y = (float(v) for v in self.sim.marble_xy_of(state))
        if segment is not None:
            if not (is_integer(segment) and 0 <= segment < self.path.n_segments):
                raise ValueError(f"segment must be an integer in 0..{self.path.n_segments - 1}, got {segment!r}")
            arc, _ = self.path.project(np.array([x, y]), np.array(segment))
            self._tracker.segment, self._tracker.progress = int(segment), float(arc)
            self._tracking = True
        elif self._tracking:
            self._tracker.update((x, y))
        else:
            self._tracker.reset((x, y))
            self._tracking = True
        return self._tracker.segment, self._tracker.progress

    def plan(self, state: np.ndarray, segment: int | None = None) -> tuple[Any, dict[str, Any]]:
        """Best first action from physics ``state`` (on path ``segment``; None: followed by the
        expert), the mean (or most frequent) over the P searches, and what the planner saw:
        ``scores`` (K·P,), the best-scoring ``sequence`` and each search's ``first_actions``."""
        state = np.asarray(state, dtype=np.float64)
        if state.shape != (self.sim.state_size,):
            raise ValueError(
                f"state must have shape ({self.sim.state_size},) (the model's state: LabyrinthSim.get_state for the "
                f"simulator), got {state.shape}"
            )
        seg, progress = self._segment_of(state, segment)
        if self.config.sampling == "mppi":
            return self._plan_mppi(state, seg, progress)
        k, n_plans = self.config.n_samples, self.config.n_plans
        sequences = self.sample_sequences()
        if self.config.keep_best and self._best is not None:
            sequences[::k] = _shifted(self._best)
        states = self.sim.rollout(state, self.tilt_deltas(sequences), nthread=self.config.nthread)
        scores = self.score(states, seg, progress)
        bests = np.arange(n_plans) * k + scores.reshape(n_plans, k).argmax(axis=1)
        self._best = sequences[bests]  # an index array: a copy, not a view of this decision's samples
        firsts = sequences[bests, 0]
        action = self._combine(firsts, scores[bests])
        return action, {
            "scores": scores,
            "sequence": sequences[int(np.argmax(scores))],  # the best of all is the best of its search
            "first_actions": firsts,
            "segment": seg,
            "progress": progress,
        }

    def _plan_mppi(self, state: np.ndarray, seg: int, progress: float) -> tuple[Any, dict[str, Any]]:
        """:meth:`plan` for "mppi" sampling: each search's remembered plan (or zeros, refined
        ``cold_iterations`` times) perturbed, scored and averaged with weights exp(score / λ)."""
        c = self.config
        k, p, h = c.n_samples, c.n_plans, c.horizon
        means: np.ndarray = np.zeros((p, h, 2)) if self._mean is None else self._mean
        for _ in range(c.cold_iterations if self._mean is None else 1):
            noise = self.sample_sequences().reshape(p, k, h, 2)
            noise[:, 0] = 0.0  # each search's plan itself is a candidate
            sequences = np.clip(means[:, None] + noise, -1.0, 1.0).reshape(p * k, h, 2)
            states = self.sim.rollout(state, self.tilt_deltas(sequences), nthread=c.nthread)
            scores = self.score(states, seg, progress)
            by_search = scores.reshape(p, k)
            weights = np.exp((by_search - by_search.max(axis=1, keepdims=True)) / c.temperature)
            weights /= weights.sum(axis=1, keepdims=True)
            means = np.einsum("pk,pkhd->phd", weights, sequences.reshape(p, k, h, 2))
        self._mean = _shifted(means)
        firsts = means[:, 0]
        return self._combine(firsts, by_search.max(axis=1)), {
            "scores": scores,
            "sequence": means[int(np.argmax(by_search.max(axis=1)))],
            "first_actions": firsts,
            "segment": seg,
            "progress": progress,
        }

    def _combine(self, firsts: np.ndarray, plan_scores: np.ndarray) -> Any:
        """One action of the P searches' first actions: their mean (continuous) or the most frequent
        (discrete; among equally frequent ones, that of the best-scoring search)."""
        if self.action_type != "discrete":
            return np.asarray(firsts.mean(axis=0), dtype=np.float32)
        counts = np.bincount(firsts, minlength=len(DISCRETE_TILTS))
        tied = counts[firsts] == counts.max()
        return int(firsts[np.flatnonzero(tied)[np.argmax(plan_scores[tied])]])

    def act(self, state: np.ndarray, segment: int | None = None) -> Any:
        """The expert's action for a physics state (see :meth:`plan`)."""
        return self.plan(state, segment)[0]

    def close(self) -> None:
        self.sim.close()


def _shifted(plans: np.ndarray) -> np.ndarray:
    """(P, H, …) plans one step on: each without its applied first step, its last step held."""
    return np.concatenate([plans[:, 1:], plans[:, -1:]], axis=1)


def run_labyrinth_expert_episode(
    env: Any, expert: LabyrinthMPC, *, seed: int | None = None, max_steps: int | None = None
) -> dict[str, Any]:
    """One episode of ``expert`` on ``env`` (a :class:`LabyrinthEnv`, possibly wrapped) from
    ``env.reset(seed=seed)``, stopped after ``max_steps`` (None: when the env truncates, or
    CyberRunner's 3000 steps at 55 Hz without a TimeLimit).

    Returns ``success`` (goal reached), ``failure`` ("hole", "off_path", "time" or None), ``steps``,
    ``time_s`` (steps / control rate: the completion time when successful), ``progress`` (m along
    the path), ``progress_fraction`` and ``return`` (summed env reward)."""
    inner = env.unwrapped
    if max_steps is None:
        max_steps = env.spec.max_episode_steps if getattr(env, "spec", None) and env.spec.max_episode_steps else 3000
    _, info = env.reset(seed=seed)
    expert.reset()
    total, steps, terminated, truncated = 0.0, 0, False, False
    while steps < max_steps and not (terminated or truncated):
        action = expert.act(inner.sim.get_state(), info["segment"])
        _, reward, terminated, truncated, info = env.step(action)
        total += reward
        steps += 1
    success = bool(info["is_success"])
    failure = None
    if not success:
        failure = "hole" if info["over_hole"] else "off_path" if info["off_path"] else "time"
    return {
        "success": success,
        "failure": failure,
        "steps": steps,
        "time_s": steps / inner.control_hz,
        "progress": float(info["progress"]),
        "progress_fraction": float(info["progress_fraction"]),
        "return": total,
    }
