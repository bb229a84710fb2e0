"""Every Python example of the README and the guide runs: each fenced ``python`` block is executed as it
stands (after ``import gymnasium as gym`` and ``import bimgame``, which a block continuing an earlier
one on its page leaves out). An example that drifts from the code fails here. The shell examples'
``bimgame`` command lines are parsed by tests/cli/test_docs_commands.py."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = [ROOT / "README.md", ROOT / "docs" / "index.md", *sorted((ROOT / "docs" / "guide").glob("*.md"))]
_BLOCK = re.compile(r"^```python\n(.*?)^```", re.MULTILINE | re.DOTALL)
PREAMBLE = "import gymnasium as gym\nimport bimgame\n"


def _examples() -> list[tuple[str, str]]:
    found = []
    for document in DOCUMENTS:
        for k, match in enumerate(_BLOCK.finditer(document.read_text())):
            found.append((f"{document.relative_to(ROOT)}#{k}", match.group(1)))
    return found


EXAMPLES = _examples()


def test_the_documents_have_python_examples():
    assert len(EXAMPLES) >= 5, [name for name, _ in EXAMPLES]


@pytest.mark.parametrize("name, code", EXAMPLES, ids=[name for name, _ in EXAMPLES])
def test_python_example_runs(name, code):
    namespace: dict = {"__name__": f"example {name}"}
    exec(compile(PREAMBLE + code, name, "exec"), namespace)
    for value in namespace.values():  # close what the example opened
        close = getattr(value, "close", None)
        if callable(close) and type(value).__module__.startswith(("gymnasium", "bimgame")):
            close()
