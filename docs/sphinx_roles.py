"""Griffe extension for the API reference (mkdocs.yml, the mkdocstrings handler's ``extensions``): the
docstrings' Sphinx roles as links.

The docstrings cross-reference with Sphinx roles (``:class:`~bimgame.learn.a3c.A3CConfig```,
``:func:`train```, ``:mod:`bimgame.sim```), which Markdown would show as they are written. Each role
becomes an optional autorefs cross-reference: a link where the API reference documents the target,
the name in code font where it does not (a third-party object, a private member), never a warning.
Names are resolved as Python would in the docstring's scope; ``~`` shows the last component only,
as in Sphinx.
"""

from __future__ import annotations

import html
import re

import griffe

#: :role:`target`, :role:`~target`, :role:`title <target>` (domain prefixes such as :py:class: too).
ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|attr|data|exc|obj|const|type):`([^`]+)`")
FENCE = re.compile(r"^\s*(```|~~~)")


def _identifier(obj: griffe.Object, target: str) -> str:
    """The full path ``target`` names in ``obj``'s scope (as written when it cannot be resolved)."""
    target = target.lstrip(".").removesuffix("()")
    if target.startswith("bimgame.") or target == "bimgame":
        return target
    head, _, rest = target.partition(".")
    try:
        resolved = obj.resolve(head)
    except Exception:  # noqa: BLE001 — griffe raises several kinds for a name it cannot resolve
        return target
    return f"{resolved}.{rest}" if rest else resolved


def _link(obj: griffe.Object, match: re.Match[str]) -> str:
    text = match.group(1).strip()
    explicit = re.fullmatch(r"(.+?)\s*<([^<>]+)>", text)
    if explicit:
        title, target = explicit.group(1), explicit.group(2)
    else:
        target = text
        shown = target.lstrip("~")
        title = shown.rsplit(".", 1)[-1] if target.startswith("~") else shown
    identifier = _identifier(obj, target.lstrip("~"))
    return (
        f'<autoref identifier="{html.escape(identifier, quote=True)}" optional>'
        f"<code>{html.escape(title)}</code></autoref>"
    )


def rewrite(obj: griffe.Object, text: str) -> str:
    """``text`` with every Sphinx role outside fenced code turned into an optional cross-reference."""
    lines, in_fence = [], False
    for line in text.split("\n"):
        if FENCE.match(line):
            in_fence = not in_fence
        lines.append(line if in_fence else ROLE.sub(lambda m: _link(obj, m), line))
    return "\n".join(lines)


class SphinxRoles(griffe.Extension):
    """Rewrites the roles of every docstring of a package once it is loaded (names resolve then)."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: object) -> None:
        stack: list[griffe.Object] = [pkg]
        while stack:
            obj = stack.pop()
            if obj.docstring is not None:
                obj.docstring.value = rewrite(obj, obj.docstring.value)
            stack.extend(member for member in obj.members.values() if not member.is_alias)
