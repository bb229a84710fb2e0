"""Where a learner's update runs: ``cpu``, ``cuda`` or ``auto`` (CUDA when torch sees a device, else the
CPU). Environments always step on the CPU, and so does the network that acts in them (one observation
batch per step is too small to pay for a transfer each way); the update's batched forward and
backward passes are what a GPU speeds up."""

from __future__ import annotations

from typing import Literal, get_args

import torch

__all__ = ["Device", "DEVICES", "resolve_device"]

Device = Literal["cpu", "cuda", "auto"]
#: The device settings a learner takes.
DEVICES: tuple[str, ...] = get_args(Device)


def resolve_device(name: str) -> torch.device:
    """The torch device of the setting ``name``; a clear error for an unknown name or for ``cuda`` on a
    machine where torch sees no CUDA device."""
    if name not in DEVICES:
        raise ValueError(f"unknown device {name!r}; allowed: {', '.join(DEVICES)}")
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ValueError(
            "device 'cuda' asked for, but torch sees no CUDA device here (torch.cuda.is_available() is False); "
            f"allowed: {', '.join(DEVICES)} ('auto' takes the CPU on this machine)"
        )
    return torch.device(name)
