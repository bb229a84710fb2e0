"""The documentation's structure, checked without building the site (``./dev docs`` runs
``mkdocs build --strict``, which checks the rest): the README stays short, every relative link and
image of the README and of the guide (docs/guide/*.md) points at a file that exists — so they work
on GitHub as on the site — and every page of mkdocs.yml's nav exists."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"
GUIDE = sorted((DOCS / "guide").glob("*.md"))
README_MAX_LINES = 200

_FENCE = re.compile(r"^\s*(```|~~~)")
_INLINE_CODE = re.compile(r"`[^`\n]*`")
#: [text](target) and ![alt](target), the target up to a space (an optional "title" follows) or ")".
_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
#: Reference definitions: [label]: target
_REFERENCE = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$", re.MULTILINE)
_SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


def _prose(text: str) -> str:
    """The Markdown outside fenced code blocks, inline code spans blanked."""
    lines, in_fence = [], False
    for line in text.splitlines():
        if _FENCE.match(line):
            in_fence = not in_fence
            lines.append("")
            continue
        lines.append("" if in_fence else _INLINE_CODE.sub("``", line))
    return "\n".join(lines)


def relative_links(text: str) -> list[str]:
    """The relative targets of a Markdown document's links and images (external URLs, mail
    addresses and same-page anchors left out), without their anchors and queries."""
    prose = _prose(text)
    targets = _LINK.findall(prose) + _REFERENCE.findall(prose)
    found = []
    for target in targets:
        if _SCHEME.match(target) or target.startswith("#"):
            continue
        path = re.split(r"[#?]", target, maxsplit=1)[0]
        if path:
            found.append(path)
    return found


def nav_pages(mkdocs_yml: str) -> list[str]:
    """The Markdown pages named in mkdocs.yml's ``nav:`` (read as text: no YAML parser needed)."""
    match = re.search(r"^nav:\s*\n((?:[ \t]+.*\n?|\s*\n)*)", mkdocs_yml, re.MULTILINE)
    assert match, "mkdocs.yml has no nav"
    return re.findall(r"^\s*-\s*(?:[^\n]*?:\s+)?([^\s:]+\.md)\s*$", match.group(1), re.MULTILINE)


def test_readme_is_short():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines; the details belong in docs/guide/"


def test_readme_keeps_the_test_command_in_its_tests_section():
    text = README.read_text(encoding="utf-8")
    section = re.search(r"^## Tests\n(.*?)(?=^## |\Z)", text, re.MULTILINE | re.DOTALL)
    assert section and "./dev test" in section.group(1)


@pytest.mark.parametrize("document", [README, *GUIDE], ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_and_images_resolve(document):
    links = relative_links(document.read_text(encoding="utf-8"))
    missing = [link for link in links if not (document.parent / link).exists()]
    assert missing == [], f"{document.relative_to(ROOT)} links to files that do not exist"


def test_the_readme_links_into_the_guide():
    linked = {(README.parent / link).resolve() for link in relative_links(README.read_text(encoding="utf-8"))}
    assert {page.resolve() for page in GUIDE} <= linked


def test_nav_pages_exist_and_the_guide_and_api_are_in_it():
    pages = nav_pages((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))
    assert [page for page in pages if not (DOCS / page).is_file()] == []
    assert len(pages) == len(set(pages))
    expected = {str(p.relative_to(DOCS)) for p in [*GUIDE, *(DOCS / "api").glob("*.md")]}
    assert expected - set(pages) == set()


def test_the_link_reader():
    text = """\
See [the guide](docs/guide/a.md#part), ![a figure](docs/x.png "title") and [site](https://example.org).
A [self link](#top), `[not a link](in/code.md)`, and [b][ref].

[ref]: docs/b.md

```
[also not](in/fence.md)
```
"""
    assert relative_links(text) == ["docs/guide/a.md", "docs/x.png", "docs/b.md"]
    nav = "site_name: x\nnav:\n  - Home: index.md\n  - Guide:\n      - A: guide/a.md\n      - guide/b.md\nplugins: []\n"
    assert nav_pages(nav) == ["index.md", "guide/a.md", "guide/b.md"]
