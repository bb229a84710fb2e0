"""Checks shared by the settings dataclasses (A3C, networks, pre-training, DAgger, experiments):
one place that says what a bad value is and names the allowed ones."""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

__all__ = ["from_dict", "require_int"]

T = TypeVar("T")


def from_dict(cls: type[T], values: dict[str, Any], what: str) -> T:
    """``cls(**values)`` for a settings dataclass, refusing unknown keys by name (e.g. a
    config.json written by another version) instead of a bare TypeError."""
    known = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(f"unknown {what} {unknown}; allowed: {sorted(known)}")
    return cls(**values)


def require_int(owner: str, name: str, value: Any, minimum: int) -> None:
    """Raise ``ValueError`` unless ``value`` is an int (not a bool) >= ``minimum``."""
    if not (isinstance(value, int) and not isinstance(value, bool) and value >= minimum):
        raise ValueError(f"{owner}.{name} must be an integer >= {minimum}, got {value!r}")
