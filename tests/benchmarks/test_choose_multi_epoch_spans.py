"""``benchmarks/choose_multi_epoch_spans.py``: the rule that picks the reflection spans, and the
package default it chose."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import choose_multi_epoch_spans as spans  # noqa: E402


def _candidate(ratios: list[float], los: float, allowed: bool = True) -> dict[str, object]:
    return {"score": sum(ratios) / len(ratios), "ratios": ratios, "los": los, "allowed": allowed}


def test_a_gentler_candidate_within_one_standard_error_of_the_best_is_chosen() -> None:
    """The best mean is not taken when a candidate that leaves out fewer LOS satellite-epochs is
    within one standard error of it (paired over the cases); a disallowed one is never taken."""
    summary = {"off": _candidate([1.0, 1.0, 1.0, 1.0], 1.0),
               "sharp": _candidate([0.40, 0.50, 0.45, 0.42], 4.0),
               "gentle": _candidate([0.50, 0.45, 0.47, 0.44], 1.5),
               "sharpest": _candidate([0.30, 0.30, 0.30, 0.30], 6.0, allowed=False)}
    assert spans.choose(summary) == "gentle"


def test_a_gentler_candidate_beyond_one_standard_error_is_not_chosen() -> None:
    """Consistently worse on every case by more than the spread of the differences: the best stays."""
    summary = {"off": _candidate([1.0, 1.0, 1.0, 1.0], 1.0),
               "sharp": _candidate([0.40, 0.50, 0.45, 0.42], 4.0),
               "gentle": _candidate([0.50, 0.61, 0.54, 0.53], 1.5)}
    assert spans.choose(summary) == "sharp"


def test_the_package_default_is_the_committed_choice() -> None:
    """``[nlos] multi_epoch_k``, ``multi_epoch_h`` and ``multi_epoch_rounds`` are the setting the
    committed run of the script chose (and that choice is the rule's on the committed numbers)."""
    if not spans.OUT.is_file():
        pytest.skip("benchmarks/results/choose_multi_epoch_spans.json is not there")
    from gnss_cli.config import load_config

    data = json.loads(spans.OUT.read_text(encoding="utf-8"))
    assert spans.choose(data["summary"]) == data["chosen"]
    chosen = spans.CANDIDATES[data["chosen"]]
    nlos = load_config(None, {}).nlos
    assert (nlos.multi_epoch_k, nlos.multi_epoch_h, nlos.multi_epoch_rounds) == (
        chosen["nlos.multi_epoch_k"], chosen["nlos.multi_epoch_h"], chosen["nlos.multi_epoch_rounds"])
