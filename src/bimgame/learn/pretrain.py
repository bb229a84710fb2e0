"""Learning from the expert's trajectories: supervised pre-training of the actor-critic (π^s) and
the value-only network V̂ (README, "Learning from trajectories").

**π^s** (``target="policy"``): the A3C network itself is trained on whole expert episodes with the
paper's loss (:mod:`bimgame.learn.supervised`). Episodes are split into training and held-out sets;
the weights with the lowest held-out loss are kept (early stopping matters: on expert data the
network starts to overfit within tens of epochs).
The result is a run directory that ``bimgame train --init`` and ``bimgame evaluate`` accept.

**V̂** (``target="value"``): a feed-forward :class:`~bimgame.learn.nets.ValueNetwork` trained on the value
and L2 terms alone (frames shuffled, no sequences needed), then frozen and used by
:mod:`bimgame.learn.rewards` as the shaping potential.

**Other tasks.** A dataset is generated for one task (usually FULL); its episodes are relabelled
for an easier task from the marbles' recorded channels (:func:`bimgame.expert.episode.relabel`): an STG1 episode is the
FULL episode up to the step the marble passed the outermost wall, with STG1's reward. A harder task
than the dataset's cannot be labelled (its episodes stop too early) and is refused.

**Many mazes.** A dataset generated on random mazes (``bimgame generate --num-mazes N``) has state
observations that end with each episode's maze encoding, as the envs of a learner on those mazes
have: a state network pre-trained on it reads the encoding (``maze_encoding``, set from the dataset),
so π^s can start ``bimgame train --num-mazes N --init`` (a network of MERL's maze cannot: its input
is 7 values, the dataset's 135). The run records the dataset's ``num_mazes``/``start_maze`` in its
``config.json`` and π^s alone is evaluated on those mazes.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bimgame.envs.puzzles import PuzzleSpec, puzzle
from bimgame.expert.datasets import dataset_manifest, dataset_mazes
from bimgame.expert.episode import Episode
from bimgame.learn.checkpoints import load_weights, save_checkpoint
from bimgame.learn.evaluations import evaluate_greedy_and_sampled
from bimgame.learn.expert_data import check_dataset_task, dataset_action_type, load_sequences
from bimgame.learn.maze_runs import network_env_options
from bimgame.learn.metric_logs import MetricLog
from bimgame.learn.nets import RecurrentActorCritic, ValueNetwork
from bimgame.learn.run_dir import RunDirectory
from bimgame.learn.runs import CHECKPOINT, KIND_POLICY, KIND_VALUE, torch_threads
from bimgame.learn.supervised import PretrainConfig, l2_penalty, policy_batches, policy_epoch, split_episodes, summarise
from bimgame.sim.maze import MazeSpec
from bimgame.util.files import FileWriteError
from bimgame.util.progress import ProgressBar
from bimgame.util.signals import sigterm_as_interrupt

__all__ = [
    "PretrainResult",
    "pretrain",
    "load_sequences",
    "build_model",
    "evaluate_policy",
    "data_source",
    "settings_for_dataset",
    "check_dataset_task",
    "dataset_action_type",
]
_TABLE = [
    "train_loss",
    "train_accuracy",
    "train_value_rmse",
    "train_aux",
    "val_loss",
    "val_accuracy",
    "val_value_rmse",
    "val_aux",
    "seconds",
]


def _frames(sequences: list[Episode], indices: np.ndarray, max_tilt: float) -> dict[str, torch.Tensor]:
    """The frames of the episodes ``indices`` as flat tensors: observations, scaled tilts, returns."""
    return {
        "obs": torch.as_tensor(np.concatenate([sequences[i].obs for i in indices])),
        "tilt": torch.as_tensor(np.concatenate([sequences[i].tilt for i in indices]) / max_tilt),
        "returns": torch.as_tensor(np.concatenate([sequences[i].returns for i in indices])),
    }


def _value_epoch(
    net: ValueNetwork,
    frames: dict[str, torch.Tensor],
    config: PretrainConfig,
    rng: np.random.Generator,
    optimizer: torch.optim.Optimizer | None,
) -> dict[str, float]:
    """One pass of V̂'s loss (value and L2 terms) over ``frames``: training with ``optimizer`` on
    shuffled batches, else measuring only, in order."""
    n = len(frames["returns"])
    order = torch.as_tensor(rng.permutation(n) if optimizer is not None else np.arange(n))
    value_se = 0.0
    net.train(optimizer is not None)
    with torch.set_grad_enabled(optimizer is not None):
        for start in range(0, n, config.batch_frames):
            idx = order[start : start + config.batch_frames]
            values = net(frames["obs"][idx], frames["tilt"][idx] if net.config.tilt_input else None)
            se = (values - frames["returns"][idx]).pow(2)
            if optimizer is not None:
                loss = config.value_coef * 0.5 * se.mean() + config.l2 * l2_penalty(net)
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(net.parameters(), config.max_grad_norm)
                optimizer.step()
            value_se += float(se.detach().sum())
    return summarise(
        {"ce": 0.0, "value_se": value_se, "correct": 0.0, "count": float(n)}, config.value_coef, policy=False
    )


# ---------------------------------------------------------------------------------- training
@dataclasses.dataclass
class PretrainResult:
    """What pre-training produced: the run, its best epoch and held-out numbers, π^s as a policy."""

    run_dir: Path
    best_epoch: int
    epochs_run: int
    val_accuracy: float
    """Held-out action-prediction accuracy of the kept weights (NaN for a value network)."""
    val_value_rmse: float
    seconds: float
    policy_eval: dict[str, float] | None
    """π^s alone as a policy: greedy and sampled success rate and length (policy target only)."""
    data_source: str = "expert"
    """Where the dataset's episodes came from: ``expert`` (bimgame generate) or ``human`` (bimgame play)."""
    mazes: dict[str, int] = dataclasses.field(default_factory=dict)
    """The dataset's mazes as learner settings (``num_mazes``, ``start_maze``; empty for MERL's maze):
    what ``bimgame train --init`` with this π^s trains on."""


def build_model(config: PretrainConfig, maze: PuzzleSpec | None = None) -> RecurrentActorCritic | ValueNetwork:
    """The untrained network of ``config.target``, shaped as A3C's for the same observations."""
    if config.target == "policy":
        return config.build_policy(config.seed, maze)
    return config.build_value(config.seed, maze)


def pretrain(
    config: PretrainConfig,
    data_dir: str | Path,
    out_dir: str | Path,
    *,
    progress: bool = True,
    sequences: list[Episode] | None = None,
) -> PretrainResult:
    """Train π^s or V̂ on the dataset in ``data_dir``; everything is written to ``out_dir``:
    ``config.json``, ``checkpoint.pt`` (the best held-out weights), ``pretrain.csv`` and TensorBoard
    scalars per epoch, ``summary.json``. ``sequences`` (already loaded with
    :func:`load_sequences`) skips reading the dataset.

    ``out_dir`` must be new or empty; it is locked while pre-training writes it
    (:class:`~bimgame.learn.run_dir.RunDirectory`). Pre-training cannot resume: if it stops before
    its summary is written (an error, Ctrl-C, SIGTERM, a full disk), it removes what it wrote, so the
    same call can be repeated."""
    kind = KIND_POLICY if config.target == "policy" else KIND_VALUE
    with RunDirectory(out_dir, kind) as run, torch_threads():
        try:
            with sigterm_as_interrupt():
                return _pretrain(config, data_dir, run, progress=progress, sequences=sequences)
        except FileWriteError as error:
            raise error.with_advice(
                f"Pre-training cannot resume, so its files are removed from {run.path}: free "
                f"some space and run the same command again"
            ) from error


def _pretrain(
    config: PretrainConfig, data_dir: str | Path, run: RunDirectory, *, progress: bool, sequences: list[Episode] | None
) -> PretrainResult:
    """:func:`pretrain` in the run directory ``run``, already held: read the data, write the settings,
    train with early stopping, keep the best held-out weights, evaluate π^s, write the summary."""
    manifest = dataset_manifest(data_dir)
    check_dataset_task(manifest, config.task, data_dir)
    if dataset_action_type(manifest) != config.action_type:
        raise ValueError(
            f"PretrainConfig.action_type {config.action_type!r}: the dataset in {data_dir} holds "
            f"{dataset_action_type(manifest)} actions; set action_type={dataset_action_type(manifest)!r}"
        )
    maze = puzzle(config.task).spec
    if config.target == "value" and not isinstance(maze, MazeSpec):
        raise ValueError("PretrainConfig.target 'value': V̂ shapes the circular maze's rewards only; use 'policy'")
    mazes = dataset_mazes(data_dir)
    config = settings_for_dataset(config, mazes, data_dir)
    if sequences is None:
        sequences = load_sequences(
            data_dir,
            config.task,
            config.obs,
            config.gamma,
            progress=progress,
            gate_bearings=config.gate_bearings,
            surroundings=config.surroundings,
            motion=config.motion,
        )
    rng = np.random.default_rng(config.seed)
    train_idx, val_idx = split_episodes(len(sequences), config.val_fraction, rng)
    net = build_model(config, maze)
    kind = run.layout.kind
    run.write_config(
        {
            "task": config.task,
            "seed": config.seed,
            "network": config.network_settings().to_dict(),
            "net": net.config.to_dict(),
            "pretrain": config.to_dict(),
            "data": str(data_dir),
            "episodes": {"train": len(train_idx), "held_out": len(val_idx)},
            "torch_threads": torch.get_num_threads(),
            **mazes,
        }
    )
    optimizer = torch.optim.Adam(net.parameters(), lr=config.lr)
    split = _Split(sequences, train_idx, val_idx, maze.max_tilt)
    if isinstance(net, ValueNetwork):
        run_epoch = _value_epochs(net, split, config, rng, optimizer)
    else:
        run_epoch = _policy_epochs(net, split, config, rng, optimizer)
    log = run.metric_log({"pretrain": _TABLE})
    started = time.monotonic()
    _log_initial(log, run_epoch(False))
    try:
        best, epochs_run = _train_epochs(config, run, net, run_epoch, log, started, progress=progress)
    finally:
        log.close()
    if best["epoch"] == 0:
        save_checkpoint(run / CHECKPOINT, model=net.state_dict(), step=0, epoch=0, kind=kind)
    load_weights(net, run / CHECKPOINT)
    policy_eval = None
    if isinstance(net, RecurrentActorCritic) and config.eval_episodes > 0:
        policy_eval = evaluate_policy(net, config, mazes=mazes)
    result = PretrainResult(
        run.path,
        best["epoch"],
        epochs_run,
        best["accuracy"],
        best["value_rmse"],
        time.monotonic() - started,
        policy_eval,
        data_source(data_dir),
        mazes,
    )
    _write_summary(run, result, episodes={"train": len(train_idx), "held_out": len(val_idx)})
    return result


@dataclasses.dataclass(frozen=True)
class _Split:
    """The episodes, split into those trained on and those held out, and the maze's largest tilt."""

    sequences: list[Episode]
    train_idx: np.ndarray
    val_idx: np.ndarray
    max_tilt: float


#: One epoch: training (``True``) or measuring on the held-out episodes (``False``); returns its summary.
EpochRunner = Callable[[bool], dict[str, float]]


def _value_epochs(
    net: ValueNetwork, split: _Split, config: PretrainConfig, rng: np.random.Generator, optimizer: torch.optim.Optimizer
) -> EpochRunner:
    """The epochs of V̂: shuffled frames of the training episodes, or all held-out frames."""
    train_frames = _frames(split.sequences, split.train_idx, split.max_tilt)
    val_frames = _frames(split.sequences, split.val_idx, split.max_tilt)

    def run_epoch(training: bool) -> dict[str, float]:
        return _value_epoch(net, train_frames if training else val_frames, config, rng, optimizer if training else None)

    return run_epoch


def _policy_epochs(
    net: RecurrentActorCritic,
    split: _Split,
    config: PretrainConfig,
    rng: np.random.Generator,
    optimizer: torch.optim.Optimizer,
) -> EpochRunner:
    """The epochs of π^s: the training episodes in a new order each time, or the held-out ones."""
    held_out = list(policy_batches(split.sequences, split.val_idx, config, split.max_tilt))  # the same every epoch

    def run_epoch(training: bool) -> dict[str, float]:
        if training:
            order = rng.permutation(split.train_idx)
            return policy_epoch(net, policy_batches(split.sequences, order, config, split.max_tilt), config, optimizer)
        return policy_epoch(net, held_out, config, None)

    return run_epoch


def _log_initial(log: MetricLog, initial: dict[str, float]) -> None:
    """Log the untrained network's held-out summary ``initial`` as epoch 0."""
    log.write(
        "pretrain",
        0,
        {
            "val_loss": initial["loss"],
            "val_accuracy": initial["accuracy"],
            "val_value_rmse": initial["value_rmse"],
            "val_aux": initial["aux"],
            "seconds": 0.0,
        },
        scalars=("val_loss", "val_accuracy", "val_value_rmse", "val_aux"),
    )


def _train_epochs(
    config: PretrainConfig,
    run: RunDirectory,
    net: RecurrentActorCritic | ValueNetwork,
    run_epoch: EpochRunner,
    log: MetricLog,
    started: float,
    *,
    progress: bool,
) -> tuple[dict[str, Any], int]:
    """Train up to ``config.epochs`` epochs, logging each and checkpointing every new best held-out
    loss; stop after ``config.patience`` epochs without one. Returns the best epoch's numbers and
    the epochs run."""
    best: dict[str, Any] = {"loss": math.inf, "epoch": 0, "accuracy": float("nan"), "value_rmse": float("nan")}
    epochs_run = 0
    with ProgressBar(f"pretrain {config.target} {config.task} {config.obs}", config.epochs, enabled=progress) as bar:
        for epoch in range(1, config.epochs + 1):
            train_summary = run_epoch(True)
            val = run_epoch(False)
            epochs_run = epoch
            if not math.isfinite(train_summary["loss"]):
                raise RuntimeError(
                    f"pre-training diverged at epoch {epoch} (training loss "
                    f"{train_summary['loss']}); lower --lr (now {config.lr})"
                )
            log.write(
                "pretrain", epoch, _epoch_row(train_summary, val, time.monotonic() - started), scalars=_TABLE[:-1]
            )
            if val["loss"] < best["loss"]:
                best = {
                    "loss": val["loss"],
                    "epoch": epoch,
                    "accuracy": val["accuracy"],
                    "value_rmse": val["value_rmse"],
                }
                save_checkpoint(run / CHECKPOINT, model=net.state_dict(), step=0, epoch=epoch, kind=run.layout.kind)
            accuracy = "" if math.isnan(val["accuracy"]) else f"held-out accuracy {val['accuracy']:.1%}  "
            bar.update(
                completed=epoch, info=f"{accuracy}value RMSE {val['value_rmse']:.3f}  best epoch {best['epoch']}"
            )
            if epoch - best["epoch"] >= config.patience:
                break
    return best, epochs_run


def _epoch_row(train: dict[str, float], val: dict[str, float], seconds: float) -> dict[str, float]:
    """An epoch's ``pretrain.csv`` row: its training and held-out summaries, ``seconds`` into the run."""
    return {
        "train_loss": train["loss"],
        "train_accuracy": train["accuracy"],
        "train_value_rmse": train["value_rmse"],
        "train_aux": train["aux"],
        "val_loss": val["loss"],
        "val_accuracy": val["accuracy"],
        "val_value_rmse": val["value_rmse"],
        "val_aux": val["aux"],
        "seconds": seconds,
    }


def _write_summary(run: RunDirectory, result: PretrainResult, *, episodes: dict[str, int]) -> None:
    """Write the run's ``summary.json``: how pre-training ended (``episodes``: trained on, held out)."""
    run.write_summary(
        {
            "kind": run.layout.kind,
            "data_source": result.data_source,
            "best_epoch": result.best_epoch,
            "epochs_run": result.epochs_run,
            "val_accuracy": result.val_accuracy,
            "val_value_rmse": result.val_value_rmse,
            "chance_accuracy": 0.2,
            "seconds": result.seconds,
            "policy_eval": result.policy_eval,
            "episodes": episodes,
        }
    )


def data_source(data_dir: str | Path) -> str:
    """Who made a dataset's episodes, from its manifest: ``expert`` (bimgame generate, which names
    none) or ``human`` (bimgame play --record); ``unknown`` if the manifest cannot be read."""
    try:
        return str(dataset_manifest(data_dir).get("source", "expert"))
    except (ValueError, OSError):
        return "unknown"


def evaluate_policy(
    net: RecurrentActorCritic, config: PretrainConfig, seed: int = 12345, *, mazes: dict[str, int] | None = None
) -> dict[str, float]:
    """π^s alone on its task: greedy and sampled success rate, length and return; on the mazes
    ``mazes`` (:func:`~bimgame.expert.datasets.dataset_mazes`: each episode's drawn from them) or,
    without, MERL's maze."""
    mazes = mazes or {}
    options = network_env_options(config, mazes.get("num_mazes"), mazes.get("start_maze", 0))
    return {
        "episodes": config.eval_episodes,
        **evaluate_greedy_and_sampled(
            net,
            task=config.task,
            obs=config.obs,
            episodes=config.eval_episodes,
            seed=seed,
            time_limit=config.time_limit,
            mazes=options or None,
        ),
    }


def settings_for_dataset(config: PretrainConfig, mazes: dict[str, int], data_dir: str | Path) -> PretrainConfig:
    """``config`` for a dataset on ``mazes`` (:func:`~bimgame.expert.datasets.dataset_mazes`): a
    state network reads the maze encoding its observations end with exactly when the dataset has
    mazes (set here, as a learner's ``num_mazes`` sets it); asking for the encoding on a dataset of
    MERL's maze is refused."""
    if config.obs != "state":
        return config  # pixels show the maze: the same network either way
    if mazes:
        return dataclasses.replace(config, maze_encoding=True)
    for name in ("maze_encoding", "gate_bearings"):
        if getattr(config, name):
            raise ValueError(
                f"PretrainConfig.{name}: the dataset in {data_dir} was generated on MERL's maze alone, its "
                "observations have no maze encoding; generate one with --num-mazes for a network that reads it"
            )
    return config
