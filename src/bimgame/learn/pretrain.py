"""Learning from the expert's trajectories: supervised pre-training of the actor-critic (π^s) and
the value-only network V̂ (the paper's §1 items 5 and 6).

**π^s** (``target="policy"``): the A3C network itself is trained on whole expert episodes with the
paper's loss, per step

    L = −log π(a*|s) + value_coef · ½ (V(s) − G)²        (+ l2 · ‖θ‖² per update)

where a* is the expert's action and G the discounted return-to-go. Episodes are fed as sequences,
from their first step, with the previous action and reward as inputs — exactly what the LSTM sees
in A3C — in chunks of ``bptt`` steps (the LSTM state carries over between the chunks of an episode,
the gradient does not: truncated backpropagation through time, as A3C's ``n_steps`` segments).
Episodes are split into training and held-out sets; the weights with the lowest held-out loss are
kept (early stopping matters: on expert data the network starts to overfit within tens of epochs).
The result is a run directory that ``bimgame train --init`` and ``bimgame evaluate`` accept.

**V̂** (``target="value"``): a feed-forward :class:`~bimgame.nets.ValueNetwork` trained on the value
and L2 terms alone (frames shuffled, no sequences needed), then frozen and used by
:mod:`bimgame.envs.shaping` as the shaping potential.

**Other tasks.** A dataset is generated for one task (usually FULL); its episodes are relabelled
for an easier task from the marbles' recorded channels (:func:`bimgame.expert.episode.relabel`): an STG1 episode is the
FULL episode up to the step the marble passed the outermost wall, with STG1's reward. A harder task
than the dataset's cannot be labelled (its episodes stop too early) and is refused.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import torch
import torch.nn.functional as F

from bimgame.learn.a3c import A3CConfig, evaluate_greedy_and_sampled, net_config_for, network_for
from bimgame.expert.datasets import dataset_manifest, iterate_sequences, load_dataset
from bimgame.expert.episode import Episode, relabel
from bimgame.sim.maze import MazeSpec
from bimgame.learn.nets import NO_ACTION, RecurrentActorCritic, ValueNetwork, build_value_network
from bimgame.envs.observe import OBS_MODES
from bimgame.learn.runs import (CHECKPOINT, CONFIG, KIND_POLICY, KIND_VALUE, MetricLog, load_weights, run_kind, save_checkpoint,
                          torch_threads, write_json)
from bimgame.util.settings import from_dict, require_int
from bimgame.sim.tasks import Task, parse_task

__all__ = ["PretrainConfig", "PretrainResult", "pretrain", "load_sequences", "load_value_network",
           "policy_loss_terms", "train_policy_epochs", "TARGETS", "KIND_POLICY", "KIND_VALUE", "run_kind"]

TARGETS = ("policy", "value")
_TABLE = ["train_loss", "train_accuracy", "train_value_rmse", "val_loss", "val_accuracy", "val_value_rmse",
          "seconds"]


@dataclasses.dataclass(frozen=True)
class PretrainConfig:
    """Settings of supervised pre-training."""

    task: str = "FULL"
    """Task whose rewards give the value targets (episodes are relabelled, see :func:`bimgame.expert.episode.relabel`)."""
    obs: str = "pixels"
    """``pixels`` (the paper's) or ``state``; the same network as A3C with these observations."""
    target: str = "policy"
    """``policy``: the actor-critic π^s; ``value``: the value-only network V̂."""
    epochs: int = 30
    """Upper bound on passes over the training episodes (early stopping usually ends sooner)."""
    patience: int = 5
    """Stop after this many epochs without a better held-out loss."""
    lr: float = 1e-3
    """Adam's learning rate."""
    l2: float = 1e-5
    """λ of the L2 penalty λ‖θ‖² on the weight matrices (biases and norms excluded)."""
    value_coef: float = 1.0
    """Weight of ½(V − G)² against the cross-entropy (the paper's loss: 1)."""
    gamma: float = 0.99
    """Discount of the return targets (A3C's γ)."""
    batch_episodes: int = 16
    """Policy: episodes per batch (sequences run side by side)."""
    batch_frames: int = 64
    """Value: frames per batch (256 underfit a 60-episode dataset: held-out RMSE 0.12 against 0.09)."""
    bptt: int = 50
    """Policy: steps per truncated-backpropagation chunk."""
    max_grad_norm: float = 1.0
    val_fraction: float = 0.2
    """Share of episodes held out for validation (at least one)."""
    seed: int = 0
    hidden: int | None = None
    features: int | None = None
    tilt_input: bool = True
    keypoints: bool = False
    subtract_background: bool = False
    eval_episodes: int = 50
    """Episodes to measure π^s alone as a policy after training (0: skip)."""

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "task", parse_task(self.task).value)
        except ValueError as error:
            raise ValueError(f"PretrainConfig.task: {error}") from None
        if self.obs not in OBS_MODES:
            raise ValueError(f"PretrainConfig.obs must be one of {OBS_MODES}, got {self.obs!r}")
        if self.target not in TARGETS:
            raise ValueError(f"PretrainConfig.target must be one of {TARGETS}, got {self.target!r}")
        for name in ("epochs", "patience", "batch_episodes", "batch_frames", "bptt"):
            require_int("PretrainConfig", name, getattr(self, name), 1)
        if not (isinstance(self.eval_episodes, int) and self.eval_episodes >= 0):
            raise ValueError(f"PretrainConfig.eval_episodes must be an integer >= 0, got {self.eval_episodes!r}")
        for name, low, high, open_low in (("lr", 0, math.inf, True), ("max_grad_norm", 0, math.inf, True),
                                          ("l2", 0, math.inf, False), ("value_coef", 0, math.inf, False),
                                          ("gamma", 0, 1, False), ("val_fraction", 0, 1, True)):
            value = getattr(self, name)
            ok = isinstance(value, (int, float)) and math.isfinite(value) and value <= high and (
                value > low if open_low else value >= low)
            if not ok or (name == "val_fraction" and value >= 1):
                bound = "(0, 1)" if name == "val_fraction" else (f"({low}, {high}]" if open_low else f"[{low}, {high}]")
                raise ValueError(f"PretrainConfig.{name} must be in {bound}, got {value!r}")
        self.a3c_config()  # validates the network settings

    def a3c_config(self) -> A3CConfig:
        """The A3C settings this network belongs to (its sizes and inputs)."""
        return A3CConfig(task=self.task, obs=self.obs, hidden=self.hidden, features=self.features,
                         tilt_input=self.tilt_input, keypoints=self.keypoints,
                         subtract_background=self.subtract_background, seed=self.seed, gamma=self.gamma)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> PretrainConfig:
        return from_dict(cls, values, "pre-training settings")


# ------------------------------------------------------------------------------------- data
def load_sequences(data_dir: str | Path, task: str | Task, obs: str, gamma: float,
                   spec: MazeSpec | None = None, *, progress: bool = False) -> list[Episode]:
    """Every episode of a dataset directory, relabelled for ``task`` (see
    :func:`~bimgame.expert.episode.relabel`)."""
    spec = spec or MazeSpec.merl()
    task = parse_task(task, spec)
    manifest = dataset_manifest(data_dir)
    data_task = parse_task(manifest["task"], spec)
    if task.walls_to_pass(spec) > data_task.walls_to_pass(spec):
        raise ValueError(f"the dataset in {data_dir} holds {data_task.value} episodes, which end before a "
                         f"{task.value} episode would; use a dataset of {task.value} or a harder task "
                         f"(FULL labels every task)")
    dataset = load_dataset(data_dir)
    episodes = iterate_sequences(dataset, obs=obs, gamma=gamma)
    if progress:
        episodes = _with_progress(episodes, dataset.total_episodes, f"reading {obs} episodes")
    return [relabel(sequence, task, gamma, spec) for sequence in episodes]


def _with_progress(items: Iterator, total: int, label: str) -> Iterator:
    from rich.progress import track

    return track(items, total=total, description=label, transient=True)


def split_episodes(count: int, val_fraction: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(training, held-out) episode indices: a seeded shuffle, at least one episode in each."""
    if count < 2:
        raise ValueError(f"pre-training needs at least 2 episodes (one held out), got {count}")
    order = rng.permutation(count)
    held = min(count - 1, max(1, int(round(val_fraction * count))))
    return np.sort(order[held:]), np.sort(order[:held])


def _padded_batch(sequences: list[Episode], max_tilt: float) -> dict[str, torch.Tensor]:
    """Episodes side by side, (T, B, …), padded at the end; ``mask`` marks real steps."""
    steps = max(len(s) for s in sequences)
    batch = len(sequences)
    obs_shape = sequences[0].obs.shape[1:]
    obs = np.zeros((steps, batch, *obs_shape), dtype=sequences[0].obs.dtype)
    out = {"actions": np.zeros((steps, batch), np.int64), "prev_action": np.full((steps, batch), NO_ACTION, np.int64),
           "prev_reward": np.zeros((steps, batch), np.float32), "tilt": np.zeros((steps, batch, 2), np.float32),
           "returns": np.zeros((steps, batch), np.float32), "mask": np.zeros((steps, batch), bool)}
    for b, s in enumerate(sequences):
        n = len(s)
        obs[:n, b] = s.obs
        out["actions"][:n, b] = s.actions
        out["prev_action"][:n, b] = s.prev_actions
        out["prev_reward"][:n, b] = s.prev_rewards
        out["tilt"][:n, b] = s.tilt / max_tilt
        out["returns"][:n, b] = s.returns
        out["mask"][:n, b] = True
    tensors = {k: torch.as_tensor(v) for k, v in out.items()}
    tensors["obs"] = torch.as_tensor(obs)
    return tensors


# --------------------------------------------------------------------------------- the loss
def l2_penalty(net: torch.nn.Module) -> torch.Tensor:
    """‖θ‖² over weight matrices and kernels (biases, norms and fixed buffers excluded)."""
    return sum((p.pow(2).sum() for p in net.parameters() if p.dim() > 1), torch.zeros(()))


def policy_loss_terms(net: RecurrentActorCritic, batch: dict[str, torch.Tensor], config: PretrainConfig,
                      optimizer: torch.optim.Optimizer | None = None) -> dict[str, float]:
    """The pre-training loss over a padded batch of episodes, chunk by chunk (truncated BPTT);
    with ``optimizer``, one update per chunk. Returns sums over real steps: ``ce``, ``value_se``
    (squared value error), ``correct`` (argmax = expert), ``count``."""
    steps, width = batch["actions"].shape
    state = net.initial_state(width)
    totals = {"ce": 0.0, "value_se": 0.0, "correct": 0.0, "count": 0.0}
    tilt_on = net.config.tilt_input
    for t0 in range(0, steps, config.bptt):
        sl = slice(t0, min(steps, t0 + config.bptt))
        mask = batch["mask"][sl]
        if not mask.any():
            break
        starts = torch.zeros_like(mask)
        if t0 == 0:
            starts[0] = True
        logits, values, state = net.unroll(batch["obs"][sl], batch["prev_action"][sl], batch["prev_reward"][sl],
                                           batch["tilt"][sl] if tilt_on else None, state, starts)
        state = type(state)(state.h.detach(), state.c.detach())
        weights = mask.float()
        count = weights.sum()
        ce = F.cross_entropy(logits.reshape(-1, logits.shape[-1]), batch["actions"][sl].reshape(-1),
                             reduction="none").reshape(mask.shape)
        value_se = (values - batch["returns"][sl]).pow(2)
        data_loss = ((ce + config.value_coef * 0.5 * value_se) * weights).sum() / count
        if optimizer is not None:
            loss = data_loss + config.l2 * l2_penalty(net)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), config.max_grad_norm)
            optimizer.step()
        totals["ce"] += float((ce.detach() * weights).sum())
        totals["value_se"] += float((value_se.detach() * weights).sum())
        totals["correct"] += float(((logits.argmax(-1) == batch["actions"][sl]).float() * weights).sum())
        totals["count"] += float(count)
    return totals


def _summarise(totals: dict[str, float], value_coef: float, policy: bool) -> dict[str, float]:
    count = max(totals["count"], 1.0)
    value_mse = totals["value_se"] / count
    loss = (totals["ce"] / count if policy else 0.0) + value_coef * 0.5 * value_mse
    return {"loss": loss, "accuracy": totals["correct"] / count if policy else float("nan"),
            "value_rmse": math.sqrt(value_mse)}


def _policy_epoch(net, sequences, indices, config, max_tilt, rng, optimizer) -> dict[str, float]:
    order = rng.permutation(indices) if optimizer is not None else indices
    totals = {"ce": 0.0, "value_se": 0.0, "correct": 0.0, "count": 0.0}
    net.train(optimizer is not None)
    with torch.set_grad_enabled(optimizer is not None):
        for start in range(0, len(order), config.batch_episodes):
            batch = _padded_batch([sequences[i] for i in order[start:start + config.batch_episodes]], max_tilt)
            for key, value in policy_loss_terms(net, batch, config, optimizer).items():
                totals[key] += value
    return _summarise(totals, config.value_coef, policy=True)


def _frames(sequences: list[Episode], indices: np.ndarray, max_tilt: float) -> dict[str, torch.Tensor]:
    return {"obs": torch.as_tensor(np.concatenate([sequences[i].obs for i in indices])),
            "tilt": torch.as_tensor(np.concatenate([sequences[i].tilt for i in indices]) / max_tilt),
            "returns": torch.as_tensor(np.concatenate([sequences[i].returns for i in indices]))}


def _value_epoch(net: ValueNetwork, frames: dict[str, torch.Tensor], config: PretrainConfig,
                 rng: np.random.Generator, optimizer) -> dict[str, float]:
    n = len(frames["returns"])
    order = torch.as_tensor(rng.permutation(n) if optimizer is not None else np.arange(n))
    value_se = 0.0
    net.train(optimizer is not None)
    with torch.set_grad_enabled(optimizer is not None):
        for start in range(0, n, config.batch_frames):
            idx = order[start:start + config.batch_frames]
            values = net(frames["obs"][idx], frames["tilt"][idx] if net.config.tilt_input else None)
            se = (values - frames["returns"][idx]).pow(2)
            if optimizer is not None:
                loss = config.value_coef * 0.5 * se.mean() + config.l2 * l2_penalty(net)
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(net.parameters(), config.max_grad_norm)
                optimizer.step()
            value_se += float(se.detach().sum())
    return _summarise({"ce": 0.0, "value_se": value_se, "correct": 0.0, "count": float(n)},
                      config.value_coef, policy=False)


# ---------------------------------------------------------------------------------- training
@dataclasses.dataclass
class PretrainResult:
    run_dir: Path
    best_epoch: int
    epochs_run: int
    val_accuracy: float
    """Held-out action-prediction accuracy of the kept weights (NaN for a value network)."""
    val_value_rmse: float
    seconds: float
    policy_eval: dict[str, float] | None
    """π^s alone as a policy: greedy and sampled success rate and length (policy target only)."""


def build_model(config: PretrainConfig, maze: MazeSpec | None = None) -> RecurrentActorCritic | ValueNetwork:
    """The untrained network of ``config.target``, shaped as A3C's for the same observations."""
    a3c = config.a3c_config()
    if config.target == "policy":
        return network_for(a3c, maze)
    net_config, inputs = net_config_for(a3c, maze)
    return build_value_network(net_config, seed=config.seed, **inputs)


def train_policy_epochs(net: RecurrentActorCritic, sequences: list[Episode], config: PretrainConfig,
                        epochs: int, rng: np.random.Generator, max_tilt: float) -> dict[str, float]:
    """``epochs`` passes of the pre-training loss over all ``sequences`` (no hold-out; DAgger's
    retraining step). Returns the last epoch's training summary."""
    optimizer = torch.optim.Adam(net.parameters(), lr=config.lr)
    summary: dict[str, float] = {}
    for _ in range(epochs):
        summary = _policy_epoch(net, sequences, np.arange(len(sequences)), config, max_tilt, rng, optimizer)
    return summary


def pretrain(config: PretrainConfig, data_dir: str | Path, out_dir: str | Path, *, progress: bool = True,
             sequences: list[Episode] | None = None) -> PretrainResult:
    """Train π^s or V̂ on the dataset in ``data_dir``; everything is written to ``out_dir``:
    ``config.json``, ``checkpoint.pt`` (the best held-out weights), ``pretrain.csv`` and TensorBoard
    scalars per epoch, ``summary.json``. ``sequences`` (already loaded with
    :func:`load_sequences`) skips reading the dataset."""
    with torch_threads():
        return _pretrain(config, data_dir, Path(out_dir), progress=progress, sequences=sequences)


def _pretrain(config: PretrainConfig, data_dir: str | Path, out_dir: Path, *, progress: bool,
              sequences: list[Episode] | None) -> PretrainResult:
    if (out_dir / CONFIG).exists() or (out_dir / CHECKPOINT).exists():
        raise ValueError(f"{out_dir} already holds a run; choose a new --out")
    maze = MazeSpec.merl()
    if sequences is None:
        sequences = load_sequences(data_dir, config.task, config.obs, config.gamma, maze, progress=progress)
    rng = np.random.default_rng(config.seed)
    train_idx, val_idx = split_episodes(len(sequences), config.val_fraction, rng)
    net = build_model(config, maze)
    kind = KIND_POLICY if config.target == "policy" else KIND_VALUE
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(out_dir / CONFIG, {"kind": kind, "a3c": config.a3c_config().to_dict(), "net": net.config.to_dict(),
                                  "pretrain": config.to_dict(), "data": str(data_dir),
                                  "episodes": {"train": len(train_idx), "held_out": len(val_idx)}})
    optimizer = torch.optim.Adam(net.parameters(), lr=config.lr)
    max_tilt = maze.max_tilt
    if config.target == "value":
        train_frames, val_frames = _frames(sequences, train_idx, max_tilt), _frames(sequences, val_idx, max_tilt)

        def run_epoch(training: bool) -> dict[str, float]:
            return _value_epoch(net, train_frames if training else val_frames, config, rng,
                                optimizer if training else None)
    else:
        def run_epoch(training: bool) -> dict[str, float]:
            return _policy_epoch(net, sequences, train_idx if training else val_idx, config, max_tilt, rng,
                                 optimizer if training else None)

    log = MetricLog(out_dir, {"pretrain": _TABLE})
    started = time.monotonic()
    best: dict[str, Any] = {"loss": math.inf, "epoch": 0, "accuracy": float("nan"), "value_rmse": float("nan")}
    initial = run_epoch(False)
    log.write("pretrain", 0, {"val_loss": initial["loss"], "val_accuracy": initial["accuracy"],
                              "val_value_rmse": initial["value_rmse"], "seconds": 0.0},
              scalars=("val_loss", "val_accuracy", "val_value_rmse"))
    epochs_run = 0
    try:
        with _EpochProgress(progress, config) as show:
            for epoch in range(1, config.epochs + 1):
                train_summary = run_epoch(True)
                val = run_epoch(False)
                epochs_run = epoch
                if not math.isfinite(train_summary["loss"]):
                    raise RuntimeError(f"pre-training diverged at epoch {epoch} (training loss "
                                       f"{train_summary['loss']}); lower --lr (now {config.lr})")
                row = {"train_loss": train_summary["loss"], "train_accuracy": train_summary["accuracy"],
                       "train_value_rmse": train_summary["value_rmse"], "val_loss": val["loss"],
                       "val_accuracy": val["accuracy"], "val_value_rmse": val["value_rmse"],
                       "seconds": time.monotonic() - started}
                log.write("pretrain", epoch, row, scalars=_TABLE[:-1])
                if val["loss"] < best["loss"]:
                    best = {"loss": val["loss"], "epoch": epoch, "accuracy": val["accuracy"],
                            "value_rmse": val["value_rmse"]}
                    save_checkpoint(out_dir / CHECKPOINT, model=net.state_dict(), step=0, epoch=epoch,
                                    kind=kind)
                show(epoch, val, best)
                if epoch - best["epoch"] >= config.patience:
                    break
    finally:
        log.close()
    if best["epoch"] == 0:
        save_checkpoint(out_dir / CHECKPOINT, model=net.state_dict(), step=0, epoch=0, kind=kind)
    load_weights(net, out_dir / CHECKPOINT)
    policy_eval = None
    if config.target == "policy" and config.eval_episodes > 0:
        policy_eval = evaluate_policy(net, config)
    result = PretrainResult(out_dir, best["epoch"], epochs_run, best["accuracy"], best["value_rmse"],
                            time.monotonic() - started, policy_eval)
    write_json(out_dir / "summary.json", {"kind": kind, "best_epoch": result.best_epoch, "epochs_run": epochs_run,
                                          "val_accuracy": result.val_accuracy,
                                          "val_value_rmse": result.val_value_rmse, "chance_accuracy": 0.2,
                                          "seconds": result.seconds, "policy_eval": policy_eval,
                                          "episodes": {"train": len(train_idx), "held_out": len(val_idx)}})
    return result


def evaluate_policy(net: RecurrentActorCritic, config: PretrainConfig, seed: int = 12345) -> dict[str, float]:
    """π^s alone on its task: greedy and sampled success rate, length and return."""
    return {"episodes": config.eval_episodes,
            **evaluate_greedy_and_sampled(net, config.a3c_config(), episodes=config.eval_episodes, seed=seed)}


class _EpochProgress:
    """A rich progress bar over epochs with the held-out numbers (or nothing when disabled)."""

    def __init__(self, enabled: bool, config: PretrainConfig):
        self.enabled = enabled
        self.config = config

    def __enter__(self):
        if not self.enabled:
            return lambda epoch, val, best: None
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self.bar = Progress(TextColumn(f"pretrain {self.config.target} {self.config.task} {self.config.obs}"),
                            BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[info]}"), TimeElapsedColumn())
        self.bar.__enter__()
        self.task_id = self.bar.add_task("epochs", total=self.config.epochs, info="")

        def show(epoch: int, val: dict[str, float], best: dict[str, Any]) -> None:
            accuracy = "" if math.isnan(val["accuracy"]) else f"held-out accuracy {val['accuracy']:.1%}  "
            self.bar.update(self.task_id, completed=epoch,
                            info=f"{accuracy}value RMSE {val['value_rmse']:.3f}  best epoch {best['epoch']}")
        return show

    def __exit__(self, *exc) -> None:
        if self.enabled:
            self.bar.__exit__(*exc)


# ------------------------------------------------------------------------------- loading runs
def load_value_network(run_dir: str | Path) -> tuple[ValueNetwork, PretrainConfig]:
    """The frozen V̂ of a value pre-training run (``bimgame pretrain --value-only``)."""
    run_dir = Path(run_dir)
    kind = run_kind(run_dir)
    if kind != KIND_VALUE:
        raise ValueError(f"{run_dir} holds a {kind} run, not a value function; train one with "
                         f"'bimgame pretrain --value-only'")
    stored = json.loads((run_dir / CONFIG).read_text())
    config = PretrainConfig.from_dict(stored["pretrain"])
    net = build_model(config)
    load_weights(net, run_dir / CHECKPOINT)
    net.eval()
    for param in net.parameters():
        param.requires_grad_(False)
    return net, config
