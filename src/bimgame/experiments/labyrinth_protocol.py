"""The labyrinth's scoring protocol: one fixed way to score a policy on CyberRunner's labyrinth and
compare it with CyberRunner's and the human record (what ``bimgame score --task LABYRINTH-…`` runs).

**References.** Bi & D'Andrea, "Sample-Efficient Learning to Solve a Real-World Labyrinth Game Using
Data-Augmented Model-Based Reinforcement Learning" (ETH Zurich, 2023; arXiv 2312.09906): CyberRunner
completed the hard layout of the real BRIO labyrinth in 14.48 s (:data:`CYBERRUNNER_RECORD_S`), its
best time, against 15.41 s (:data:`HUMAN_RECORD_S`), the fastest time recorded by a human player.
Both are best times on the hard layout: they are compared with a policy's fastest and median
completion times on ``LABYRINTH-HARD`` only (the other layouts have no published times).

**Protocol.** ``episodes`` episodes (:data:`LABYRINTH_PROTOCOL_EPISODES` by default) of the task's
layout, episode i from ``reset(seed=seed + i)`` (``seed``: :data:`LABYRINTH_PROTOCOL_SEED` by default):
the layout's own start plus the env's start noise (±2 mm) drawn from that seed, so every policy gets
the same starts. ``seed + i`` because that is how :func:`~bimgame.learn.actor.evaluate_network` seeds
board i of its batched env, which reproduces the single env exactly
(:class:`~bimgame.envs.labyrinth_vector.LabyrinthVectorEnv`): a network (batched) and a built-in
policy (one env) play the same starts. Each episode runs under the task's time limit,
CyberRunner's 54.5 s (3000 steps at 55 Hz, ``puzzle(task).time_limit``), with the env's default
settings (CyberRunner's reward, 30°/s tilt rate, an episode ends in a hole or off the path by the
``tolerance`` rule), or with ``off_path_rule="cyberrunner"`` CyberRunner's own off-path test
(``bimgame score --off-path-rule``; the summary names the rule: scores compare at the same rule).

**Policies.** ``random``: uniform continuous tilt-rate actions in [-1, 1]², from a generator seeded
per episode; ``noop``: zero actions (the board stays flat); ``expert``: the MPC expert
(:class:`~bimgame.expert.labyrinth_mpc.LabyrinthMPC`, default settings) on the simulator's state, its
generator seeded per episode; a marble law (``.json``) of the model-based learner
(:mod:`bimgame.learn.model_based`): the same MPC planning through it on the env's state observation,
its generator seeded per episode as the expert's; a bimgame run directory or checkpoint of a network
trained on the same task: :func:`~bimgame.learn.actor.evaluate_network` plays it on its own
observations and actions, greedy by default, sampling with ``sampled`` (from a generator seeded with ``seed``), on
:data:`SCORE_THREADS` torch threads. Episode i depends on (seed, i) alone. Stable-Baselines3 models
and ``module:callable`` policies are refused for now.

**Reported** (:func:`summarise_labyrinth`): success rate and mean return, each with a 95%
percentile-bootstrap interval over episodes (:func:`~bimgame.experiments.statistics.mean_interval`,
seeded, so the same episodes give the same interval; it collapses to a point at 0% and 100%); the
completion time (s; steps / 55 Hz) of the successful episodes: fastest, quartiles and median, and
on the hard layout their ratios to the references; how episodes ended (:data:`ENDINGS`: goal; hole
or off_path, by the env's ``over_hole`` at the last step; time: ran to the limit — a fall on the very
last step counts as time), in all (``ended_by``, whose ``fall`` is hole + off_path) and per episode
(``ended``); and the path progress reached, per episode and its mean, as a fraction of the
path's length (:func:`~bimgame.experiments.labyrinth_figures.plot_episode_ends` draws where on the
board the episodes ended).

**Progress reached** is the marble's progress along the path (``info["progress"]``) after the last
step that did not fail: at the goal, at the time limit, or just before the step that fell into a hole
or left the path (where the env pays ``fail_reward`` = 0 instead of that step's progress). It is
computed from the episode's return, which :func:`evaluate_network` gives and the info it does not:
every other step pays ``progress_scale`` × its progress and the goal adds ``goal_bonus``, so
progress reached = start progress + (return − goal bonus if solved) / ``progress_scale``, exactly.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.envs.labyrinth_env import LABYRINTH_OFF_PATH_RULES, LabyrinthEnv
from bimgame.envs.puzzles import LABYRINTH_TASKS, puzzle
from bimgame.experiments.protocol import PROTOCOL_SEED
from bimgame.experiments.statistics import mean_interval
from bimgame.expert.labyrinth_mpc import LabyrinthMPC
from bimgame.learn.actor import EvalResult, evaluate_network
from bimgame.learn.common import MAX_SEED, load_run_network
from bimgame.learn.maze_runs import network_env_options
from bimgame.learn.model_based.agent import ModelBasedAgent
from bimgame.learn.model_based.marble_law import MarbleLaw
from bimgame.learn.runs import torch_threads
from bimgame.util.progress import ProgressBar
from bimgame.util.settings import require_int

__all__ = [
    "CYBERRUNNER_RECORD_S",
    "ENDINGS",
    "SCORE_THREADS",
    "HUMAN_RECORD_S",
    "LABYRINTH_POLICIES",
    "LABYRINTH_PROTOCOL_EPISODES",
    "LABYRINTH_PROTOCOL_SEED",
    "protocol_starts",
    "score_labyrinth",
    "summarise_labyrinth",
    "start_progress",
]

#: CyberRunner's best time on the hard layout of the real labyrinth (s; Bi & D'Andrea 2023).
CYBERRUNNER_RECORD_S = 14.48
#: The fastest time a human player had recorded on the hard layout, which CyberRunner beat (s; same paper).
HUMAN_RECORD_S = 15.41
#: The layout the references were set on.
REFERENCE_TASK = "LABYRINTH-HARD"
#: How a scored episode can end: at the goal, over a hole, off the path (by the protocol's off-path
#: rule, ``tolerance`` by default: no path segment within the path tolerance in sight), or at the time
#: limit. Summaries written before
#: the hole and the path were told apart name both ``fall``, which ``ended_by["fall"]`` still counts
#: (their sum).
ENDINGS = ("goal", "hole", "off_path", "time")
#: The built-in policies the labyrinth's protocol plays.
LABYRINTH_POLICIES = ("random", "noop", "expert")
#: Episodes of the protocol (scores are comparable at the same number): enough for a success rate to
#: ±14% (95%) at worst, while the MPC expert, at ≈ 70 ms a decision on a loaded 2-core machine, takes
#: about half an hour on the easy layout and one to two hours on the hard one.
LABYRINTH_PROTOCOL_EPISODES = 50
#: The seed the starts derive from (the benchmark protocol's, :data:`~bimgame.experiments.protocol.PROTOCOL_SEED`).
LABYRINTH_PROTOCOL_SEED = PROTOCOL_SEED
#: Torch threads a network is scored on, whatever the machine or caller: the batched forward pass's
#: float sums depend on how many threads split them, and on a chaotic marble a last-bit difference
#: changes episodes (100 boards sampled at one thread and at two differed in 17 of them within 150
#: steps), so a fixed count makes the same seed give the same score on every machine.
SCORE_THREADS = 1
#: Seed of the bootstrap's generator (the same episodes always get the same intervals).
_BOOTSTRAP_SEED = 0
#: Second word of the built-in policies' generator seeds, so their draws differ from the env's start
#: noise, which the same episode seed draws.
_POLICY_STREAM = 1

#: An episode's actor: the action for the step's info (the env is the one it plays).
Act = Callable[[dict[str, Any]], Any]


def _labyrinth_task(task: str) -> str:
    """The canonical name of a labyrinth task; ``ValueError`` naming the allowed ones otherwise."""
    found = puzzle(task)
    if found.is_maze:
        raise ValueError(
            f"task {found.task} is the circular maze's; the labyrinth's protocol takes {', '.join(LABYRINTH_TASKS)}"
        )
    return found.task


def _builtin_actor(
    name: str, env: LabyrinthEnv, seed: int, law: MarbleLaw | None = None
) -> tuple[Act, Callable[[], None]]:
    """Built-in policy ``name`` (or, with ``law``, the model-based learner's planner through it) for
    the episode from start seed ``seed``: (act, close)."""
    rng = np.random.default_rng([seed, _POLICY_STREAM])
    if law is not None:
        agent = ModelBasedAgent.for_env(env, law, rng=rng)
        return (lambda info: agent.act(env.state_observation(), int(info["segment"]))), lambda: None
    if name == "random":
        return (lambda info: rng.uniform(-1.0, 1.0, 2).astype(np.float32)), lambda: None
    if name == "noop":
        return (lambda info: np.zeros(2, dtype=np.float32)), lambda: None
    expert = LabyrinthMPC.for_env(env, rng=rng)
    return (lambda info: expert.act(env.sim.get_state(), int(info["segment"]))), expert.close


def _play_builtins(
    name: str,
    layout: str,
    starts: list[int],
    time_limit: int,
    progress: bool,
    off_path_rule: str,
    law: MarbleLaw | None = None,
) -> EvalResult:
    """Built-in policy ``name`` (with ``law``: the model-based planner, named ``name``) on one env of
    ``layout`` (ending episodes off the path by ``off_path_rule``), one episode per start seed, in order."""
    env = LabyrinthEnv(layout, off_path_rule=off_path_rule)
    result = EvalResult([], [], [])
    try:
        with ProgressBar(f"{name} on the {layout} labyrinth", len(starts), enabled=progress, transient=True) as bar:
            for seed in starts:
                _, info = env.reset(seed=seed)
                act, close = _builtin_actor(name, env, seed, law)
                total, length, success = 0.0, time_limit, False
                try:
                    for step in range(1, time_limit + 1):
                        _, reward, terminated, _, info = env.step(act(info))
                        total += float(reward)
                        if terminated:
                            length, success = step, bool(info["is_success"])
                            break
                finally:
                    close()
                result.successes.append(success)
                result.lengths.append(length)
                result.returns.append(total)
                result.holes.append(bool(info["over_hole"]))
                bar.update(advance=1, info=f"success {np.mean(result.successes):.0%}")
    finally:
        env.close()
    return result


def _network_source(policy: str, task: str) -> Path:
    """``policy`` as a run directory or checkpoint the protocol plays; ``ValueError`` naming what the
    labyrinth's protocol takes otherwise."""
    allowed = (
        f"{', '.join(LABYRINTH_POLICIES)}, a bimgame run directory or checkpoint trained on {task}, "
        "or a marble law (.json) of the model-based learner"
    )
    path = Path(policy)
    if path.exists() and path.suffix != ".zip":
        return path
    if path.suffix == ".zip":
        why = "Stable-Baselines3 models are scored on the circular maze only (for now)"
    elif ":" in policy and not policy.startswith(("/", ".")):
        why = "module:callable policies are scored on the circular maze only (for now)"
    elif policy == "geodesic":
        why = "the geodesic controller follows the circular maze's channels"
    else:
        why = "no such built-in policy, file or directory"
    raise ValueError(f"POLICY {policy!r} on {task}: {why}; allowed: {allowed}")


def _play_network(
    source: Path,
    task: str,
    *,
    obs: str | None,
    sampled: bool,
    episodes: int,
    seed: int,
    progress: bool,
    off_path_rule: str,
) -> tuple[EvalResult, dict[str, Any]]:
    """The run's network on ``episodes`` boards batched (:func:`evaluate_network`, ending episodes off
    the path by ``off_path_rule``), and what the summary says of it (its observations, actions, mode,
    checkpoint step)."""
    net, run, step = load_run_network(source)
    if run.task != task:
        raise ValueError(
            f"{source} is a run trained on {run.task}, not {task}: its network is scored on its own task; "
            f"score it with --task {run.task}"
        )
    if obs is not None and obs != run.network.obs:
        raise ValueError(
            f"{source}: the network was trained on {run.network.obs} observations, not {obs}; "
            f"score it with --obs {run.network.obs} (or without --obs)"
        )
    with (
        ProgressBar(
            f"{source} on {task}", 1, enabled=progress, count=None, transient=True, info=f"{episodes} boards batched"
        ) as bar,
        torch_threads(SCORE_THREADS),
    ):
        result = evaluate_network(
            net.eval(),
            task=task,
            obs_mode=run.network.obs,
            episodes=episodes,
            seed=seed,
            greedy=not sampled,
            max_episode_steps=puzzle(task).time_limit,
            mazes=network_env_options(run.network, rules={"off_path_rule": off_path_rule}),
        )
        bar.update(advance=1)
    facts = {"obs": run.network.obs, "action_type": run.network.action_type, "step": step}
    return result, facts


def protocol_starts(episodes: int, seed: int = LABYRINTH_PROTOCOL_SEED) -> list[int]:
    """The reset seeds of the protocol's ``episodes`` episodes: ``seed + i``, as
    :func:`~bimgame.learn.actor.evaluate_network` seeds its envs (module notes)."""
    return [seed + i for i in range(episodes)]


def start_progress(task: str, starts: list[int]) -> list[float]:
    """The marble's progress (m along the path) at the start of each episode, ``reset(seed=s)`` for
    each start seed ``s``: what :func:`summarise_labyrinth` counts progress reached from."""
    env = _protocol_env(task)
    try:
        return _start_progress(env, starts)
    finally:
        env.close()


def _protocol_env(task: str) -> LabyrinthEnv:
    """The protocol's env of labyrinth ``task`` (its layout, default settings)."""
    layout = puzzle(_labyrinth_task(task)).layout
    assert layout is not None  # a labyrinth task has its layout
    return LabyrinthEnv(layout)


def _start_progress(env: LabyrinthEnv, starts: list[int]) -> list[float]:
    return [float(env.reset(seed=s)[1]["progress"]) for s in starts]


def _quantile(values: np.ndarray, q: float) -> float | None:
    return float(np.percentile(values, q)) if len(values) else None


def _ratio(value: float | None, reference: float, task: str) -> float | None:
    return None if value is None or task != REFERENCE_TASK else value / reference


def _endings(solved: np.ndarray, timed_out: np.ndarray, holes: list[bool]) -> list[str]:
    """How each episode ended (:data:`ENDINGS`): a fall is ``hole`` or ``off_path`` by the env's
    ``over_hole`` at the episode's last step, ``fall`` where the result holds none."""
    known = len(holes) == len(solved)
    falls = [("hole" if hole else "off_path") for hole in holes] if known else ["fall"] * len(solved)
    return [
        "goal" if goal else "time" if late else fall for goal, late, fall in zip(solved, timed_out, falls, strict=True)
    ]


def summarise_labyrinth(result: EvalResult, task: str, starts: list[int], *, time_limit: int) -> dict[str, Any]:
    """The protocol's numbers for the episodes of ``result`` (from start seeds ``starts``, on ``task``):
    see the module notes. Deterministic: the same episodes give the same dict."""
    task = _labyrinth_task(task)
    layout = puzzle(task).layout
    assert layout is not None  # a labyrinth task has its layout
    env = _protocol_env(task)  # its reward constants, path, rate and the episodes' start progress
    try:
        scale, bonus, length, hz = env.progress_scale, env.goal_bonus, env.path.length, env.control_hz
        start = np.asarray(_start_progress(env, starts))
    finally:
        env.close()
    successes = np.asarray(result.successes, dtype=np.float64)
    returns = np.asarray(result.returns, dtype=np.float64)
    lengths = np.asarray(result.lengths, dtype=np.int64)
    solved = successes.astype(bool)
    # The path's arc length reached, in [0, 1] by construction: the clip drops float rounding of the
    # summed rewards (an episode that ends where it started gave -1.6e-19).
    reached = np.clip((start + (returns - bonus * successes) / scale) / length, 0.0, 1.0)
    times = lengths[solved] / hz
    rng = np.random.default_rng(_BOOTSTRAP_SEED)
    best, median = (float(times.min()) if len(times) else None), _quantile(times, 50)
    timed_out = ~solved & (lengths >= time_limit)
    ended = _endings(solved, timed_out, result.holes)
    return {
        "task": task,
        "layout": layout,
        "episodes": len(successes),
        "time_limit_steps": time_limit,
        "control_hz": hz,
        "success_rate": float(successes.mean()),
        "success_rate_ci": list(mean_interval(successes, rng=rng)),
        "mean_return": float(returns.mean()),
        "mean_return_ci": list(mean_interval(returns, rng=rng)),
        "completion_time_s": {"best": best, "q25": _quantile(times, 25), "median": median, "q75": _quantile(times, 75)},
        "mean_progress_fraction": float(reached.mean()),
        "ended_by": {
            **{how: ended.count(how) for how in ENDINGS},
            "fall": int((~solved & ~timed_out).sum()),
        },
        "references": {
            "task": REFERENCE_TASK,
            "cyberrunner_s": CYBERRUNNER_RECORD_S,
            "human_s": HUMAN_RECORD_S,
            "source": "Bi & D'Andrea 2023, arXiv 2312.09906 (best times on the real board)",
        },
        "best_over_cyberrunner": _ratio(best, CYBERRUNNER_RECORD_S, task),
        "best_over_human": _ratio(best, HUMAN_RECORD_S, task),
        "median_over_cyberrunner": _ratio(median, CYBERRUNNER_RECORD_S, task),
        "median_over_human": _ratio(median, HUMAN_RECORD_S, task),
        "successes": [bool(s) for s in solved],
        "lengths": [int(n) for n in lengths],
        "returns": [float(r) for r in returns],
        "progress_fractions": [float(p) for p in reached],
        "ended": ended,
    }


def score_labyrinth(
    policy: str | Path,
    task: str,
    *,
    episodes: int = LABYRINTH_PROTOCOL_EPISODES,
    sampled: bool = False,
    seed: int = LABYRINTH_PROTOCOL_SEED,
    progress: bool = True,
    obs: str | None = None,
    off_path_rule: str = "tolerance",
) -> dict[str, Any]:
    """The labyrinth protocol's numbers (:func:`summarise_labyrinth`) for ``policy`` on ``task``
    (LABYRINTH-EASY, -MEDIUM, -HARD): ``random``, ``noop``, ``expert``, a model-based learner's marble
    law (``.json``), or a bimgame run directory or checkpoint trained on ``task`` (see the module notes).
    ``sampled``: a network samples its actions
    (greedy by default); ``obs``: the observations a network must have been trained on (None: its
    own); built-in policies read no observations and take neither. ``off_path_rule``: when an episode
    ends off the path (:data:`~bimgame.envs.labyrinth_env.LABYRINTH_OFF_PATH_RULES`; the protocol's is
    ``tolerance``, the env's default), for every policy. Raises ``ValueError`` naming the bad value and
    what is allowed; the same arguments give the same dict but for ``seconds``."""
    task = _labyrinth_task(task)
    if off_path_rule not in LABYRINTH_OFF_PATH_RULES:
        raise ValueError(
            f"score_labyrinth.off_path_rule must be one of {', '.join(LABYRINTH_OFF_PATH_RULES)}, got {off_path_rule!r}"
        )
    require_int("score_labyrinth", "episodes", episodes, 1)
    if not (isinstance(seed, int) and not isinstance(seed, bool) and 0 <= seed and seed + episodes - 1 <= MAX_SEED):
        raise ValueError(f"score_labyrinth.seed must be an integer from 0 to {MAX_SEED} - (episodes - 1), got {seed!r}")
    starts = protocol_starts(episodes, seed)
    time_limit = puzzle(task).time_limit
    started = time.perf_counter()
    facts: dict[str, Any] = {"obs": None, "action_type": "continuous", "step": None}
    if isinstance(policy, str) and policy in LABYRINTH_POLICIES:
        layout = puzzle(task).layout
        assert layout is not None  # a labyrinth task has its layout
        result = _play_builtins(policy, layout, starts, time_limit, progress, off_path_rule)
        mode = None
    elif Path(policy).suffix == ".json":
        law = MarbleLaw.load(policy)  # ValueError naming the file when it is no law
        layout = puzzle(task).layout
        assert layout is not None  # a labyrinth task has its layout
        result = _play_builtins("model-based", layout, starts, time_limit, progress, off_path_rule, law)
        facts, mode = {"obs": "state", "action_type": "continuous", "step": None}, None
    else:
        source = _network_source(str(policy), task)
        result, facts = _play_network(
            source,
            task,
            obs=obs,
            sampled=sampled,
            episodes=episodes,
            seed=seed,
            progress=progress,
            off_path_rule=off_path_rule,
        )
        mode = "sampled" if sampled else "greedy"
    seconds = time.perf_counter() - started
    summary = summarise_labyrinth(result, task, starts, time_limit=time_limit)
    return {
        "policy": str(policy),
        "protocol_seed": seed,
        "off_path_rule": off_path_rule,
        "mode": mode,
        **facts,
        **summary,
        "seconds": seconds,
    }
