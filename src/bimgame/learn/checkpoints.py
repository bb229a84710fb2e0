"""Checkpoints of a training run: its weights, optimiser statistics and counters in one file.

A checkpoint (``checkpoint.pt`` in a run directory, :data:`~bimgame.learn.runs.CHECKPOINT`) is
written atomically (:func:`save_checkpoint`), so a killed run leaves the previous one whole, and is
read with ``torch.load(weights_only=True)`` (:func:`load_checkpoint`): a checkpoint is a dict of
tensors, numbers and strings only, so a file someone sent cannot run code when loaded. Whatever is
wrong with a file — missing, empty, truncated, unsafe, damaged, not from bimgame, non-finite
weights — is a :class:`CheckpointError` naming it; a file that cannot be written (a full disk)
raises :class:`~bimgame.util.files.FileWriteError`, which names it.
"""

from __future__ import annotations

import io
import re
import warnings
from pathlib import Path
from typing import Any

import torch

from bimgame.learn.runs import CHECKPOINT
from bimgame.util import files
from bimgame.util.files import FileWriteError

__all__ = [
    "CheckpointError",
    "save_checkpoint",
    "load_checkpoint",
    "load_weights",
    "load_init_weights",
    "with_added_aux_heads",
    "with_added_critic",
    "with_own_background",
    "apply_weights",
]

#: The format tag every bimgame checkpoint carries.
_FORMAT = "bimgame-checkpoint-1"
#: The entries every checkpoint holds, with their types.
_REQUIRED = {"model": dict, "step": int}


class CheckpointError(ValueError):
    """A checkpoint that cannot be used: missing, unreadable, unsafe, or not from a bimgame run."""


def save_checkpoint(
    path: str | Path,
    *,
    model: dict[str, torch.Tensor],
    step: int,
    optimizer: dict[str, Any] | None = None,
    **extra: Any,
) -> Path:
    """Write a checkpoint atomically (:class:`~bimgame.util.files.FileWriteError` naming it if that fails). ``extra``
    values must be tensors, numbers, strings or containers of them (what ``weights_only`` loading
    accepts)."""
    payload = {
        "format": _FORMAT,
        "model": {k: v.detach().clone() for k, v in model.items()},
        "step": int(step),
        **extra,
    }
    if optimizer is not None:
        payload["optimizer"] = optimizer
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    try:
        return files.atomic_write_bytes(path, buffer.getvalue())
    except OSError as error:
        raise FileWriteError.from_error(path, error) from error


def _load_failure(path: Path, error: BaseException) -> CheckpointError:
    """Why ``torch.load(weights_only=True)`` refused ``path``, in our words: torch's own message
    advises loading with ``weights_only=False``, which would run whatever code the file holds, so none
    of its advice is passed on."""
    text = str(error)
    # torch words it two ways: "Unsupported global: GLOBAL x.y" and "unsupported GLOBAL x.y whose module ...".
    unsafe = re.search(r"[Uu]nsupported (?:global: )?GLOBAL ([\w.]+)", text)
    if unsafe:
        return CheckpointError(
            f"refused to load {path}: it holds objects other than tensors and plain data "
            f"({unsafe.group(1)}); loading such a file could run code, so bimgame never does"
        )
    if isinstance(error, EOFError) or "failed finding central directory" in text:
        return CheckpointError(f"cannot read checkpoint {path}: it is truncated (an unfinished copy or download?)")
    return CheckpointError(
        f"cannot read checkpoint {path}: it is not a PyTorch checkpoint, or it is damaged "
        f"({_unpickler_reason(error, text)})"
    )


def _unpickler_reason(error: BaseException, text: str) -> str:
    """The gist of the unpickler's message ``text`` about ``error``, on one line; the error's type
    when the message is empty or would advise ``weights_only=False``."""
    reason = re.search(r"WeightsUnpickler error:\s*(.+?)\s*(?:\n\n|$)", text, re.S)
    detail = reason.group(1) if reason else text.split(". ")[0]
    detail = " ".join(detail.split())
    if "weights_only" in detail or not detail:
        detail = type(error).__name__
    return detail


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Read a checkpoint safely; raises :class:`CheckpointError` naming what is wrong."""
    path = Path(path)
    if path.is_dir():
        path = path / CHECKPOINT
    _require_nonempty_file(path)
    payload = _read_weights_only(path)
    _check_payload(path, payload)
    return payload


def _require_nonempty_file(path: Path) -> None:
    """Refuse a checkpoint path that is not a file, cannot be examined, or is empty."""
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path}")
    try:
        size = path.stat().st_size
    except OSError as error:
        raise CheckpointError(f"cannot read checkpoint {path}: {error.strerror or error}") from None
    if size == 0:
        raise CheckpointError(
            f"cannot read checkpoint {path}: the file is empty (0 bytes; truncated, or never written to the end)"
        )


def _read_weights_only(path: Path) -> Any:
    """What ``torch.load(weights_only=True)`` reads from ``path``: tensors and plain data only; any
    refusal or damage becomes a :class:`CheckpointError`."""
    try:
        with warnings.catch_warnings():
            # A damaged file can claim any pickle protocol; torch's warning about it says nothing useful here.
            warnings.filterwarnings("ignore", message="Detected pickle protocol", category=UserWarning)
            return torch.load(path, map_location="cpu", weights_only=True)
    except OSError as error:
        raise CheckpointError(f"cannot read checkpoint {path}: {error.strerror or error}") from None
    except Exception as error:  # noqa: BLE001 - damaged bytes make the unpickler raise IndexError, KeyError, struct.error…
        raise _load_failure(path, error) from None


def _check_payload(path: Path, payload: Any) -> None:
    """Refuse what was read from ``path`` unless it is a bimgame checkpoint: the format tag, the
    :data:`_REQUIRED` entries, and finite tensors as weights."""
    if not isinstance(payload, dict) or payload.get("format") != _FORMAT:
        raise CheckpointError(f"{path} is not a bimgame checkpoint (no 'format': '{_FORMAT}')")
    for key, kind in _REQUIRED.items():
        if not isinstance(payload.get(key), kind):
            raise CheckpointError(f"checkpoint {path} lacks {key!r} ({kind.__name__})")
    bad = [k for k, v in payload["model"].items() if not torch.is_tensor(v)]
    if bad:
        raise CheckpointError(f"checkpoint {path}: model entries {bad} are not tensors")
    nonfinite = [k for k, v in payload["model"].items() if v.is_floating_point() and not torch.isfinite(v).all()]
    if nonfinite:
        raise CheckpointError(f"checkpoint {path}: weights {nonfinite} are not finite")


def load_weights(module: torch.nn.Module, source: str | Path) -> int:
    """Load a checkpoint's (or run directory's) weights into ``module``; returns the checkpoint's
    step. Shapes must match exactly."""
    return apply_weights(module, load_checkpoint(source), source)


def load_init_weights(module: torch.nn.Module, init: str | Path | None) -> None:
    """Start ``module`` from the weights ``--init`` names (a checkpoint file or run directory; None:
    keep its fresh weights); a checkpoint that cannot be used is a :class:`CheckpointError` naming
    the flag."""
    if init is None:
        return
    try:
        payload = load_checkpoint(init)
        weights = with_added_aux_heads(with_added_critic(payload["model"], module), module)
        weights = with_own_background(weights, module, init)
        apply_weights(module, {**payload, "model": weights}, init)
    except CheckpointError as error:
        raise CheckpointError(f"--init: {error}") from None


#: The conv encoder's empty-board frame (``subtract_background``; all zeros without it).
_BACKGROUND = "encoder.background"


def with_own_background(
    weights: dict[str, torch.Tensor], module: torch.nn.Module, source: str | Path
) -> dict[str, torch.Tensor]:
    """``weights`` with ``module``'s own empty-board frame in place of the checkpoint's: the frame is
    a fixed input of the board ``module`` was built for, not something learned (a π^s of the easy
    layout starts a run on hard with the hard board's frame). A network that subtracted a frame
    started where none is subtracted, or the reverse, would read its frames otherwise than it
    learned to: a :class:`CheckpointError` naming ``--subtract-background``."""
    own, theirs = module.state_dict().get(_BACKGROUND), weights.get(_BACKGROUND)
    if own is None or theirs is None or own.shape != theirs.shape:
        return weights  # no conv encoder here, or a mismatch apply_weights names
    if bool(theirs.any()) != bool(own.any()):
        trained, run = ("with", "without") if theirs.any() else ("without", "with")
        raise CheckpointError(
            f"{source} was trained {trained} --subtract-background (the empty board subtracted from each "
            f"frame) and this run is {run} it; give the run the same setting"
        )
    return {**weights, _BACKGROUND: own}


#: The weights of an asymmetric critic's state reader (``RecurrentActorCritic.critic_state``).
_CRITIC_STATE = "critic_state."


def with_added_critic(weights: dict[str, torch.Tensor], module: torch.nn.Module) -> dict[str, torch.Tensor]:
    """``weights`` of a network without an asymmetric critic made to fit ``module``, which has one
    (``weights`` unchanged otherwise): the run adds the critic to a policy trained without it (a π^s
    or DAgger iterate, which cannot have one). The state reader keeps ``module``'s fresh weights and
    the value head takes the old head's weights on the LSTM's features and zeros on the state
    reader's, so the critic starts as the old one's value exactly and learns to read the state
    (Net2Net's function-preserving widening, Chen et al. 2016) instead of from nothing."""
    expected = module.state_dict()
    adds = any(k.startswith(_CRITIC_STATE) for k in expected) and not any(k.startswith(_CRITIC_STATE) for k in weights)
    old_value = weights.get("value.weight")
    if not adds or old_value is None or old_value.shape[1] >= expected["value.weight"].shape[1]:
        return weights
    widened = torch.zeros_like(expected["value.weight"])
    widened[:, : old_value.shape[1]] = old_value
    state_reader = {k: v for k, v in expected.items() if k.startswith(_CRITIC_STATE)}  # loaded onto themselves
    return {**weights, **state_reader, "value.weight": widened}


#: The weights of the auxiliary heads (``RecurrentActorCritic.aux_frame``, ``aux_memory``).
_AUX_HEADS = ("aux_frame.", "aux_memory.")


def with_added_aux_heads(weights: dict[str, torch.Tensor], module: torch.nn.Module) -> dict[str, torch.Tensor]:
    """``weights`` of a network without auxiliary heads made to fit ``module``, which has them
    (``weights`` unchanged otherwise): the run adds the heads to a policy trained without them (a
    DAgger iterate, which cannot have them). The heads keep ``module``'s fresh weights: they read the
    features and feed nothing back, so the policy acts exactly as loaded, and their loss teaches the
    shared encoder and LSTM to carry the state from the first update on."""
    heads = {k: v for k, v in module.state_dict().items() if k.startswith(_AUX_HEADS)}
    if not heads or any(k.startswith(_AUX_HEADS) for k in weights):
        return weights
    return {**weights, **heads}  # loaded onto themselves


def apply_weights(module: torch.nn.Module, payload: dict[str, Any], source: str | Path) -> int:
    """Put the weights of a checkpoint already read (:func:`load_checkpoint`) from ``source`` into
    ``module``; returns its step. Shapes must match exactly."""
    weights: dict[str, torch.Tensor] = payload["model"]
    expected = module.state_dict()
    missing = sorted(set(expected) - set(weights))
    unexpected = sorted(set(weights) - set(expected))
    mismatched = [k for k in expected if k in weights and weights[k].shape != expected[k].shape]
    if missing or unexpected or mismatched:
        shapes = [(k, tuple(weights[k].shape), tuple(expected[k].shape)) for k in mismatched]
        # Only a continuous-action network has a log_std: one side is discrete, the other continuous.
        hint = " (one network has continuous actions, the other discrete)" if "log_std" in missing + unexpected else ""
        if "encoder.maze_weight" in missing + unexpected:
            hint = (
                " (one network reads the maze encoding through weights of its own, the other does not: networks "
                "trained on many mazes before NetConfig.maze_size read it as plain inputs and cannot start new runs)"
            )
        raise CheckpointError(
            f"weights in {source} do not fit this network{hint}: missing {missing}, unexpected {unexpected}, "
            f"shape mismatch {shapes}"
        )
    module.load_state_dict(weights)
    step: int = payload["step"]
    return step
