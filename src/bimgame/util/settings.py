"""What every settings dataclass (A3C, networks, pre-training, DAgger, the MPC expert, budgets)
shares: building one from a dict with a clear error, integer checks, and the field docstrings.

A setting is declared once, as a dataclass field with a default and a docstring right below it (as
CleanRL and tyro read them). :func:`field_docs` reads those docstrings from the source, so that the
command line's ``--help`` is generated from them instead of being written a second time.

Two labels open a clause of a field docstring that says what one value means, in the docstring's
own words: ``None: …`` (what a None default stands for, e.g. "LSTM size; None: 256 for pixels, 128
for state observations") and ``False: …`` (what a switch does when off, e.g. "Feed the board tilt to
the LSTM. False: the paper's exact input, without the tilt"). :func:`split_field_doc` separates
them, so that ``--help`` can say what a flag such as ``--no-tilt-input`` does instead of what the
setting means when on."""

from __future__ import annotations

import ast
import dataclasses
import functools
import inspect
import textwrap
from typing import Any, TypeVar

import numpy as np

__all__ = [
    "from_dict",
    "require_int",
    "field_docs",
    "is_integer",
    "is_real",
    "FieldDoc",
    "split_field_doc",
    "VALUE_LABELS",
]

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


@functools.cache
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
        for statement, following in zip(body, body[1:], strict=False):
            if (
                isinstance(statement, ast.AnnAssign)
                and isinstance(statement.target, ast.Name)
                and isinstance(following, ast.Expr)
                and isinstance(following.value, ast.Constant)
                and isinstance(following.value.value, str)
            ):
                docs[statement.target.id] = " ".join(following.value.value.split())
    return docs


#: The labels of the value clauses of a field docstring (see the module notes).
VALUE_LABELS = ("None", "False")


@dataclasses.dataclass(frozen=True)
class FieldDoc:
    """A field docstring split into its description and its value clauses (:func:`split_field_doc`)."""

    text: str
    """The docstring without its value clauses."""
    none: str | None = None
    """The ``None: …`` clause without its label and final full stop (None: there is none)."""
    false: str | None = None
    """The ``False: …`` clause, likewise."""


def split_field_doc(doc: str) -> FieldDoc:
    """Split a folded field docstring (:func:`field_docs`) into its description and its value clauses.

    A clause starts a sentence or a ``;``-separated part with ``None:`` or ``False:`` and ends with
    it; full stops and semicolons inside parentheses do not end it. "LSTM size; None: 256 for
    pixels (the paper's), 128 for state." gives the text "LSTM size." and the None clause "256 for
    pixels (the paper's), 128 for state"."""
    kept: list[str] = []
    clauses: dict[str, str] = {}
    for part in _sentence_parts(doc):
        label, colon, rest = part.strip().partition(":")
        if colon and label in VALUE_LABELS and label not in clauses:
            clauses[label] = rest.strip().rstrip(".;").strip()
            if kept and kept[-1].rstrip().endswith(";") and part.rstrip().endswith("."):
                kept[-1] = kept[-1].rstrip()[:-1] + ". "  # the clause ended the sentence
        else:
            kept.append(part)
    text = "".join(kept).strip()
    if text.endswith((";", ",")):
        text = text[:-1] + "."
    return FieldDoc(text=text, none=clauses.get("None"), false=clauses.get("False"))


def _sentence_parts(doc: str) -> list[str]:
    """``doc`` cut after each ``. `` and ``; `` outside parentheses, each part keeping its separator
    and the space after it (so that joining the parts gives ``doc`` back)."""
    parts: list[str] = []
    depth = start = 0
    for i, char in enumerate(doc):
        depth += {"(": 1, ")": -1}.get(char, 0)
        if depth == 0 and char in ".;" and doc[i + 1 : i + 2] in ("", " "):
            parts.append(doc[start : i + 2])
            start = i + 2
    if start < len(doc):
        parts.append(doc[start:])
    return parts
