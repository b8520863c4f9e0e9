"""The "Benchmark tables" page: one Markdown table per JSON file in ``benchmarks/results/``.

A result file that has ``"title"``, ``"command"`` and ``"table": {"columns": [...], "rows":
[[...], ...]}`` (and optionally ``"notes"``, a string, and ``"more_tables"``, a list of tables
with a ``"title"`` each) becomes a section: the title, the command that measured it, the table(s). ``bench_full_run.json`` and ``bench_memory.json`` were
written before that shape; :data:`ADAPTERS` turns their numbers into the same fields. A file of
neither shape is listed by name at the end, so nothing is dropped silently.

Usage: ``python benchmarks/results_page.py [RESULTS_DIR] > measured.md``; the MkDocs hook
(``tools/mkdocs_hooks.py``) runs it at every build into the page ``benchmark-tables.md``.

A hand-written page may carry a generated section too: the lines between
``<!-- results: NAME.json -->`` and ``<!-- /results -->`` are that file's section
(:func:`fill_sections`); ``python benchmarks/results_page.py --fill docs/results.md`` rewrites
them, and a test checks that the committed page equals its refill.
"""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

RESULTS = Path(__file__).resolve().parent / "results"


def _full_run(data: dict[str, Any]) -> dict[str, Any]:
    rows = [[case, r["epochs"], round(r["gnss_solve_s"], 2), round(r["gnss_solve_cpu_s"], 2),
             round(r["gnss_solve_peak_rss_mib"], 1), round(r["rtklib_s"], 2), round(r["rtklib_peak_rss_mib"], 1),
             round(r["ratio"], 2)] for case, r in data["cases"].items()]
    return {
        "title": "Whole run against RTKLIB (24 h ESBC file)",
        "command": f"python benchmarks/bench_full_run.py --repeat {data.get('repeat', 3)}",
        "table": {"columns": ["case", "epochs", "gnss-solve s", "gnss-solve CPU s", "gnss-solve peak MiB",
                              "rnx2rtkp s", "rnx2rtkp peak MiB", "time ratio"], "rows": rows},
        "notes": f"Medians of {data.get('repeat')} runs on {data.get('cpu_count')} cores; target: ratio "
                 f"<= {data.get('target_ratio')} for {', '.join(data.get('target_cases', []))}.",
    }


def _memory(data: dict[str, Any]) -> dict[str, Any]:
    rows = [[c["method"], c["hours"], c["epochs"], c["peak_mib"], c["seconds"], c["exit_code"]] for c in data["cases"]]
    targets = data.get("targets", {})
    return {
        "title": "Peak memory: a simulated hour against a day (1 Hz, GPS + Galileo)",
        "command": "python benchmarks/bench_memory.py --hours 1 24",
        "table": {"columns": ["method", "hours", "epochs", "peak MiB", "seconds", "exit code"], "rows": rows},
        "notes": f"Targets: the 24 h peak <= {targets.get('ratio')} x the 1 h peak and <= {targets.get('peak_mib')} MiB.",
    }


ADAPTERS: dict[str, Callable[[dict[str, Any]], dict[str, Any]]] = {
    "bench_full_run.json": _full_run, "bench_memory.json": _memory}
"""File name -> function turning a result file of an older shape into title, command, table."""


def results_json(data: object) -> str:
    """A result file's text: JSON indented by one space, each array of plain values (a table row)
    on one line, so that a table of hundreds of rows stays hundreds of lines.

    >>> print(results_json({"rows": [[1, "a"], [2.5, None]]}), end="")
    {
     "rows": [
      [1, "a"],
      [2.5, null]
     ]
    }
    """
    text = json.dumps(data, indent=1, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
    flat = re.compile(r"\[\n\s*([^\[\]{}]*?)\n\s*\]")  # JSON strings hold no raw newline
    return flat.sub(lambda m: "[" + ", ".join(v.strip() for v in m.group(1).split(",\n")) + "]", text) + "\n"


def has_table(data: object) -> bool:
    """Whether ``data`` has the fields a section is made of."""
    return (isinstance(data, dict) and isinstance(data.get("title"), str) and isinstance(data.get("command"), str)
            and isinstance(data.get("table"), dict) and isinstance(data["table"].get("columns"), list)
            and isinstance(data["table"].get("rows"), list))


def _cell(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:g}"
    return str(value).replace("|", "\\|").replace("\n", " ")


def _table_lines(table: dict[str, Any], source: str) -> list[str]:
    columns, rows = table["columns"], table["rows"]
    lines = ["| " + " | ".join(_cell(c) for c in columns) + " |", "|" + "---|" * len(columns)]
    for row in rows:
        if len(row) != len(columns):
            raise ValueError(f"{source}: a row has {len(row)} cells for {len(columns)} columns: {row!r}")
        lines.append("| " + " | ".join(_cell(v) for v in row) + " |")
    return [*lines, ""]


def section(data: dict[str, Any], source: str, level: int = 2) -> str:
    """One result as Markdown: its title (a heading of ``level``), command, table(s) and notes.

    The command is inline code, not a shell block: the docs' shell blocks run in the tests, and a
    benchmark takes minutes."""
    lines = [f"{'#' * level} {data['title']}", "", f"Measured with `{data['command']}`.", "",
             *_table_lines(data["table"], source)]
    if data.get("notes"):
        lines += [str(data["notes"]), ""]
    for more in data.get("more_tables", []):
        lines += [f"{'#' * (level + 1)} {more['title']}", "", *_table_lines(more, source)]
    lines += [f"*From `benchmarks/results/{source}`.*", ""]
    return "\n".join(lines)


_FILL = re.compile(r"(<!-- results: (?P<name>[\w.-]+\.json) -->\n)(?P<body>.*?)(<!-- /results -->)", re.S)


def fill_sections(markdown: str, results: Path = RESULTS) -> str:
    """``markdown`` with the lines between each ``<!-- results: NAME.json -->`` and the next
    ``<!-- /results -->`` replaced by that file's section (headings one level down: ``###``).

    Raises
    ------
    FileNotFoundError
        When a named result file is missing.
    """
    def one(match: re.Match[str]) -> str:
        name = match.group("name")
        data = json.loads((results / name).read_text(encoding="utf-8"))
        return match.group(1) + "\n" + section(data, name, level=3) + "\n" + match.group(4)

    return _FILL.sub(one, markdown)


def page(results: Path = RESULTS) -> str:
    """The whole page: a section per result file, then the files of another shape by name."""
    lines = ["# Benchmark tables", "",
             "Every table below is made at build time from a JSON file the benchmark wrote into "
             "`benchmarks/results/`; rerun its command to measure again. What each experiment means "
             "is in [Measured results](results.md).", ""]
    other = []
    files = sorted(results.glob("*.json")) if results.is_dir() else []
    for path in files:
        data = json.loads(path.read_text(encoding="utf-8"))
        if not has_table(data) and path.name in ADAPTERS:
            data = ADAPTERS[path.name](data)
        if has_table(data):
            lines.append(section(data, path.name))
        else:
            other.append(path.name)
    if not files:
        lines += ["No result files yet: run a benchmark (`python benchmarks/bench_….py`).", ""]
    if other:
        lines += ["## Other result files", "",
                  "These have no `title` / `command` / `table` fields yet: "
                  + ", ".join(f"`{name}`" for name in other) + ".", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--fill":
        target = Path(sys.argv[2])
        target.write_text(fill_sections(target.read_text(encoding="utf-8")), encoding="utf-8")
    else:
        print(page(Path(sys.argv[1]) if len(sys.argv) > 1 else RESULTS))
