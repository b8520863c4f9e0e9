"""The documentation's examples run: every fenced ``sh``, ``bash`` and ``python`` block of
README.md and docs/*.md, in a temporary folder holding a link to the repository's
``sample_rinex/``.

The blocks of one page run in order in one folder, so a block may use what an earlier block of
its page wrote (``results/`` of a ``gnss-batch`` run, say). Shell blocks run under ``bash -e -o
pipefail`` with this interpreter's scripts first on ``PATH``; Python blocks with this
interpreter. Lines that only install (``pip install ...``) are not run: the tests run in the
installed environment.

HTML comments on the lines right above a block's fence say how to run it:

- ``<!-- no-test: REASON -->``: not run (a Dask cluster, a download, the test suite itself, file
  names that stand for the reader's files). The test below counts these blocks and keeps their
  number from growing unnoticed.
- ``<!-- test-data: FOLDER[,FOLDER] -->``: links the files of ``../shared/rinex/FOLDER`` into the
  block's folder first; the block is skipped, with the reason, when a folder is missing.
- ``<!-- test-setup: COMMAND -->``: a shell command run first, making the files a block takes as
  given (a ``positions.csv``).

Nothing here needs MkDocs.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
RINEX = (REPO / ".." / "shared" / "rinex").resolve()
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
LANGUAGES = {"sh": "shell", "bash": "shell", "python": "python"}
MAX_UNTESTED = 12
"""At most this many blocks carry ``no-test``; raise it only with a reason in each marker."""
TIMEOUT_S = 120

_FENCE = re.compile(r"^```(\w+)[^\n]*\n(.*?)^```[ \t]*$", re.S | re.M)
_MARKER = re.compile(r"<!--\s*(no-test|test-data|test-setup):\s*(.*?)\s*-->")
_COMMENT_LINE = re.compile(r"^\s*<!--.*-->\s*$")
_INSTALL = re.compile(r"^\s*pip install\b")


@dataclass(frozen=True)
class Block:
    """A fenced block of a page: its language, code, line and the markers before it."""

    page: Path
    line: int
    language: str
    code: str
    markers: dict[str, str] = field(default_factory=dict)

    @property
    def id(self) -> str:
        return f"{self.page.relative_to(REPO)}:{self.line}"


def page_blocks(page: Path) -> list[Block]:
    """The ``sh``/``bash``/``python`` blocks of ``page`` with the markers on the lines before them."""
    text = page.read_text(encoding="utf-8")
    blocks = []
    for match in _FENCE.finditer(text):
        language = LANGUAGES.get(match.group(1))
        if language is None:
            continue
        above = []  # the comment lines right above the fence
        for line in reversed(text[: match.start()].splitlines()):
            if not _COMMENT_LINE.match(line):
                break
            above.append(line)
        markers = {m.group(1): m.group(2) for m in _MARKER.finditer("\n".join(above))}
        blocks.append(Block(page, text.count("\n", 0, match.start()) + 1, language, match.group(2), markers))
    return blocks


BLOCKS = [block for page in PAGES for block in page_blocks(page)]


def runnable_code(block: Block) -> str:
    """The block's code without its install lines (a shell block's ``pip install ...``)."""
    if block.language != "shell":
        return block.code
    return "\n".join(line for line in block.code.splitlines() if not _INSTALL.match(line))


class PageRun:
    """The folder of one page's blocks and how far they have run."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.done: dict[str, str | None] = {}  # block id -> None (ran), or why it did not

    def run(self, block: Block) -> str | None:
        """Run ``block`` after the earlier blocks of its page; None, or why it did not run."""
        for earlier in (b for b in BLOCKS if b.page == block.page and b.line < block.line):
            if earlier.id not in self.done:
                self.done[earlier.id] = self._run_one(earlier)
        self.done[block.id] = self._run_one(block)
        return self.done[block.id]

    def _run_one(self, block: Block) -> str | None:
        if "no-test" in block.markers:
            return f"marked no-test: {block.markers['no-test']}"
        for folder in filter(None, (f.strip() for f in block.markers.get("test-data", "").split(","))):
            source = RINEX / folder
            if not source.is_dir():
                return f"needs the real data folder {source} (beside the repository in CI)"
            for path in source.iterdir():
                link = self.folder / path.name
                if not link.exists():
                    link.symlink_to(path)
        env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
               "MPLBACKEND": "Agg", "PYTHONPATH": ""}
        if "test-setup" in block.markers:
            _check(block, subprocess.run(["bash", "-e", "-o", "pipefail", "-c", block.markers["test-setup"]],
                                         cwd=self.folder, env=env, capture_output=True, text=True, timeout=TIMEOUT_S),
                   "its test-setup")
        if block.language == "shell":
            command = ["bash", "-e", "-o", "pipefail", "-c", runnable_code(block)]
        else:
            command = [sys.executable, "-c", block.code]
        _check(block, subprocess.run(command, cwd=self.folder, env=env, capture_output=True, text=True,
                                     timeout=TIMEOUT_S), "it")
        return None


def _check(block: Block, done: subprocess.CompletedProcess[str], what: str) -> None:
    if done.returncode != 0:
        raise AssertionError(f"{block.id}: {what} exited with {done.returncode}:\n{block.code}\n"
                             f"--- stderr (last lines) ---\n" + "\n".join(done.stderr.splitlines()[-15:]))


@pytest.fixture(scope="module")
def page_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[Path, PageRun]:
    runs = {}
    for page in PAGES:
        folder = tmp_path_factory.mktemp(page.stem)
        (folder / "sample_rinex").symlink_to(REPO / "sample_rinex")
        runs[page] = PageRun(folder)
    return runs


@pytest.mark.parametrize("block", [b for b in BLOCKS if "no-test" not in b.markers], ids=lambda b: b.id)
def test_the_block_runs(block: Block, page_runs: dict[Path, PageRun]) -> None:
    if not runnable_code(block).strip():
        pytest.fail(f"{block.id} only installs: mark it <!-- no-test: REASON -->")
    reason = page_runs[block.page].run(block)
    if reason is not None:
        pytest.skip(reason)


def test_untested_blocks_say_why_and_are_few() -> None:
    untested = [b for b in BLOCKS if "no-test" in b.markers]
    assert all(b.markers["no-test"] for b in untested), [b.id for b in untested if not b.markers["no-test"]]
    assert len(untested) <= MAX_UNTESTED, [f"{b.id}: {b.markers['no-test']}" for b in untested]
    assert len(BLOCKS) - len(untested) > len(untested), "most examples should run"


def test_the_markers_are_found(tmp_path: Path) -> None:
    """A marker counts on the lines right above its fence, and only there."""
    page = tmp_path / "page.md"
    page.write_text("<!-- no-test: far away -->\ntext\n\n<!-- x -->\n<!-- test-data: a,b -->\n```sh\necho 1\n```\n"
                    "```python\nprint(2)\n```\n\n```text\nnot code\n```\n", encoding="utf-8")
    first, second = page_blocks(page)
    assert (first.line, first.language, first.code, first.markers) == (6, "shell", "echo 1\n", {"test-data": "a,b"})
    assert (second.language, second.markers) == ("python", {})
    install = Block(page, 1, "shell", "pip install -e '.[plot]'  # figures\ngnss-solve --version\n")
    assert runnable_code(install) == "gnss-solve --version"
