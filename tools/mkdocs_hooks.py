"""MkDocs hooks (``hooks:`` in ``mkdocs.yml``): the pages made at build time.

- ``reference/<command>.md``: one page per console script, from its Typer app
  (``tools/cli_reference.py``);
- ``benchmark-tables.md``: the tables of ``benchmarks/results/*.json``
  (``benchmarks/results_page.py``);
- ``overview.md``: the README, its ``docs/`` links made relative to the site.

None of them is in the repository; links to ``../README.md`` in the pages point to the overview.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path
from types import ModuleType
from typing import Any

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[1]


def _load(path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location(path.stem, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def readme_page(text: str) -> str:
    """README.md as a page of the site: links into ``docs/`` become site links."""
    return re.sub(r"\]\(docs/", "](", text)


def on_files(files: Files, config: Any) -> Files:
    cli_reference = _load(ROOT / "tools" / "cli_reference.py")
    results_page = _load(ROOT / "benchmarks" / "results_page.py")
    for name, text in cli_reference.pages().items():
        files.append(File.generated(config, f"reference/{name}.md", content=text))
    files.append(File.generated(config, "benchmark-tables.md", content=results_page.page()))
    files.append(File.generated(config, "overview.md", content=readme_page((ROOT / "README.md").read_text("utf-8"))))
    return files


def on_page_markdown(markdown: str, page: Any, config: Any, files: Files) -> str:
    return markdown.replace("](../README.md", "](overview.md")
