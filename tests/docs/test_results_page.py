"""The "Benchmark tables" page: a table per result file, with its command; the older shapes are
adapted; a file of no known shape is listed, never dropped."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("results_page", REPO / "benchmarks" / "results_page.py")
assert _spec is not None and _spec.loader is not None
results_page = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(results_page)


def _write(folder: Path, name: str, data: object) -> None:
    (folder / name).write_text(json.dumps(data), encoding="utf-8")


def test_a_table_file_becomes_a_section(tmp_path: Path) -> None:
    _write(tmp_path, "bench_x.json", {"title": "Speed", "command": "python benchmarks/bench_x.py --n 3",
                                       "table": {"columns": ["method", "s"], "rows": [["wls", 1.5], ["a|b", None]]},
                                       "notes": "On two cores."})
    page = results_page.page(tmp_path)
    assert "## Speed\n\nMeasured with `python benchmarks/bench_x.py --n 3`.\n" in page
    assert "| method | s |\n|---|---|\n| wls | 1.5 |\n| a\\|b |  |\n" in page
    assert "On two cores." in page and "`benchmarks/results/bench_x.json`" in page


def test_unknown_shapes_are_listed_and_bad_rows_fail(tmp_path: Path) -> None:
    _write(tmp_path, "other.json", {"cases": []})
    assert "`other.json`" in results_page.page(tmp_path)
    _write(tmp_path, "bad.json", {"title": "t", "command": "c", "table": {"columns": ["a", "b"], "rows": [[1]]}})
    with pytest.raises(ValueError, match="bad.json"):
        results_page.page(tmp_path)


def test_no_folder_gives_a_page(tmp_path: Path) -> None:
    assert "No result files yet" in results_page.page(tmp_path / "missing")


@pytest.mark.parametrize("name", sorted(results_page.ADAPTERS))
def test_the_committed_older_files_are_adapted(name: str) -> None:
    path = results_page.RESULTS / name
    if not path.is_file():
        pytest.skip(f"{path} is not there")
    data = results_page.ADAPTERS[name](json.loads(path.read_text(encoding="utf-8")))
    assert results_page.has_table(data)
    assert all(len(row) == len(data["table"]["columns"]) for row in data["table"]["rows"]) and data["table"]["rows"]


def test_more_tables_and_filled_sections(tmp_path: Path) -> None:
    _write(tmp_path, "fair.json", {"title": "Fair", "command": "python benchmarks/fair.py",
                                   "table": {"columns": ["a"], "rows": [[1.0]]},
                                   "more_tables": [{"title": "Rows", "columns": ["b", "c"], "rows": [["x", 2]]}]})
    assert "### Rows\n\n| b | c |\n|---|---|\n| x | 2 |\n" in results_page.page(tmp_path)
    text = "# Page\n\n<!-- results: fair.json -->\nold table\n<!-- /results -->\n\nafter\n"
    filled = results_page.fill_sections(text, tmp_path)
    assert "old table" not in filled and "### Fair\n" in filled and "#### Rows\n" in filled
    assert filled.endswith("<!-- /results -->\n\nafter\n") and results_page.fill_sections(filled, tmp_path) == filled


def test_the_results_page_sections_are_those_of_the_json() -> None:
    """docs/results.md's generated sections are what the committed JSON gives (rerun
    ``python benchmarks/results_page.py --fill docs/results.md`` after a benchmark)."""
    text = (REPO / "docs" / "results.md").read_text(encoding="utf-8")
    assert results_page.fill_sections(text) == text
