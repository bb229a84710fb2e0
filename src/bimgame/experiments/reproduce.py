"""The paper's experiments (DESIGN §1 item 8) as one resumable grid of pieces.

A reproduction lives in one directory ``DIR``::

    plan.json        the budget and every piece: id, kind, directory, dependencies, cost estimate
    status.json      each piece's state (done, failed, …), wall time and how often it was computed;
                     rewritten (atomically) after every piece
    data/            the expert dataset (FULL by default: it labels every task)
    pretrain/<TASK>/policy-seed<k>/   π^s, pre-trained on the dataset relabelled for TASK
    pretrain/<TASK>/value-seed<k>/    V̂, the value-only network used as a shaping potential
    runs/<TASK>/<algorithm>/seed<k>/  an A3C run (bimgame.learn.a3c) or a DAgger run (bimgame.learn.dagger)

The grid is tasks × algorithms × seeds, with the algorithms

- ``a3c``: A3C from random weights;
- ``pretrain+a3c``: A3C starting from π^s (paper §1 item 5);
- ``a3c+value``: A3C from random weights on r + γV̂(s') − V̂(s) (item 6);
- ``pretrain+a3c+value``: both;
- ``dagger``: DAgger with the MPC expert (item 7), from random weights.

**Pre-training is done per task and per seed**, not once per task: seed k of ``pretrain+a3c``
starts from a π^s trained with seed k (its own initial weights and held-out split), so the spread
over seeds — and the bootstrap intervals of :mod:`bimgame.experiments.report` — include the variability of
pre-training, which is part of the method being compared. On state observations a pre-training
costs seconds; on pixels minutes, still small next to an A3C run.

**Resuming.** Whether a piece is finished is decided from its own outputs, never from
``status.json`` alone: a dataset with its ``COMPLETE`` marker, a pre-training with its
``summary.json``, an A3C run with a ``summary.json`` that says it finished its steps, a DAgger run
whose ``dagger_state.json`` counts all its iterations. Finished pieces are skipped; an unfinished
A3C or DAgger run is resumed from its last checkpoint, an unfinished dataset from its saved
episodes; an unfinished pre-training (not resumable, and cheap) is started again. So an
interrupted reproduction — Ctrl-C, a crash, ``stop_after`` — continues where it stopped when the
same command is run again.

**Threads.** Pre-training and DAgger run in this process with up to two torch threads. On a
two-core machine that is also running something else, two intra-op threads made a small state
network's pre-training ten times slower than one (54 s against 5 s, measured with another training
run on the machine). The budget's ``torch_threads`` (default 1) sets the count for these library
calls (see :func:`library_threads`); A3C workers always use one thread each.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import json
import shutil
import time
import traceback
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

from bimgame.util.files import exclusive_lock
from bimgame.learn.runs import write_json
from bimgame.util.settings import from_dict, require_int
from bimgame.sim.tasks import Task, parse_task

__all__ = ["ALGORITHMS", "PAPER_TASKS", "PIECE_KINDS", "GRID_FIELDS", "PLAN", "STATUS", "Budget", "BUDGETS",
           "budget_named", "CostModel", "COSTS", "Piece", "plan_pieces", "piece_done", "estimate_seconds",
           "format_duration", "ReproductionResult", "reproduce", "check_compatible", "write_plan", "load_plan",
           "load_status", "library_threads", "a3c_config_for", "pretrain_config_for", "dagger_config_for",
           "algorithm_slug"]

#: The compared methods, in the order of the paper's figures.
ALGORITHMS = ("a3c", "pretrain+a3c", "a3c+value", "pretrain+a3c+value", "dagger")
#: The tasks of the paper's learning curves (STG3/STG4 can be added: the paper reports them unlearned).
PAPER_TASKS = ("FULL", "STG1", "STG2")
PIECE_KINDS = ("dataset", "pretrain-policy", "pretrain-value", "a3c", "dagger")
#: Budget fields that only change which pieces exist (not what any piece computes): a reproduction
#: directory may be continued with other values of these, reusing every piece they share.
GRID_FIELDS = ("tasks", "algorithms", "seeds")
PLAN = "plan.json"
STATUS = "status.json"
_LOCK = ".reproduce.lock"
_PLAN_FORMAT = "bimgame-reproduction-1"


def algorithm_slug(algorithm: str) -> str:
    """The directory name of an algorithm (``pretrain+a3c+value`` → ``pretrain-a3c-value``)."""
    return algorithm.replace("+", "-")


def _depth(task: Task) -> int:
    """How many walls an episode of ``task`` passes (FULL: all four)."""
    return 4 if task.steps_to_go is None else task.steps_to_go


# ------------------------------------------------------------------------------------ budgets
@dataclasses.dataclass(frozen=True)
class Budget:
    """Everything that decides what a reproduction computes: the grid and every piece's settings.

    The presets are :data:`BUDGETS` (``quick`` and ``paper``); any field can be changed with
    :func:`dataclasses.replace`. Invalid values raise ``ValueError`` naming the field."""

    name: str = "custom"
    """A label for reports (``quick``, ``paper`` or anything else)."""
    tasks: tuple[str, ...] = ("STG1",)
    """Tasks of the grid (FULL, STG1 … STG4)."""
    algorithms: tuple[str, ...] = ALGORITHMS
    """Methods of the grid (see :data:`ALGORITHMS`)."""
    seeds: int = 2
    """Runs per task and algorithm (seeds 0 … seeds−1)."""
    obs: str = "state"
    """``state`` or ``pixels`` (the paper's), for every network of the grid."""
    a3c_steps: Mapping[str, int] = dataclasses.field(default_factory=lambda: {t.value: 1_000_000 for t in Task})
    """Environment steps per A3C run, per task (every task of the grid needs an entry)."""
    workers: int = 2
    """A3C worker processes."""
    envs_per_worker: int = 16
    """Environments per A3C worker (stepped as one batch)."""
    hidden: int | None = None
    """LSTM size of every network; None: the default for ``obs`` (256 pixels, 128 state)."""
    features: int | None = None
    """Encoder output size; None: the default for ``obs``."""
    subtract_background: bool = False
    """Pixels: subtract the empty-maze frame before the convolutions (ignored for state). The
    presets turn it on: without it the pixel agent did not learn STG1 (see the README)."""
    eval_every: int = 100_000
    """A3C: environment steps between greedy/sampled evaluations (0: only the final one)."""
    eval_episodes: int = 10
    """A3C: episodes per evaluation."""
    checkpoint_every: int = 50_000
    """A3C: environment steps between checkpoints (what an interruption can lose)."""
    dataset_task: str = "FULL"
    """Task of the expert dataset; it must be at least as deep as every task of the grid (FULL
    labels every task, see :func:`bimgame.pretrain.relabel`)."""
    dataset_episodes: int = 40
    dataset_seed: int = 0
    dataset_max_steps: int | None = None
    """Time limit of the expert's episodes; None: the dataset task's."""
    dataset_workers: int = 2
    """Processes generating expert episodes (1: in this process)."""
    pretrain_epochs: int = 30
    pretrain_patience: int = 5
    pretrain_eval_episodes: int = 50
    """Episodes measuring π^s alone as a policy (greedy and sampled)."""
    value_epochs: int = 100
    value_patience: int = 10
    value_batch_frames: int = 64
    dagger_iterations: int = 4
    dagger_episodes: int = 6
    """DAgger: learner rollouts per iteration (each state labelled by the MPC expert, ≈16 ms each)."""
    dagger_epochs: int = 5
    """DAgger: passes over the aggregated data per iteration."""
    dagger_eval_episodes: int = 20
    threshold_fraction: float = 0.8
    """Steps-to-threshold: the success rate to reach, as a fraction of the expert's on the task."""
    torch_threads: int = 1
    """Torch threads of pre-training and DAgger (see the module notes; A3C workers use one each)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "tasks", tuple(self.tasks))
        object.__setattr__(self, "algorithms", tuple(self.algorithms))
        allowed_tasks = ", ".join(t.value for t in Task)
        if not self.tasks:
            raise ValueError(f"Budget.tasks must name at least one task; allowed: {allowed_tasks}")
        tasks = []
        for task in self.tasks:
            try:
                tasks.append(parse_task(task).value)
            except ValueError:
                raise ValueError(f"Budget.tasks: unknown task {task!r}; allowed: {allowed_tasks}") from None
        if len(set(tasks)) != len(tasks):
            raise ValueError(f"Budget.tasks lists a task twice: {tasks}")
        object.__setattr__(self, "tasks", tuple(tasks))
        if not self.algorithms:
            raise ValueError(f"Budget.algorithms must name at least one; allowed: {', '.join(ALGORITHMS)}")
        unknown = [a for a in self.algorithms if a not in ALGORITHMS]
        if unknown:
            raise ValueError(f"Budget.algorithms: unknown {unknown}; allowed: {', '.join(ALGORITHMS)}")
        if len(set(self.algorithms)) != len(self.algorithms):
            raise ValueError(f"Budget.algorithms lists an algorithm twice: {list(self.algorithms)}")
        # Keep the canonical order, whatever order they were given in.
        object.__setattr__(self, "algorithms", tuple(a for a in ALGORITHMS if a in self.algorithms))
        from bimgame.envs.observe import OBS_MODES

        if self.obs not in OBS_MODES:
            raise ValueError(f"Budget.obs must be one of {', '.join(OBS_MODES)}, got {self.obs!r}")
        steps = dict(self.a3c_steps)
        for key, value in steps.items():
            try:
                parse_task(key)
            except ValueError:
                raise ValueError(f"Budget.a3c_steps: unknown task {key!r}; allowed: {allowed_tasks}") from None
            _check_int(f"a3c_steps[{key!r}]", value, 1)
        missing = [t for t in self.tasks if t not in steps]
        if missing and any(a != "dagger" for a in self.algorithms):
            raise ValueError(f"Budget.a3c_steps has no entry for {missing}; give steps for every task of the grid")
        object.__setattr__(self, "a3c_steps", {parse_task(k).value: int(v) for k, v in steps.items()})
        for name in ("seeds", "workers", "envs_per_worker", "eval_episodes", "checkpoint_every", "dataset_episodes",
                     "dataset_workers", "pretrain_epochs", "pretrain_patience", "value_epochs", "value_patience",
                     "value_batch_frames", "dagger_iterations", "dagger_episodes", "dagger_epochs", "torch_threads"):
            _check_int(name, getattr(self, name), 1)
        for name in ("eval_every", "dataset_seed", "pretrain_eval_episodes", "dagger_eval_episodes"):
            _check_int(name, getattr(self, name), 0)
        for name in ("hidden", "features", "dataset_max_steps"):
            if getattr(self, name) is not None:
                _check_int(name, getattr(self, name), 1)
        if not isinstance(self.subtract_background, bool):
            raise ValueError(f"Budget.subtract_background must be True or False, got {self.subtract_background!r}")
        if not (isinstance(self.threshold_fraction, (int, float)) and not isinstance(self.threshold_fraction, bool)
                and 0.0 < self.threshold_fraction <= 1.0):
            raise ValueError(f"Budget.threshold_fraction must be in (0, 1], got {self.threshold_fraction!r}")
        try:
            data_task = parse_task(self.dataset_task)
        except ValueError:
            raise ValueError(f"Budget.dataset_task: unknown task {self.dataset_task!r}; allowed: "
                             f"{allowed_tasks}") from None
        object.__setattr__(self, "dataset_task", data_task.value)
        too_deep = [t for t in self.tasks if _depth(Task(t)) > _depth(data_task)]
        if too_deep:
            raise ValueError(f"Budget.dataset_task {data_task.value} cannot label {too_deep}: its episodes end "
                             f"before theirs would; use dataset_task='FULL' (it labels every task)")

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready values (what ``plan.json`` stores)."""
        values = dataclasses.asdict(self)
        values["tasks"] = list(self.tasks)
        values["algorithms"] = list(self.algorithms)
        values["a3c_steps"] = dict(self.a3c_steps)
        return values

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> Budget:
        """The budget of :meth:`to_dict`'s values; unknown keys are an error naming them."""
        return from_dict(cls, dict(values), "budget settings")

    def with_grid(self, *, tasks: tuple[str, ...] | list[str] | None = None,
                  algorithms: tuple[str, ...] | list[str] | None = None, seeds: int | None = None,
                  obs: str | None = None, torch_threads: int | None = None) -> Budget:
        """This budget with the given grid (and observation) overrides; None keeps the value."""
        changes = {k: v for k, v in (("tasks", tasks), ("algorithms", algorithms), ("seeds", seeds), ("obs", obs),
                                     ("torch_threads", torch_threads)) if v is not None}
        return dataclasses.replace(self, **changes)

    def steps_for(self, task: str) -> int:
        """Environment steps of an A3C run on ``task``."""
        return int(self.a3c_steps[parse_task(task).value])

    @property
    def needs_policy(self) -> bool:
        """Whether an algorithm of the grid starts from a pre-trained π^s."""
        return any(a.startswith("pretrain") for a in self.algorithms)

    @property
    def needs_value(self) -> bool:
        """Whether an algorithm of the grid is rewarded with a pre-trained V̂."""
        return any(a.endswith("+value") for a in self.algorithms)


def _check_int(name: str, value: Any, minimum: int) -> None:
    require_int("Budget", name, value, minimum)


#: The presets. ``quick`` shows the comparison on STG1 within half an hour on two cores: state
#: observations, where A3C from scratch reached 80% success after 210k–255k steps in six runs, so
#: 300k steps per run; 80 FULL expert episodes (40 gave a π^s that solved STG1 0–34% of the time
#: alone, 80 gave 42–88%); two seeds. Measured: 8.4 minutes on the idle two-core machine (pre-training
#: sped A3C up 2.3×); with a 40-episode dataset it took 23 minutes while other training jobs kept
#: both cores busy. ``paper`` is the paper's grid: pixels, FULL/STG1/STG2, five seeds, 5M steps per
#: A3C run, a 300-episode FULL dataset — about two and a half days on two cores (``bimgame
#: reproduce --dry-run`` prints the estimate per piece).
BUDGETS: dict[str, Budget] = {
    "quick": Budget(
        name="quick", tasks=("STG1",), seeds=2, obs="state", subtract_background=True,
        a3c_steps={"STG1": 300_000, "STG2": 1_000_000, "STG3": 1_500_000, "STG4": 2_000_000, "FULL": 2_000_000},
        eval_every=100_000, eval_episodes=10, checkpoint_every=50_000,
        dataset_task="FULL", dataset_episodes=80, dataset_workers=2,
        pretrain_eval_episodes=50, dagger_iterations=4, dagger_episodes=6, dagger_epochs=10, dagger_eval_episodes=20),
    "paper": Budget(
        name="paper", tasks=PAPER_TASKS, seeds=5, obs="pixels", subtract_background=True,
        a3c_steps={t.value: 5_000_000 for t in Task},
        eval_every=250_000, eval_episodes=20, checkpoint_every=200_000,
        dataset_task="FULL", dataset_episodes=300, dataset_workers=2,
        pretrain_eval_episodes=50, dagger_iterations=10, dagger_episodes=20, dagger_epochs=10,
        dagger_eval_episodes=20),
}


def budget_named(name: str) -> Budget:
    """A preset of :data:`BUDGETS` by name."""
    if name not in BUDGETS:
        raise ValueError(f"unknown budget {name!r}; allowed: {', '.join(BUDGETS)}")
    return BUDGETS[name]


# ------------------------------------------------------------------------------- cost model
@dataclasses.dataclass(frozen=True)
class CostModel:
    """Per-piece wall-time estimates on an otherwise idle two-core machine (the reference machine
    of the README); a concurrent job slows every piece down. Each field says where its number comes
    from; the totals were checked against whole runs of the ``quick`` budget."""

    a3c_sps: Mapping[str, float] = dataclasses.field(default_factory=lambda: {"state": 9_000.0, "pixels": 1_870.0})
    """A3C environment steps/s with 2 workers × 16 envs, scaled by workers/2 (state: 9,900 measured
    in the quick budget's runs on the idle machine, 2,000–3,000 while other training jobs ran;
    pixels: the README's speed table)."""
    a3c_overhead_s: float = 6.0
    """Per A3C run: starting the worker processes, the final evaluation, the curves figure."""
    expert_episode_s: Mapping[str, float] = dataclasses.field(default_factory=lambda: {
        "FULL": 2.3, "STG1": 0.6, "STG2": 1.0, "STG3": 1.5, "STG4": 2.0})
    """One MPC expert episode on one core (FULL: 80 episodes took 90 s on two idle cores; STG1:
    ≈ 40 decisions of ≈ 16 ms; STG2–4 interpolated)."""
    expert_label_s: float = 0.016
    """One MPC decision (DAgger's label for one visited state)."""
    expert_steps: Mapping[str, float] = dataclasses.field(default_factory=lambda: {
        "FULL": 200.0, "STG1": 40.0, "STG2": 90.0, "STG3": 130.0, "STG4": 200.0})
    """Mean length of an expert episode (the dataset's size in steps)."""
    train_frame_s: Mapping[str, float] = dataclasses.field(default_factory=lambda: {"state": 1.5e-4,
                                                                                     "pixels": 8e-4})
    """Pre-training and DAgger: one frame through forward and backward, one thread (pixels: the
    README's ≈ 750 µs per sample at batch 16; state: rough, from the quick budget's pre-trainings)."""
    pretrain_epochs_expected: float = 15.0
    """Epochs until early stopping typically ends a pre-training."""
    eval_step_s: Mapping[str, float] = dataclasses.field(default_factory=lambda: {"state": 4e-3, "pixels": 1.2e-2})
    """One batched evaluation step (all episodes of an evaluation side by side; rough)."""
    piece_overhead_s: float = 2.0
    """Per pre-training or DAgger piece: loading the dataset, building the network."""
    dagger_length_share: float = 0.35
    """DAgger after its first iteration: mean rollout length as a share of the time limit (the
    learner's failures run to it; 0.3 measured on STG1 in the quick budget)."""


COSTS = CostModel()


def _time_limit(task: str) -> int:
    from bimgame.sim.tasks import MAX_EPISODE_STEPS

    return MAX_EPISODE_STEPS[Task(task)]


def _eval_seconds(task: str, obs: str, episodes: int, costs: CostModel) -> float:
    """A greedy and a sampled batched evaluation that may run to the time limit."""
    return 0.0 if episodes == 0 else 2 * _time_limit(task) * costs.eval_step_s[obs]


def estimate_seconds(piece: Piece, budget: Budget, costs: CostModel = COSTS) -> float:
    """Expected wall time of one piece (see :class:`CostModel`)."""
    obs = budget.obs
    if piece.kind == "dataset":
        per_episode = costs.expert_episode_s[budget.dataset_task]
        return costs.piece_overhead_s + budget.dataset_episodes * per_episode / min(budget.dataset_workers, 2)
    task = piece.task or budget.dataset_task
    frames = budget.dataset_episodes * costs.expert_steps[task] * 0.8  # 20% held out
    if piece.kind == "pretrain-policy":
        epochs = min(budget.pretrain_epochs, costs.pretrain_epochs_expected)
        return (costs.piece_overhead_s + epochs * frames * costs.train_frame_s[obs]
                + _eval_seconds(task, obs, budget.pretrain_eval_episodes, costs))
    if piece.kind == "pretrain-value":
        epochs = min(budget.value_epochs, 2 * costs.pretrain_epochs_expected)
        return costs.piece_overhead_s + epochs * frames * costs.train_frame_s[obs] / 3  # feed-forward
    if piece.kind == "a3c":
        sps = costs.a3c_sps[obs] * min(budget.workers, 2) / 2
        return costs.a3c_overhead_s + budget.steps_for(task) / sps
    if piece.kind == "dagger":
        seconds = costs.piece_overhead_s
        aggregated = 0.0
        for iteration in range(budget.dagger_iterations):
            # Iteration 0 follows the expert; later ones mostly the learner, whose failures run long.
            length = costs.expert_steps[task] if iteration == 0 else costs.dagger_length_share * _time_limit(task)
            labels = budget.dagger_episodes * length
            aggregated += labels
            seconds += (labels * costs.expert_label_s + budget.dagger_epochs * aggregated * costs.train_frame_s[obs]
                        + _eval_seconds(task, obs, budget.dagger_eval_episodes, costs))
        return seconds
    raise ValueError(f"unknown piece kind {piece.kind!r}; allowed: {', '.join(PIECE_KINDS)}")


def format_duration(seconds: float) -> str:
    """``95`` → ``1.6 min``, ``7200`` → ``2.0 h``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


# ------------------------------------------------------------------------------------ pieces
@dataclasses.dataclass(frozen=True)
class Piece:
    """One unit of work of a reproduction, saved in its own directory ``path`` (relative to DIR)."""

    id: str
    kind: str
    path: str
    task: str | None = None
    algorithm: str | None = None
    seed: int | None = None
    needs: tuple[str, ...] = ()
    """Ids of the pieces whose outputs this one reads."""

    def to_dict(self) -> dict[str, Any]:
        values = dataclasses.asdict(self)
        values["needs"] = list(self.needs)
        return values


def _policy_path(task: str, seed: int) -> str:
    return f"pretrain/{task}/policy-seed{seed}"


def _value_path(task: str, seed: int) -> str:
    return f"pretrain/{task}/value-seed{seed}"


def _run_path(task: str, algorithm: str, seed: int) -> str:
    return f"runs/{task}/{algorithm_slug(algorithm)}/seed{seed}"


def plan_pieces(budget: Budget) -> list[Piece]:
    """Every piece of the grid in the order they run: the dataset, then per task and seed the
    pre-trainings that seed needs and its runs (seed 0 of every algorithm before seed 1, so a
    partial reproduction already holds whole comparisons)."""
    pieces = [Piece(id="data", kind="dataset", path="data", task=budget.dataset_task)]
    for task in budget.tasks:
        for seed in range(budget.seeds):
            policy, value = _policy_path(task, seed), _value_path(task, seed)
            if budget.needs_policy:
                pieces.append(Piece(id=policy, kind="pretrain-policy", path=policy, task=task, seed=seed,
                                    needs=("data",)))
            if budget.needs_value:
                pieces.append(Piece(id=value, kind="pretrain-value", path=value, task=task, seed=seed,
                                    needs=("data",)))
            for algorithm in budget.algorithms:
                path = _run_path(task, algorithm, seed)
                if algorithm == "dagger":
                    pieces.append(Piece(id=path, kind="dagger", path=path, task=task, algorithm=algorithm, seed=seed))
                    continue
                needs = tuple(p for p, used in ((policy, algorithm.startswith("pretrain")),
                                                (value, algorithm.endswith("+value"))) if used)
                pieces.append(Piece(id=path, kind="a3c", path=path, task=task, algorithm=algorithm, seed=seed,
                                    needs=needs))
    return pieces


# ------------------------------------------------------------------------- piece settings
def pretrain_config_for(budget: Budget, task: str, seed: int, target: str) -> "PretrainConfig":  # noqa: F821
    """The pre-training settings of π^s (``target="policy"``) or V̂ (``"value"``) for a task and seed."""
    from bimgame.learn.pretrain import PretrainConfig

    common = dict(task=task, obs=budget.obs, seed=seed, hidden=budget.hidden, features=budget.features,
                  subtract_background=budget.subtract_background and budget.obs == "pixels")
    if target == "policy":
        return PretrainConfig(target="policy", epochs=budget.pretrain_epochs, patience=budget.pretrain_patience,
                              eval_episodes=budget.pretrain_eval_episodes, **common)
    if target == "value":
        return PretrainConfig(target="value", epochs=budget.value_epochs, patience=budget.value_patience,
                              batch_frames=budget.value_batch_frames, eval_episodes=0, **common)
    raise ValueError(f"unknown pre-training target {target!r}; allowed: policy, value")


def a3c_config_for(budget: Budget, task: str, seed: int) -> "A3CConfig":  # noqa: F821
    """The A3C settings of every A3C algorithm's run for a task and seed (the algorithms differ in
    the initial weights and the reward, not in these)."""
    from bimgame.learn.a3c import A3CConfig

    return A3CConfig(task=task, obs=budget.obs, steps=budget.steps_for(task), workers=budget.workers,
                     envs_per_worker=budget.envs_per_worker, seed=seed, hidden=budget.hidden, features=budget.features,
                     subtract_background=budget.subtract_background and budget.obs == "pixels",
                     eval_every=budget.eval_every, eval_episodes=budget.eval_episodes,
                     checkpoint_every=budget.checkpoint_every)


def dagger_config_for(budget: Budget, task: str, seed: int) -> "DAggerConfig":  # noqa: F821
    """DAgger's settings for a task and seed (the learner is the same network as A3C's)."""
    from bimgame.learn.dagger import DAggerConfig
    from bimgame.learn.pretrain import PretrainConfig

    learner = PretrainConfig(task=task, obs=budget.obs, seed=seed, hidden=budget.hidden, features=budget.features,
                             subtract_background=budget.subtract_background and budget.obs == "pixels",
                             eval_episodes=0)
    return DAggerConfig(learner=learner, iterations=budget.dagger_iterations,
                        episodes_per_iteration=budget.dagger_episodes, epochs_per_iteration=budget.dagger_epochs,
                        eval_episodes=budget.dagger_eval_episodes)


# ---------------------------------------------------------------------------- done or not
def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        value = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return value if isinstance(value, dict) else None


def piece_done(piece: Piece, out_dir: str | Path, budget: Budget) -> bool:
    """Whether ``piece``'s outputs in ``out_dir`` show it finished (see the module notes)."""
    path = Path(out_dir) / piece.path
    if piece.kind == "dataset":
        from bimgame.expert.datasets import DatasetError, dataset_summary

        try:
            dataset_summary(path)
        except (DatasetError, OSError):
            return False
        return True
    if piece.kind in ("pretrain-policy", "pretrain-value"):
        return (path / "summary.json").is_file() and (path / "checkpoint.pt").is_file()
    if piece.kind == "a3c":
        summary = _read_json(path / "summary.json")
        if summary is not None and summary.get("stopped") == "finished" and \
                int(summary.get("steps", 0)) >= budget.steps_for(piece.task):
            return True
        return _checkpoint_step(path) >= budget.steps_for(piece.task)
    if piece.kind == "dagger":
        state = _read_json(path / "dagger_state.json")
        return state is not None and int(state.get("iteration", 0)) >= budget.dagger_iterations
    raise ValueError(f"unknown piece kind {piece.kind!r}; allowed: {', '.join(PIECE_KINDS)}")


def _checkpoint_step(run_dir: Path) -> int:
    """The step of a run's checkpoint (-1 when there is none). A run whose checkpoint already holds
    all its steps but that stopped before writing its summary (killed during the final evaluation)
    cannot be resumed by :func:`bimgame.a3c.train`, and needs nothing more: its logs are complete."""
    if not (run_dir / "checkpoint.pt").is_file():
        return -1
    from bimgame.learn.runs import CheckpointError, load_checkpoint

    try:
        return int(load_checkpoint(run_dir / "checkpoint.pt")["step"])
    except CheckpointError:
        return -1


# ------------------------------------------------------------------------------ running pieces
@contextlib.contextmanager
def library_threads(count: int) -> Iterator[None]:
    """Run a block — the pieces' library calls — with ``count`` torch threads, restoring the caller's
    setting afterwards. :func:`bimgame.pretrain.pretrain` and :func:`bimgame.dagger.dagger` use at
    most the caller's count (:func:`bimgame.runs.torch_threads`), so this decides theirs."""
    from bimgame.learn.runs import torch_threads

    with torch_threads(count):
        yield


def _run_dataset(piece: Piece, budget: Budget, out_dir: Path) -> str:
    from bimgame.expert.datasets import generate_dataset

    generate_dataset(out_dir / piece.path, task=budget.dataset_task, episodes=budget.dataset_episodes,
                     seed=budget.dataset_seed, workers=budget.dataset_workers, progress=False,
                     max_steps=budget.dataset_max_steps)
    return ""


def _run_pretrain(piece: Piece, budget: Budget, out_dir: Path) -> str:
    from bimgame.learn.pretrain import KIND_POLICY, KIND_VALUE, pretrain

    target = "policy" if piece.kind == "pretrain-policy" else "value"
    path = out_dir / piece.path
    note = ""
    stored = _read_json(path / "config.json")
    if stored is not None or (path / "checkpoint.pt").exists():
        # Started but unfinished (pre-training cannot resume): start it again. Only our own kind of
        # run directory is removed.
        expected = KIND_POLICY if target == "policy" else KIND_VALUE
        if stored is None or stored.get("kind") != expected:
            raise ValueError(f"{path} holds something other than an unfinished {expected} run; move it away "
                             f"and run again")
        shutil.rmtree(path)
        note = "restarted an unfinished pre-training"
    pretrain(pretrain_config_for(budget, piece.task, piece.seed, target), out_dir / "data", path, progress=False)
    return note


def _run_a3c(piece: Piece, budget: Budget, out_dir: Path) -> str:
    from bimgame.learn.a3c import train
    from bimgame.envs.shaping import ValueReward

    path = out_dir / piece.path
    config = a3c_config_for(budget, piece.task, piece.seed)
    init = (out_dir / _policy_path(piece.task, piece.seed)).resolve() if piece.algorithm.startswith("pretrain") \
        else None
    value = (out_dir / _value_path(piece.task, piece.seed)).resolve() if piece.algorithm.endswith("+value") \
        else None
    wrapper = ValueReward(str(value), gamma=config.gamma) if value is not None else None
    resume = (path / "config.json").is_file()
    extra = {"reward": {"value_reward": None if value is None else str(value), "geodesic_coef": None},
             "reproduction": {"algorithm": piece.algorithm, "task": piece.task, "seed": piece.seed}}
    result = train(config, path, resume=resume, init=init, env_wrapper=wrapper, progress=False, extra_config=extra)
    if result.stopped != "finished":
        raise KeyboardInterrupt
    return "resumed from its checkpoint" if resume else ""


def _run_dagger(piece: Piece, budget: Budget, out_dir: Path) -> str:
    from bimgame.learn.dagger import dagger

    path = out_dir / piece.path
    resume = (path / "config.json").is_file()
    dagger(dagger_config_for(budget, piece.task, piece.seed), path, resume=resume, progress=False)
    return "resumed after its last finished iteration" if resume else ""


_RUNNERS: dict[str, Callable[[Piece, Budget, Path], str]] = {
    "dataset": _run_dataset, "pretrain-policy": _run_pretrain, "pretrain-value": _run_pretrain,
    "a3c": _run_a3c, "dagger": _run_dagger}


# ------------------------------------------------------------------------------ plan and status
def _now() -> str:
    return _dt.datetime.now().astimezone().isoformat(timespec="seconds")


def load_plan(out_dir: str | Path) -> tuple[Budget, list[Piece]]:
    """The budget and pieces of a reproduction directory (its ``plan.json``)."""
    path = Path(out_dir) / PLAN
    stored = _read_json(path)
    if stored is None:
        raise ValueError(f"{out_dir} is not a reproduction directory (no readable {PLAN}); "
                         f"start one with: bimgame reproduce --out {out_dir}")
    if stored.get("format") != _PLAN_FORMAT:
        raise ValueError(f"{path} is not a bimgame reproduction plan (format {stored.get('format')!r}, "
                         f"expected {_PLAN_FORMAT!r})")
    budget = Budget.from_dict(stored["budget"])
    fields = {f.name for f in dataclasses.fields(Piece)}
    pieces = [Piece(**{**{k: v for k, v in p.items() if k in fields}, "needs": tuple(p["needs"])})
              for p in stored["pieces"]]
    return budget, pieces


def load_status(out_dir: str | Path) -> dict[str, Any]:
    """``status.json`` of a reproduction directory (an empty status when there is none)."""
    stored = _read_json(Path(out_dir) / STATUS)
    return stored if stored is not None else {"pieces": {}, "invocations": []}


def check_compatible(out_dir: str | Path, budget: Budget) -> None:
    """Refuse (ValueError naming the differences) to continue a reproduction directory with settings
    that change what its pieces compute; only :data:`GRID_FIELDS` may differ."""
    out_dir = Path(out_dir)
    if not (out_dir / PLAN).exists():
        return
    stored, _ = load_plan(out_dir)
    old, new = stored.to_dict(), budget.to_dict()
    for values in (old, new):  # a pixel-only setting changes nothing with state observations
        if values["obs"] != "pixels":
            values["subtract_background"] = False
    changed = [k for k in new if k not in GRID_FIELDS and k != "name" and old.get(k) != new[k]]
    if changed:
        details = "; ".join(f"{k}: {old.get(k)!r} there, {new[k]!r} now" for k in changed)
        raise ValueError(f"{out_dir} holds a reproduction with other settings ({details}). Continue it with its "
                         f"own budget ('{stored.name}', or no --budget), change only {', '.join(GRID_FIELDS)}, "
                         f"or use another --out")


def write_plan(out_dir: str | Path, budget: Budget, costs: CostModel = COSTS) -> list[Piece]:
    """Write ``plan.json`` (atomically): the budget, every piece with its cost estimate; returns the pieces."""
    import bimgame

    out_dir = Path(out_dir)
    pieces = plan_pieces(budget)

    write_json(out_dir / PLAN, {
        "format": _PLAN_FORMAT, "bimgame_version": bimgame.__version__, "written": _now(),
        "budget": budget.to_dict(),
        "pieces": [{**p.to_dict(), "estimate_seconds": round(estimate_seconds(p, budget, costs), 1)} for p in pieces],
        "estimate_seconds": round(sum(estimate_seconds(p, budget, costs) for p in pieces), 1)})
    return pieces


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM (batch schedulers, ``kill``) stops the reproduction like Ctrl-C: the piece running is
    marked interrupted and resumes next time. Only possible on the main thread."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _exclusive(out_dir: Path):
    """One reproduction process per directory at a time."""
    return exclusive_lock(out_dir / _LOCK, f"another bimgame reproduce is running in {out_dir}; wait for it or stop it")


# ------------------------------------------------------------------------------------ the runner
@dataclasses.dataclass
class ReproductionResult:
    out_dir: Path
    computed: list[str]
    """Pieces computed (or finished) by this call."""
    reused: list[str]
    """Pieces found finished and skipped."""
    failed: dict[str, str]
    """Pieces that raised, with the error."""
    skipped: list[str]
    """Pieces not run because a piece they need failed."""
    remaining: list[str]
    """Pieces not run because ``stop_after`` was reached."""
    seconds: float

    @property
    def complete(self) -> bool:
        return not (self.failed or self.skipped or self.remaining)


def reproduce(out_dir: str | Path, budget: Budget, *, progress: bool = True, stop_after: int | None = None,
              console: Any = None, costs: CostModel = COSTS) -> ReproductionResult:
    """Run (or continue) the reproduction of ``budget`` in ``out_dir``.

    Writes ``plan.json``, then runs every unfinished piece in order, rewriting ``status.json`` after
    each. A failing piece is recorded and the pieces that do not need it still run. Ctrl-C stops
    cleanly (the piece running is marked interrupted and resumes next time) and re-raises
    ``KeyboardInterrupt``.

    Args:
        stop_after: compute at most this many pieces in this call, then return (finished pieces do
            not count); run again to continue.
        progress: one overall rich progress bar over the pieces (each piece's own bars stay off).
        console: a ``rich.console.Console`` for the messages (default: stderr).
    Returns:
        What was computed, reused, failed or left; the report is built by :mod:`bimgame.experiments.report`.
    """
    from rich.console import Console

    if stop_after is not None and not (isinstance(stop_after, int) and stop_after >= 1):
        raise ValueError(f"stop_after must be None or an integer >= 1, got {stop_after!r}")
    if not isinstance(budget, Budget):
        raise TypeError(f"budget must be a Budget, got {type(budget).__name__}")
    # Absolute, so the paths the runs record in their config.json (init, value reward) hold from anywhere.
    out_dir = Path(out_dir).resolve()
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"--out {out_dir} exists and is not a directory")
    out_dir.mkdir(parents=True, exist_ok=True)
    console = console or Console(stderr=True)
    with _exclusive(out_dir), _sigterm_as_interrupt():
        check_compatible(out_dir, budget)
        pieces = write_plan(out_dir, budget, costs)
        status = load_status(out_dir)
        entries: dict[str, dict[str, Any]] = status.setdefault("pieces", {})
        invocation = {"started": _now(), "budget": budget.name}
        status.setdefault("invocations", []).append(invocation)
        result = ReproductionResult(out_dir, [], [], {}, [], [], 0.0)
        started = time.monotonic()

        def save() -> None:
            status["updated"] = _now()
            write_json(out_dir / STATUS, status)

        done = {p.id for p in pieces if piece_done(p, out_dir, budget)}
        for piece in pieces:
            entry = entries.setdefault(piece.id, {"computed": 0})
            entry.update(kind=piece.kind, path=piece.path)
            if piece.id in done:
                entry["state"] = "done"
                result.reused.append(piece.id)
            else:
                if entry.get("state") == "done":  # its outputs are gone: it starts over
                    entry["seconds"] = 0.0
                entry["state"] = "pending"
        save()
        todo = [p for p in pieces if p.id not in done]
        shown = todo if stop_after is None else todo[:stop_after]
        with _Display(progress, console, shown, budget, costs) as display:
            for piece in todo:
                entry = entries[piece.id]
                blocked = [n for n in piece.needs if n in result.failed or n in result.skipped]
                if blocked:
                    entry.update(state="skipped", error=f"needs {', '.join(blocked)}, which did not finish")
                    result.skipped.append(piece.id)
                    save()
                    continue
                if stop_after is not None and len(result.computed) + len(result.failed) >= stop_after:
                    result.remaining.append(piece.id)
                    continue
                entry.update(state="running", started=_now())
                entry.pop("error", None)
                save()
                display.start(piece)
                t0 = time.monotonic()
                try:
                    with library_threads(budget.torch_threads):
                        note = _RUNNERS[piece.kind](piece, budget, out_dir)
                except KeyboardInterrupt:
                    entry.update(state="interrupted", seconds=entry.get("seconds", 0.0) + time.monotonic() - t0)
                    save()
                    raise
                except Exception as error:  # recorded; independent pieces still run
                    entry.update(state="failed", error=f"{type(error).__name__}: {error}",
                                 traceback=traceback.format_exc(), finished=_now(),
                                 seconds=entry.get("seconds", 0.0) + time.monotonic() - t0)
                    result.failed[piece.id] = entry["error"]
                    save()
                    display.finish(piece, f"[red]failed[/red]: {_escape(entry['error'])}")
                    continue
                seconds = time.monotonic() - t0
                # Wall time includes earlier interrupted or failed attempts of the same piece.
                entry.update(state="done", finished=_now(), computed=entry.get("computed", 0) + 1,
                             seconds=entry.get("seconds", 0.0) + seconds)
                entry.pop("traceback", None)
                if note:
                    entry["note"] = note
                result.computed.append(piece.id)
                save()
                display.finish(piece, f"done in {format_duration(seconds)}" + (f" ({_escape(note)})" if note else ""))
        result.seconds = time.monotonic() - started
        invocation.update(finished=_now(), seconds=round(result.seconds, 1), computed=len(result.computed),
                          reused=len(result.reused), failed=len(result.failed))
        save()
    return result


def _escape(text: str) -> str:
    """Text shown literally by rich (an error message may contain ``[...]``)."""
    from rich.markup import escape

    return escape(text)


class _Display:
    """One rich progress bar over the pieces, weighted by their estimated cost, with a line per
    finished piece; plain lines when the bar is off."""

    def __init__(self, enabled: bool, console: Any, todo: list[Piece], budget: Budget, costs: CostModel):
        self.enabled, self.console = enabled, console
        self.budget, self.costs = budget, costs
        self.estimates = {p.id: estimate_seconds(p, budget, costs) for p in todo}
        self.count = len(todo)
        self.finished = 0

    def __enter__(self) -> _Display:
        if self.enabled:
            from rich.progress import (BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn)

            self.bar = Progress(TextColumn("reproduce"), BarColumn(), TextColumn("{task.fields[pieces]}"),
                                TimeElapsedColumn(), TextColumn("left ≈"), TimeRemainingColumn(),
                                TextColumn("{task.description}"), console=self.console, transient=False)
            self.bar.__enter__()
            self.task = self.bar.add_task("", total=max(sum(self.estimates.values()), 1.0),
                                          pieces=f"0/{self.count} pieces")
        return self

    def start(self, piece: Piece) -> None:
        estimate = self.estimates.get(piece.id) or estimate_seconds(piece, self.budget, self.costs)
        text = f"{piece.id} (≈ {format_duration(estimate)})"
        if self.enabled:
            self.bar.update(self.task, description=text)
        else:
            self.console.print(f"running {_escape(text)}")

    def finish(self, piece: Piece, message: str) -> None:
        """``message`` is rich markup (escape any text in it)."""
        self.finished += 1
        line = f"{_escape(f'[{self.finished}/{self.count}] {piece.id}')}: {message}"
        if self.enabled:
            self.bar.console.print(line)
            self.bar.update(self.task, advance=self.estimates.get(piece.id, 0.0),
                            pieces=f"{self.finished}/{self.count} pieces")
        else:
            self.console.print(line)

    def __exit__(self, *exc: Any) -> None:
        if self.enabled:
            self.bar.update(self.task, description="")
            self.bar.__exit__(*exc)
