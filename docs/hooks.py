"""MkDocs hook (mkdocs.yml ``hooks:``): figures that the guide shows from outside ``docs/``.

``docs/guide/expert.md`` shows ``../../benchmarks/results/expert_lengths_full.png``, which the benchmark
writes where its JSON is. That relative path works on GitHub; for the site, each PNG of the folders
below is published under ``outside/`` and registered under the path a page's link resolves to
(``../benchmarks/results/…`` from the docs folder), so the link is checked and rewritten like any other.
"""

from __future__ import annotations

import os
from pathlib import Path

from mkdocs.structure.files import File, InclusionLevel

#: Folders (relative to the repository root) whose PNG figures the pages may show.
OUTSIDE = ("benchmarks/results",)


def on_files(files, config):
    root = Path(config.config_file_path).resolve().parent
    for folder in OUTSIDE:
        for png in sorted((root / folder).glob("*.png")):
            # The path a link from a page resolves to, relative to the docs folder: ../benchmarks/results/x.png
            src_uri = Path(os.path.relpath(png, config.docs_dir)).as_posix()
            file = File.generated(config, src_uri, abs_src_path=str(png), inclusion=InclusionLevel.INCLUDED)
            file.dest_uri = f"outside/{folder}/{png.name}"
            files.append(file)
    return files
