"""What a directory holds, for tests that check that a refused or failed command changed nothing."""

from __future__ import annotations

from pathlib import Path


def snapshot(root: Path, *, without_tensorboard: bool = False) -> dict[str, bytes]:
    """Every file under ``root`` by relative path, with its bytes (TensorBoard event files left out
    with ``without_tensorboard``: a resumed writer may add one)."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(Path(root).rglob("*"))
            if p.is_file() and not (without_tensorboard and "tfevents" in p.name)}
