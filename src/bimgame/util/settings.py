"""What every settings dataclass (A3C, networks, pre-training, DAgger, the MPC expert, budgets)
shares: building one from a dict with a clear error, integer checks, and the field docstrings.

A setting is declared once, as a dataclass field with a default and a docstring right below it (as
CleanRL and tyro read them). :func:`field_docs` reads those docstrings from the source, so that the
command line's ``--help`` is generated from them instead of being written a second time."""

from __future__ import annotations

import ast
import dataclasses
import functools
import inspect
import textwrap
from typing import Any, TypeVar

import numpy as np

__all__ = ["from_dict", "require_int", "field_docs", "is_integer", "is_real"]

T = TypeVar("T")


def from_dict(cls: type[T], values: dict[str, Any], what: str) -> T:
    """``cls(**values)`` for a settings dataclass, refusing unknown keys by name (e.g. a
    config.json written by another version) instead of a bare TypeError."""
    known = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(f"unknown {what} {unknown}; allowed: {sorted(known)}")
    return cls(**values)


def is_integer(value: Any) -> bool:
    """A Python or numpy integer, not a bool (``True`` is an ``int`` to Python, not a count to a user)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def is_real(value: Any) -> bool:
    """A Python or numpy integer or float, not a bool."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def require_int(owner: str, name: str, value: Any, minimum: int, *, optional: bool = False) -> None:
    """Raise ``ValueError`` unless ``value`` is an int (not a bool) >= ``minimum`` (or, if
    ``optional``, None)."""
    if optional and value is None:
        return
    if not (isinstance(value, int) and not isinstance(value, bool) and value >= minimum):
        allowed = f"None or an integer >= {minimum}" if optional else f"an integer >= {minimum}"
        raise ValueError(f"{owner}.{name} must be {allowed}, got {value!r}")


@functools.lru_cache(maxsize=None)
def field_docs(cls: type) -> dict[str, str]:
    """The docstrings written under the fields of a dataclass and of its dataclass bases (a string
    literal right after ``name: type = default``), folded to one line each; fields without one are
    absent. Read from the source with :mod:`ast`, since Python keeps no attribute docstrings."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass) or klass is object:
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError):  # no source (e.g. defined interactively): no help texts
            continue
        body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
        for statement, following in zip(body, body[1:]):
            if (isinstance(statement, ast.AnnAssign) and isinstance(statement.target, ast.Name)
                    and isinstance(following, ast.Expr) and isinstance(following.value, ast.Constant)
                    and isinstance(following.value.value, str)):
                docs[statement.target.id] = " ".join(following.value.value.split())
    return docs
