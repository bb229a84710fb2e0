"""Running one piece of a reproduction: the settings each piece passes to the library
(:func:`pretrain_config_for`, :func:`a3c_config_for`, :func:`ppo_config_for`, :func:`dagger_config_for`,
all derived from the budget and the algorithm's record) and one function per kind of work
(:func:`run_dataset`, :func:`run_pretrain`, :func:`run_a3c`, :func:`run_ppo`, :func:`run_dagger`)
that computes — or continues — a piece in its directory and returns a note for ``status.json``
("resumed from its checkpoint", …). Which piece runs which function is :mod:`bimgame.experiments.kinds`.

A runner raises ``KeyboardInterrupt`` when the piece stopped before it finished (Ctrl-C, SIGTERM),
so that :func:`bimgame.experiments.reproduce.reproduce` marks it interrupted; any other error marks
it failed.

**Threads.** Pre-training and DAgger run in this process; the budget's ``torch_threads`` (default
1: more intra-op threads slowed small networks down on a busy machine, see ``docs/budgets.md``)
sets their torch threads (:func:`bimgame.learn.runs.torch_threads`), and those of PPO's runs, which
step their environments and update in this process; A3C workers always use one thread each.
"""

from __future__ import annotations

import shutil
from dataclasses import asdict
from pathlib import Path
from typing import Any

from bimgame.experiments.algorithms import A3C, algorithm_named
from bimgame.experiments.budgets import Budget
from bimgame.experiments.grid import Piece, policy_path, value_path
from bimgame.experiments.methods import finetune_overrides, ppo_overrides
from bimgame.expert.datasets import generate_dataset
from bimgame.learn.a3c import A3CConfig, train
from bimgame.learn.dagger import DAggerConfig, dagger
from bimgame.learn.learner_settings import FINETUNE_FIELDS
from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.learn.pretrain import pretrain
from bimgame.learn.rewards import RewardSettings, env_wrapper_for
from bimgame.learn.runs import CONFIG, KIND_POLICY, KIND_VALUE, write_run_json
from bimgame.learn.supervised import PretrainConfig
from bimgame.util.files import read_json

__all__ = [
    "pretrain_config_for",
    "a3c_config_for",
    "ppo_config_for",
    "dagger_config_for",
    "run_dataset",
    "run_pretrain",
    "run_a3c",
    "run_ppo",
    "run_dagger",
]


#: The network settings that need the simulator's state while learning: V̂ and DAgger's learner have none.
_PRIVILEGED = ("aux_heads", "asymmetric_critic")


def _network(budget: Budget, *, privileged: bool) -> dict[str, Any]:
    """The network settings of the budget's pieces (:class:`~bimgame.learn.common.NetworkSettings`'s
    names); without the privileged ones (``aux_heads``, ``asymmetric_critic``) unless ``privileged``."""
    settings = {"obs": budget.obs, **budget.network.settings_for(budget.obs)}
    return settings if privileged else {k: v for k, v in settings.items() if k not in _PRIVILEGED}


def pretrain_config_for(budget: Budget, task: str, seed: int, target: str) -> PretrainConfig:
    """The pre-training settings of π^s (``target="policy"``) or V̂ (``"value"``) for a task and seed:
    the budget's networks with its ``pretrain`` or ``value`` group. V̂ is not measured as a policy and
    has no asymmetric critic; its auxiliary heads are the networks' default for the observations."""
    if target == "policy":
        return PretrainConfig(
            target="policy", task=task, seed=seed, **_network(budget, privileged=True), **asdict(budget.pretrain)
        )
    if target == "value":
        return PretrainConfig(
            target="value",
            task=task,
            seed=seed,
            eval_episodes=0,
            **_network(budget, privileged=False),
            **asdict(budget.value),
        )
    raise ValueError(f"unknown pre-training target {target!r}; allowed: policy, value")


def a3c_config_for(
    budget: Budget, task: str, seed: int, algorithm: str = A3C.name, data_dir: str | Path | None = None
) -> A3CConfig:
    """The A3C settings of ``algorithm``'s run for a task and seed: the budget's networks and ``a3c``
    group (its steps for ``task``), with the algorithm's fine-tuning settings
    (:func:`~bimgame.experiments.methods.finetune_overrides`; ``data_dir``, the reproduction's expert
    dataset, for the algorithms that read it). The paper's algorithms differ in the initial weights
    and the reward, not in these."""
    steps = budget.steps_for(task)
    overrides = finetune_overrides(algorithm, steps, None if data_dir is None else str(data_dir))
    run = {**asdict(budget.a3c), "steps": steps}
    settings = {"task": task, "seed": seed, **_network(budget, privileged=True), **run}
    return A3CConfig.from_flat({**settings, **overrides})


#: The ``a3c`` group's settings that every run trained by steps takes, PPO's too: one budget of
#: evaluations and checkpoints for every method compared (its ``steps`` are :meth:`Budget.steps_for`).
_SHARED_SCHEDULE = ("eval_every", "eval_episodes", "checkpoint_every")


def ppo_config_for(
    budget: Budget, task: str, seed: int, algorithm: str = "ppo", data_dir: str | Path | None = None
) -> PPOConfig:
    """The PPO settings of ``algorithm``'s run for a task and seed: the budget's networks (the same as
    A3C's and π^s's, so that a run can start from π^s), its ``ppo`` group, A3C's steps for ``task``
    and A3C's evaluations and checkpoints (the same budget as A3C's runs), with the algorithm's own
    settings (:func:`~bimgame.experiments.methods.ppo_overrides`)."""
    steps = budget.steps_for(task)
    overrides = ppo_overrides(algorithm, steps, None if data_dir is None else str(data_dir))
    schedule = {name: getattr(budget.a3c, name) for name in _SHARED_SCHEDULE}
    run = {**asdict(budget.ppo), **schedule, "steps": steps}
    settings = {"task": task, "seed": seed, **_network(budget, privileged=True), **run}
    return PPOConfig.from_flat({**settings, **overrides})


def dagger_config_for(budget: Budget, task: str, seed: int) -> DAggerConfig:
    """DAgger's settings for a task and seed: the budget's ``dagger`` group, and as the learner the
    same network as A3C's without the privileged inputs (its own rollouts record no simulator states)."""
    learner = PretrainConfig(
        task=task,
        seed=seed,
        aux_heads=False,
        asymmetric_critic=False,
        eval_episodes=0,
        **_network(budget, privileged=False),
    )
    group = budget.dagger
    return DAggerConfig(
        learner=learner,
        iterations=group.iterations,
        episodes_per_iteration=group.episodes,
        epochs_per_iteration=group.epochs,
        eval_episodes=group.eval_episodes,
    )


def run_dataset(piece: Piece, budget: Budget, out_dir: Path) -> str:
    """Generate (or complete) the expert dataset of the budget's ``dataset`` group."""
    generate_dataset(out_dir / piece.path, progress=False, **asdict(budget.dataset))
    return ""


def _task_and_seed(piece: Piece) -> tuple[str, int]:
    """The task and seed of a piece trained for one of them (every such piece of a plan has both)."""
    if piece.task is None or piece.seed is None:
        raise ValueError(f"piece {piece.id!r} has no task or no seed")
    return piece.task, piece.seed


def run_pretrain(piece: Piece, budget: Budget, out_dir: Path, target: str) -> str:
    """Pre-train π^s (``target="policy"``) or V̂ (``"value"``); an unfinished one starts again."""
    path = out_dir / piece.path
    note = ""
    stored = read_json(path / CONFIG)
    if stored is not None or (path / "checkpoint.pt").exists():
        # Started but unfinished (pre-training cannot resume): start it again. Only our own kind of
        # run directory is removed.
        expected = KIND_POLICY if target == "policy" else KIND_VALUE
        if stored is None or stored.get("kind") != expected:
            raise ValueError(
                f"{path} holds something other than an unfinished {expected} run; move it away and run again"
            )
        shutil.rmtree(path)
        note = "restarted an unfinished pre-training"
    task, seed = _task_and_seed(piece)
    pretrain(pretrain_config_for(budget, task, seed, target), out_dir / "data", path, progress=False)
    return note


def run_a3c(piece: Piece, budget: Budget, out_dir: Path) -> str:
    """Train (or continue) an A3C run of the piece's algorithm, from π^s and on V̂'s reward when its
    record says so."""
    path = out_dir / piece.path
    task, seed = _task_and_seed(piece)
    if piece.algorithm is None:
        raise ValueError(f"piece {piece.id!r} names no algorithm")
    algorithm = algorithm_named(piece.algorithm)
    config = a3c_config_for(budget, task, seed, piece.algorithm, (out_dir / "data").resolve())
    init = (out_dir / policy_path(task, seed)).resolve() if algorithm.starts_from_policy else None
    value = (out_dir / value_path(task, seed)).resolve() if algorithm.value_reward else None
    reward = RewardSettings(value_reward=None if value is None else str(value))
    wrapper = env_wrapper_for(reward, obs=config.network.obs, gamma=config.optimization.gamma)
    resume = (path / CONFIG).is_file()
    if resume:
        stored = read_json(path / CONFIG) or {}
        if isinstance(stored.get("a3c"), dict):
            config = _with_stored_preset_name(stored["a3c"], config)
            _point_at_the_dataset_now(path, stored, config)
    extra = {
        "reward": reward.to_dict(),
        "reproduction": {"algorithm": piece.algorithm, "task": piece.task, "seed": piece.seed},
    }
    result = train(config, path, resume=resume, init=init, env_wrapper=wrapper, progress=False, extra_config=extra)
    if result.stopped != "finished":
        raise KeyboardInterrupt
    return "resumed from its checkpoint" if resume else ""


def _with_stored_preset_name(previous: dict, config: A3CConfig) -> A3CConfig:
    """``config`` with the fine-tuning preset name of the unfinished run whose stored A3C settings are
    ``previous`` when only the name differs: a ``pretrain+a3c`` run started before it recorded
    ``finetune="paper"`` (None then) has the same settings and resumes as it was started."""
    flat, defaults = config.to_dict(), A3CConfig().to_dict()
    if previous.get("finetune") == flat["finetune"]:
        return config
    same = all(previous.get(field, defaults[field]) == flat[field] for field in FINETUNE_FIELDS)
    return config.with_flat(finetune=previous.get("finetune")) if same else config


def _point_at_the_dataset_now(path: Path, stored: dict, config: A3CConfig) -> None:
    """Record in the unfinished run in ``path`` (its ``config.json`` holds ``stored``) the place its
    reproduction's dataset is now.

    A reproduction's run reads the reproduction's own dataset piece (``DIR/data``, by absolute path
    in its ``config.json``); a resumed run must keep its settings. When DIR has moved since the run
    started — a Ray task continuing on another node a run shipped back from the node that died, or
    a person who moved the directory — the same dataset piece is elsewhere, so the run's record is
    pointed at it there (atomically), and it resumes instead of being refused."""
    settings = stored["a3c"]
    if config.expert_data is None:
        return
    before = settings.get("expert_data")
    if isinstance(before, str) and before != config.expert_data and Path(before).name == Path(config.expert_data).name:
        write_run_json(path / CONFIG, {**stored, "a3c": {**settings, "expert_data": config.expert_data}})


def run_ppo(piece: Piece, budget: Budget, out_dir: Path) -> str:
    """Train (or continue) a PPO run of the piece's algorithm, from π^s when its record says so (the
    π^s piece the A3C runs of its task and seed start from)."""
    path = out_dir / piece.path
    task, seed = _task_and_seed(piece)
    if piece.algorithm is None:
        raise ValueError(f"piece {piece.id!r} names no algorithm")
    algorithm = algorithm_named(piece.algorithm)
    config = ppo_config_for(budget, task, seed, piece.algorithm, (out_dir / "data").resolve())
    resume = (path / CONFIG).is_file()
    # A resumed run continues from its own checkpoint; only a new one starts from π^s.
    init = (out_dir / policy_path(task, seed)).resolve() if algorithm.starts_from_policy and not resume else None
    result = train_ppo(config, path, resume=resume, init=init, progress=False)
    if result.stopped != "finished":
        raise KeyboardInterrupt
    return "resumed from its checkpoint" if resume else ""


def run_dagger(piece: Piece, budget: Budget, out_dir: Path) -> str:
    """Run (or continue after its last finished iteration) a DAgger run."""
    path = out_dir / piece.path
    resume = (path / CONFIG).is_file()
    task, seed = _task_and_seed(piece)
    dagger(dagger_config_for(budget, task, seed), path, resume=resume, progress=False)
    return "resumed after its last finished iteration" if resume else ""
