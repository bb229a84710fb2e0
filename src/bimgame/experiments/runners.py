"""Running one piece of a reproduction: the settings each piece passes to the library
(:func:`pretrain_config_for`, :func:`a3c_config_for`, :func:`dagger_config_for`, all derived from
the budget and the algorithm's record) and one function per kind of work (:func:`run_dataset`,
:func:`run_pretrain`, :func:`run_a3c`, :func:`run_dagger`) that computes — or continues — a piece
in its directory and returns a note for ``status.json`` ("resumed from its checkpoint", …). Which
piece runs which function is :mod:`bimgame.experiments.kinds`.

A runner raises ``KeyboardInterrupt`` when the piece stopped before it finished (Ctrl-C, SIGTERM),
so that :func:`bimgame.experiments.reproduce.reproduce` marks it interrupted; any other error marks
it failed.

**Threads.** Pre-training and DAgger run in this process; the budget's ``torch_threads`` (default
1: more intra-op threads slowed small networks down on a busy machine, see ``docs/budgets.md``)
sets their torch threads (:func:`bimgame.learn.runs.torch_threads`); A3C workers always use one
thread each.
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

from bimgame.experiments.algorithms import A3C, algorithm_named
from bimgame.experiments.budgets import Budget
from bimgame.experiments.grid import Piece, policy_path, value_path
from bimgame.experiments.methods import finetune_overrides
from bimgame.expert.datasets import generate_dataset
from bimgame.learn.a3c import A3CConfig, train
from bimgame.learn.dagger import DAggerConfig, dagger
from bimgame.learn.finetune import FINETUNE_FIELDS
from bimgame.learn.pretrain import pretrain
from bimgame.learn.rewards import RewardSettings, env_wrapper_for
from bimgame.learn.runs import CONFIG, KIND_POLICY, KIND_VALUE, write_run_json
from bimgame.learn.supervised import PretrainConfig
from bimgame.util.files import read_json

__all__ = ["pretrain_config_for", "a3c_config_for", "dagger_config_for", "run_dataset", "run_pretrain", "run_a3c",
           "run_dagger"]


def pretrain_config_for(budget: Budget, task: str, seed: int, target: str) -> PretrainConfig:
    """The pre-training settings of π^s (``target="policy"``) or V̂ (``"value"``) for a task and seed."""
    common = dict(task=task, obs=budget.obs, seed=seed, hidden=budget.hidden, features=budget.features,
                  subtract_background=budget.network_subtract_background, precision=budget.precision)
    if target == "policy":
        return PretrainConfig(target="policy", epochs=budget.pretrain_epochs, patience=budget.pretrain_patience,
                              eval_episodes=budget.pretrain_eval_episodes, aux_heads=budget.aux_heads,
                              asymmetric_critic=budget.asymmetric_critic, **common)
    if target == "value":
        return PretrainConfig(target="value", epochs=budget.value_epochs, patience=budget.value_patience,
                              batch_frames=budget.value_batch_frames, eval_episodes=0, **common)
    raise ValueError(f"unknown pre-training target {target!r}; allowed: policy, value")


def a3c_config_for(budget: Budget, task: str, seed: int, algorithm: str = A3C.name,
                   data_dir: str | Path | None = None) -> A3CConfig:
    """The A3C settings of ``algorithm``'s run for a task and seed: the budget's, with the
    algorithm's fine-tuning settings (:func:`~bimgame.experiments.methods.finetune_overrides`;
    ``data_dir``, the reproduction's expert dataset, for the algorithms that read it). The paper's
    algorithms differ in the initial weights and the reward, not in these."""
    steps = budget.steps_for(task)
    overrides = finetune_overrides(algorithm, steps, None if data_dir is None else str(data_dir))
    settings = dict(task=task, obs=budget.obs, steps=steps, workers=budget.workers,
                    envs_per_worker=budget.envs_per_worker, seed=seed, hidden=budget.hidden, features=budget.features,
                    subtract_background=budget.network_subtract_background, precision=budget.precision,
                    aux_heads=budget.aux_heads, asymmetric_critic=budget.asymmetric_critic,
                    augment_shift=budget.augment_shift, eval_every=budget.eval_every,
                    eval_episodes=budget.eval_episodes, checkpoint_every=budget.checkpoint_every)
    return A3CConfig(**{**settings, **overrides})


def dagger_config_for(budget: Budget, task: str, seed: int) -> DAggerConfig:
    """DAgger's settings for a task and seed (the learner is the same network as A3C's)."""
    learner = PretrainConfig(task=task, obs=budget.obs, seed=seed, hidden=budget.hidden, features=budget.features,
                             subtract_background=budget.network_subtract_background, precision=budget.precision,
                             aux_heads=False, asymmetric_critic=False, eval_episodes=0)
    return DAggerConfig(learner=learner, iterations=budget.dagger_iterations,
                        episodes_per_iteration=budget.dagger_episodes, epochs_per_iteration=budget.dagger_epochs,
                        eval_episodes=budget.dagger_eval_episodes)


def run_dataset(piece: Piece, budget: Budget, out_dir: Path) -> str:
    """Generate (or complete) the expert dataset."""
    generate_dataset(out_dir / piece.path, task=budget.dataset_task, episodes=budget.dataset_episodes,
                     seed=budget.dataset_seed, workers=budget.dataset_workers, progress=False,
                     max_steps=budget.dataset_max_steps)
    return ""


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
            raise ValueError(f"{path} holds something other than an unfinished {expected} run; move it away "
                             f"and run again")
        shutil.rmtree(path)
        note = "restarted an unfinished pre-training"
    pretrain(pretrain_config_for(budget, piece.task, piece.seed, target), out_dir / "data", path, progress=False)
    return note


def run_a3c(piece: Piece, budget: Budget, out_dir: Path) -> str:
    """Train (or continue) an A3C run of the piece's algorithm, from π^s and on V̂'s reward when its
    record says so."""
    path = out_dir / piece.path
    algorithm = algorithm_named(piece.algorithm)
    config = a3c_config_for(budget, piece.task, piece.seed, piece.algorithm, (out_dir / "data").resolve())
    init = (out_dir / policy_path(piece.task, piece.seed)).resolve() if algorithm.starts_from_policy else None
    value = (out_dir / value_path(piece.task, piece.seed)).resolve() if algorithm.value_reward else None
    reward = RewardSettings(value_reward=None if value is None else str(value))
    wrapper = env_wrapper_for(reward, obs=config.obs, gamma=config.gamma)
    resume = (path / CONFIG).is_file()
    if resume:
        stored = read_json(path / CONFIG) or {}
        if isinstance(stored.get("a3c"), dict):
            config = _with_stored_preset_name(stored["a3c"], config)
            _point_at_the_dataset_now(path, stored, config)
    extra = {"reward": reward.to_dict(),
             "reproduction": {"algorithm": piece.algorithm, "task": piece.task, "seed": piece.seed}}
    result = train(config, path, resume=resume, init=init, env_wrapper=wrapper, progress=False, extra_config=extra)
    if result.stopped != "finished":
        raise KeyboardInterrupt
    return "resumed from its checkpoint" if resume else ""


def _with_stored_preset_name(previous: dict, config: A3CConfig) -> A3CConfig:
    """``config`` with the fine-tuning preset name of the unfinished run whose stored A3C settings are
    ``previous`` when only the name differs: a ``pretrain+a3c`` run started before it recorded
    ``finetune="paper"`` (None then) has the same settings and resumes as it was started."""
    if previous.get("finetune") == config.finetune:
        return config
    same = all(previous.get(field, getattr(A3CConfig, field)) == getattr(config, field) for field in FINETUNE_FIELDS)
    return dataclasses.replace(config, finetune=previous.get("finetune")) if same else config


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


def run_dagger(piece: Piece, budget: Budget, out_dir: Path) -> str:
    """Run (or continue after its last finished iteration) a DAgger run."""
    path = out_dir / piece.path
    resume = (path / CONFIG).is_file()
    dagger(dagger_config_for(budget, piece.task, piece.seed), path, resume=resume, progress=False)
    return "resumed after its last finished iteration" if resume else ""
