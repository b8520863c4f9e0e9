"""``benchmarks/choose_segment_misfit.py``: the rule that picks ``max_segment_misfit``, and the
package default it chose."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import choose_segment_misfit as misfit  # noqa: E402


def _summary(costly: set[float]) -> dict[str, dict[str, object]]:
    """Every candidate allowed at score 1, but those of ``costly`` (score 1.05)."""
    return {c: {"allowed": True, "score": 1.05 if misfit.CANDIDATES[c]["max_segment_misfit"] in costly else 1.0}
            for c in misfit.CANDIDATES}


def test_the_limit_keeps_a_margin_of_two_from_one_that_costs() -> None:
    """With 2 costly the smallest free limit, 3, has 2 within half of it, so 5 is chosen; with
    nothing costly, 2; with 3 costly as well, 10 (5's half, 2.5, reaches 3)."""
    assert misfit.choose(_summary({2.0})) == "limit 5"
    assert misfit.choose(_summary(set())) == "limit 2"
    assert misfit.choose(_summary({2.0, 3.0})) == "limit 10"


def test_a_disallowed_limit_counts_as_costly() -> None:
    summary = _summary(set())
    summary["limit 2"]["allowed"] = False
    assert misfit.choose(summary) == "limit 5"


def test_the_package_default_is_the_committed_choice() -> None:
    if not misfit.OUT.is_file():
        pytest.skip("benchmarks/results/choose_segment_misfit.json is not there")
    from gnss_cli.config import load_config

    data = json.loads(misfit.OUT.read_text(encoding="utf-8"))
    assert misfit.choose(data["summary"]) == data["chosen"]
    assert load_config(None, {}).max_segment_misfit == misfit.CANDIDATES[data["chosen"]]["max_segment_misfit"]
