"""The benchmark protocol: one fixed way to score any policy on a task, and normalised scores.

**Protocol** (:class:`Protocol`): ``episodes`` episodes (100 by default) of the task, episode i
starting from ``reset(seed=episode_seed(PROTOCOL_SEED, i))`` — the same derivation the expert's
datasets use, so the expert's reference episodes are the protocol's — each under the task's own time
limit. Reported: success rate, mean return, mean length of the solved episodes, each with a
percentile-bootstrap 95% interval over episodes (seeded, so the same policy always gets the same
numbers), and the normalised score.

**Mazes** (``mazes``, :class:`MazeChoice`): ``merl`` (the default) plays every episode on MERL's
maze. Otherwise the episodes are on numbered random mazes (:mod:`bimgame.sim.maze_sets`), episode i
on a maze fixed by i alone, passed as ``reset(seed=…, options={"maze": number})`` to an env built
with ``num_mazes``: ``test`` puts episode i on held-out test maze i (so 100 episodes are 100
held-out mazes), ``test:N`` / ``train:N`` / ``…:START:N`` spread the episodes evenly over mazes
``START … START+N-1`` of the split (episode i on ``START + i·N // episodes``; a run trained with
``--num-mazes N`` trained on ``train:N``). Built-in policies plan in the episode's maze; a bimgame
network gets the observations it was trained on (see :func:`run_protocol`).

**Normalised score** (as D4RL and Minari define it): ``100 · (R − R_random) / (R_expert − R_random)``
with R the mean return, R_random that of a uniformly random policy and R_expert that of the MPC
expert with default settings, both measured once with the protocol and stored with the package
(:mod:`bimgame.expert.references`; ``bimgame score --measure-references`` measures them anew). 0 is the
random policy, 100 the expert. Neither reference looks at observations, so one pair serves state
and pixel observations alike. On random mazes the references are the ones measured on the held-out
test mazes (``--measure-references --mazes test``, stored in the same file under ``"mazes"`` →
``"test"``; the MERL entries are untouched): both splits draw their mazes from one distribution, so
those references put scores on training and test mazes on one scale. Without them the normalised
score is None.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import json
import multiprocessing
import os
import re
import time
from collections.abc import Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any

import numpy as np

from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.observe import OBS_MODES
from bimgame.experiments.policy_fitting import MazeScriptedPolicy, fitted_policy, reads_gate_bearings
from bimgame.experiments.policy_sources import EpisodePolicy, builtin_policy, load_policy
from bimgame.experiments.statistics import mean_interval
from bimgame.expert.evaluation import evaluate_expert, summarise
from bimgame.expert.mpc import MPCConfig
from bimgame.expert.pool import environment, episode_progress
from bimgame.expert.references import REFERENCES_FILE, normalised_score, references_for
from bimgame.sim.maze_sets import MAZE_SPLITS, UNLIMITED_MAZE_NUMBERS
from bimgame.sim.tasks import Task, parse_task, task_setting
from bimgame.util.processes import exit_when_parent_dies
from bimgame.util.progress import ProgressBar
from bimgame.util.seeding import episode_seed
from bimgame.util.settings import require_int

__all__ = [
    "Protocol",
    "MazeChoice",
    "MazeScriptedPolicy",
    "Score",
    "PROTOCOL_SEED",
    "PROTOCOL_EPISODES",
    "MAZE_FORMS",
    "score",
    "run_protocol",
    "measure_references",
    "maze_references",
]

#: The run seed the protocol's start seeds derive from (fixed: changing it changes every score).
PROTOCOL_SEED = 20_181_105
PROTOCOL_EPISODES = 100
#: Seed of the bootstrap's generator (the intervals are the same for the same episodes).
_BOOTSTRAP_SEED = 0
#: The forms a maze choice takes, for error messages and help.
MAZE_FORMS = "merl, test, test:N, test:START:N, train:N, train:START:N"
#: The stored references that normalise scores on random mazes (see the module notes).
MAZE_REFERENCES = "test"
#: Numeric libraries' thread counts, set to 1 in the worker processes of :func:`measure_references`.
_THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMEXPR_NUM_THREADS")


@dataclasses.dataclass(frozen=True)
class MazeChoice:
    """Which mazes a protocol's episodes are on: MERL's (``split`` None) or mazes of a split."""

    split: str | None = None
    """None (MERL's maze), ``train`` or ``test`` (:mod:`bimgame.sim.maze_sets`)."""
    start: int = 0
    """The first maze number of the set."""
    count: int | None = None
    """Mazes in the set; None: one per episode (``test``: episode i on test maze i)."""

    @classmethod
    def parse(cls, spec: str) -> MazeChoice:
        """``merl``, ``test``, ``test:N``, ``test:START:N``, ``train:N`` or ``train:START:N``; anything
        else raises ``ValueError`` naming these forms."""
        if not isinstance(spec, str):
            raise ValueError(f"mazes must be a string ({MAZE_FORMS}), got {spec!r}")
        split, *numbers = spec.strip().lower().split(":")
        if split == "merl" and not numbers:
            return cls()
        if split not in MAZE_SPLITS or len(numbers) > 2 or (split == "train" and not numbers):
            why = "train needs its number of mazes (train:N)" if split == "train" and not numbers else "unknown form"
            raise ValueError(f"mazes {spec!r}: {why}; allowed: {MAZE_FORMS} (N >= 1 mazes from number START >= 0)")
        if not all(re.fullmatch(r"\d+", n) for n in numbers):
            raise ValueError(f"mazes {spec!r}: START and N must be non-negative integers; allowed: {MAZE_FORMS}")
        start = int(numbers[0]) if len(numbers) == 2 else 0
        count = int(numbers[-1]) if numbers else None
        if count is not None and count < 1:
            raise ValueError(f"mazes {spec!r}: N (the number of mazes) must be >= 1; allowed: {MAZE_FORMS}")
        if start + (count or 0) > UNLIMITED_MAZE_NUMBERS:
            raise ValueError(f"mazes {spec!r}: maze numbers go up to {UNLIMITED_MAZE_NUMBERS - 1}")
        return cls(split, start, count)

    def __str__(self) -> str:
        if self.split is None:
            return "merl"
        if self.count is None:
            return self.split
        return f"{self.split}:{self.count}" if self.start == 0 else f"{self.split}:{self.start}:{self.count}"

    def set_size(self, episodes: int) -> int:
        """How many mazes the set holds (``test`` alone: one per episode)."""
        return self.count if self.count is not None else episodes

    def numbers(self, episodes: int) -> list[int] | None:
        """Episode i's maze number for each of ``episodes`` episodes (None on MERL's maze): ``START +
        i·N // episodes``, the episodes spread evenly over the set, episode i on maze i when N is
        ``episodes``."""
        if self.split is None:
            return None
        size = self.set_size(episodes)
        return [self.start + (i * size) // episodes for i in range(episodes)]

    def env_kwargs(self, episodes: int) -> dict[str, Any]:
        """:class:`~bimgame.envs.env.BallInMazeEnv` arguments of the set (none on MERL's maze)."""
        if self.split is None:
            return {}
        return {"num_mazes": self.set_size(episodes), "start_maze": self.start, "maze_split": self.split}

    def describe(self, episodes: int) -> str:
        """For titles: ``MERL's maze``, ``held-out test mazes 0..99``, ``training mazes 0..2``."""
        if self.split is None:
            return "MERL's maze"
        size = self.set_size(episodes)
        spaced = f" ({episodes} of them played)" if episodes < size else ""
        kind = "held-out test" if self.split == "test" else "training"
        return f"{kind} mazes {self.start}..{self.start + size - 1}{spaced}"


@dataclasses.dataclass(frozen=True)
class Protocol:
    """Which episodes a policy is scored on."""

    task: str = "STG1"
    """FULL, STG1 … STG4."""
    obs: str = "state"
    """The observations the policy gets: ``state`` or ``pixels``."""
    episodes: int = PROTOCOL_EPISODES
    """Episodes, from the protocol's fixed start seeds (the first ``episodes`` of them)."""
    mazes: str = "merl"
    """The episodes' mazes (:class:`MazeChoice`: merl, test, test:N, test:START:N, train:N,
    train:START:N); kept in its canonical spelling."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "task", task_setting("Protocol", self.task))
        if self.obs not in OBS_MODES:
            raise ValueError(f"Protocol.obs must be one of {OBS_MODES}, got {self.obs!r}")
        require_int("Protocol", "episodes", self.episodes, 1)
        try:
            choice = MazeChoice.parse(self.mazes)
        except ValueError as error:
            raise ValueError(f"Protocol.{error}") from None
        object.__setattr__(self, "mazes", str(choice))

    @property
    def time_limit(self) -> int:
        return Task(self.task).time_limit

    @property
    def maze_choice(self) -> MazeChoice:
        return MazeChoice.parse(self.mazes)

    def start_seeds(self) -> list[int]:
        return [episode_seed(PROTOCOL_SEED, i) for i in range(self.episodes)]

    def maze_numbers(self) -> list[int] | None:
        """Each episode's maze number (None on MERL's maze)."""
        return self.maze_choice.numbers(self.episodes)

    def make_env(self, *, gate_bearings: bool = False) -> BallInMazeEnv:
        """The env the episodes are played on: the protocol's observations, and its mazes (with
        ``gate_bearings``, state observations on mazes also hold them: for a network that reads them)."""
        kwargs: dict[str, Any] = self.maze_choice.env_kwargs(self.episodes)
        if gate_bearings:
            kwargs["gate_bearings"] = True
        return BallInMazeEnv(self.task, obs_mode=self.obs, **kwargs)


def maze_references(task: str, key: str = MAZE_REFERENCES) -> tuple[float, float] | None:
    """(random, expert) mean returns of ``task`` measured on the mazes stored under ``key`` (the
    package's reference file's ``"mazes"`` entry), or None if not measured."""
    resource = importlib.resources.files("bimgame.expert").joinpath(REFERENCES_FILE)
    stored = json.loads(resource.read_text()) if resource.is_file() else {}
    entry = stored.get("mazes", {}).get(key, {}).get("tasks", {}).get(parse_task(task).value)
    return None if entry is None else (float(entry["random"]), float(entry["expert"]))


@dataclasses.dataclass
class Score:
    """A policy's result under a :class:`Protocol`."""

    protocol: Protocol
    returns: list[float]
    lengths: list[int]
    successes: list[bool]
    seconds: float
    notes: list[str] = dataclasses.field(default_factory=list)
    """What the protocol changed for the policy (e.g. observations without the maze encoding)."""

    def summary(self) -> dict[str, Any]:
        """The protocol's numbers with 95% bootstrap intervals, the normalised score and the mazes."""
        returns = np.asarray(self.returns, dtype=np.float64)
        successes = np.asarray(self.successes, dtype=np.float64)
        solved = np.asarray([n for n, s in zip(self.lengths, self.successes, strict=True) if s], dtype=np.float64)
        rng = np.random.default_rng(_BOOTSTRAP_SEED)
        choice = self.protocol.maze_choice
        out: dict[str, Any] = {
            "task": self.protocol.task,
            "obs": self.protocol.obs,
            "episodes": len(returns),
            "seconds": self.seconds,
            "mazes": self.protocol.mazes,
            "maze_split": choice.split or "merl",
            "maze_set": choice.describe(self.protocol.episodes),
        }
        for name, values in (("success_rate", successes), ("mean_return", returns), ("mean_length_solved", solved)):
            out[name] = float(values.mean()) if len(values) else None
            out[f"{name}_ci"] = list(mean_interval(values, rng=rng)) if len(values) else None
        out["normalised_score"] = None
        out["normalised_score_ci"] = None
        out["references"] = None
        if choice.split is None:
            if references_for(self.protocol.task) is not None:
                out["normalised_score"] = normalised_score(self.protocol.task, out["mean_return"])
                out["normalised_score_ci"] = [normalised_score(self.protocol.task, v) for v in out["mean_return_ci"]]
                out["references"] = "merl"
        else:
            pair = maze_references(self.protocol.task)
            if pair is not None and pair[0] != pair[1]:
                low, high = pair
                out["normalised_score"] = 100.0 * (out["mean_return"] - low) / (high - low)
                out["normalised_score_ci"] = [100.0 * (v - low) / (high - low) for v in out["mean_return_ci"]]
                out["references"] = MAZE_REFERENCES
        out["notes"] = list(self.notes)
        return out


def score(
    policy: str,
    task: str = "STG1",
    *,
    obs: str = "state",
    episodes: int = PROTOCOL_EPISODES,
    sampled: bool = False,
    progress: bool = False,
    mazes: str = "merl",
) -> dict[str, Any]:
    """The protocol's numbers for the policy named by ``policy`` (see
    :func:`~bimgame.experiments.policy_sources.load_policy`) on ``mazes`` (:class:`MazeChoice`): what
    ``bimgame score`` prints."""
    protocol = Protocol(task=task, obs=obs, episodes=episodes, mazes=mazes)
    return run_protocol(load_policy(policy, obs=obs, sampled=sampled), protocol, progress=progress).summary()


def run_protocol(policy: EpisodePolicy, protocol: Protocol, *, progress: bool = False) -> Score:
    """Score ``policy`` with ``protocol``: one episode per start seed, in order, on a fresh
    single env with the protocol's observations, mazes and the task's time limit (episode i on its
    maze: ``reset(seed=…, options={"maze": …})``). Built-in policies (of
    :func:`~bimgame.experiments.policy_sources.builtin_policy`, or a :class:`MazeScriptedPolicy`, which
    a wrapper around one must use) plan in each episode's maze, and a bimgame network gets
    observations of the size it was trained on (see
    :func:`~bimgame.experiments.policy_fitting.fitted_policy`; the result's ``notes`` say what
    changed; one trained with gate bearings gets them); other policies get the env's observations,
    which on mazes end with the maze's encoding (128 values)."""
    on_mazes = protocol.obs == "state" and protocol.maze_choice.split is not None
    env = protocol.make_env(gate_bearings=on_mazes and reads_gate_bearings(policy))
    returns: list[float] = []
    lengths: list[int] = []
    successes: list[bool] = []
    started = time.perf_counter()
    numbers = protocol.maze_numbers()
    mazes: list[int | None] = [None] * protocol.episodes if numbers is None else list(numbers)
    try:
        policy, notes = fitted_policy(policy, env)
        label = f"score {protocol.task} {protocol.obs}" + ("" if protocol.mazes == "merl" else f" {protocol.mazes}")
        with ProgressBar(label, protocol.episodes, enabled=progress, transient=True) as bar:
            for seed, maze in zip(protocol.start_seeds(), mazes, strict=True):
                total, length, success = _play_episode(env, policy, seed, protocol.time_limit, maze)
                returns.append(total)
                lengths.append(length)
                successes.append(success)
                bar.update(advance=1, info=f"success {np.mean(successes):.0%}")
    finally:
        env.close()
    return Score(protocol, returns, lengths, successes, time.perf_counter() - started, notes)


def _play_episode(
    env: BallInMazeEnv, policy: EpisodePolicy, seed: int, time_limit: int, maze: int | None = None
) -> tuple[float, int, bool]:
    """One episode of ``policy`` from start seed ``seed`` (on maze number ``maze`` of the env's set),
    cut at ``time_limit`` steps: its return, its length in steps and whether it succeeded."""
    obs, info = env.reset(seed=seed, options=None if maze is None else {"maze": maze})
    policy.reset(seed)
    total = 0.0
    for step in range(1, time_limit + 1):
        obs, reward, terminated, _, info = env.step(policy.act(env, obs, info))
        policy.observe(reward)
        total += float(reward)
        if terminated:
            return total, step, bool(info["is_success"])
    return total, time_limit, False


def _builtin_episode(protocol: Protocol, name: str, index: int) -> tuple[int, float, int, bool]:
    """Episode ``index`` of ``protocol`` played by built-in policy ``name`` on an env of its own:
    (index, return, length, success), as :func:`run_protocol` plays it."""
    env = protocol.make_env()
    try:
        mazes = protocol.maze_numbers()
        seed = episode_seed(PROTOCOL_SEED, index)
        policy, _ = fitted_policy(builtin_policy(name), env)
        return (index, *_play_episode(env, policy, seed, protocol.time_limit, None if mazes is None else mazes[index]))
    finally:
        env.close()


def _worker_started() -> None:
    """A worker of :func:`_builtin_score` ends when the process that started it dies."""
    parent = multiprocessing.parent_process()
    exit_when_parent_dies(parent.pid if parent is not None else None)


def _builtin_episodes(protocol: Protocol, name: str, workers: int) -> Iterator[tuple[int, float, int, bool]]:
    """Every episode of ``protocol`` played by built-in policy ``name`` (:func:`_builtin_episode`), on
    ``workers`` processes (spawned, single-threaded numerics; 1: in this process), as they finish."""
    indices = range(protocol.episodes)
    if workers == 1 or protocol.episodes == 1:
        yield from (_builtin_episode(protocol, name, index) for index in indices)
        return
    context = multiprocessing.get_context("spawn")
    with environment(**dict.fromkeys(_THREAD_VARIABLES, "1")):
        pool = ProcessPoolExecutor(min(workers, protocol.episodes), context, initializer=_worker_started)
        try:
            pending = {pool.submit(_builtin_episode, protocol, name, index) for index in indices}
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                yield from (future.result() for future in finished)
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise
        pool.shutdown(wait=True)


def _builtin_score(protocol: Protocol, name: str, *, workers: int, progress: bool) -> Score:
    """:func:`run_protocol` of built-in policy ``name`` with its episodes on ``workers`` processes: the
    same numbers, since each episode depends on its index alone."""
    started = time.perf_counter()
    results: dict[int, tuple[float, int, bool]] = {}
    label = f"{name} on {protocol.task} {protocol.mazes}"
    with episode_progress(progress, label, protocol.episodes, transient=True) as update:
        for index, total, length, success in _builtin_episodes(protocol, name, workers):
            results[index] = (total, length, success)
            update(success)
    returns, lengths, successes = zip(*(results[i] for i in range(protocol.episodes)), strict=True)
    return Score(protocol, list(returns), list(lengths), list(successes), time.perf_counter() - started)


def measure_references(
    tasks: list[str],
    *,
    episodes: int = PROTOCOL_EPISODES,
    workers: int | None = None,
    progress: bool = True,
    mazes: str = "merl",
) -> dict[str, Any]:
    """The reference returns measured with the protocol: a uniformly random policy (in process) and
    the default MPC expert (on ``workers`` processes, default all cores; same start seeds), per task,
    on ``mazes`` (the package stores MERL's at the top level and the test mazes' under ``"mazes"`` →
    ``"test"``; see the module notes)."""
    choice = MazeChoice.parse(mazes)
    out: dict[str, Any] = {
        "protocol_seed": PROTOCOL_SEED,
        "episodes": episodes,
        "expert": MPCConfig().__dict__,
        "tasks": {},
    }
    if choice.split is not None:
        out["mazes"] = str(choice)
    workers = workers if workers is not None else (os.cpu_count() or 1)
    require_int("measure_references", "workers", workers, 1)
    for task in tasks:
        protocol = Protocol(task=task, obs="state", episodes=episodes, mazes=str(choice))
        random = run_protocol(builtin_policy("random"), protocol, progress=progress).summary()
        if choice.split is None:
            expert = evaluate_expert(task, episodes, seed=PROTOCOL_SEED, workers=workers, progress=progress)
            expert_summary = summarise(expert)
        else:
            expert_summary = _builtin_score(protocol, "expert", workers=workers, progress=progress).summary()
        out["tasks"][protocol.task] = {
            "random": random["mean_return"],
            "expert": expert_summary["mean_return"],
            "random_success_rate": random["success_rate"],
            "expert_success_rate": expert_summary["success_rate"],
        }
    return out
