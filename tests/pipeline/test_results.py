"""One epoch-status vocabulary: solver and identification outcomes map to it, the README lists it."""

from __future__ import annotations

import re
from pathlib import Path

from gnss_cli.behavior import StlsStatus
from gnss_cli.pipeline import EpochStatus, solver_epoch_status, window_epoch_status
from gnss_cli.pipeline.results import WINDOW_FAILED, window_status_word
from gnss_cli.solvers import Status


def test_every_solver_status_maps_to_an_epoch_status() -> None:
    assert solver_epoch_status(Status.CONVERGED) is EpochStatus.OK
    for code in Status:
        if code <= 0:
            assert solver_epoch_status(int(code)).value == code.name.lower()


def test_window_statuses() -> None:
    assert window_epoch_status(None) is EpochStatus.FALLBACK_WLS
    assert window_epoch_status(StlsStatus.INFEASIBLE) is EpochStatus.FALLBACK_WLS
    assert window_epoch_status(StlsStatus.ITERATION_LIMIT) is EpochStatus.OK
    assert window_status_word(StlsStatus.DIRECT) == "direct" and window_status_word(None) == WINDOW_FAILED


def test_values_are_the_printed_words_and_the_docs_list_them() -> None:
    assert str(EpochStatus.FALLBACK_WLS) == "fallback_wls" and f"{EpochStatus.OK}" == "ok"
    docs = (Path(__file__).resolve().parents[2] / "docs" / "outputs.md").read_text()
    section = docs.split("## Epoch status", 1)[1].split("\n## ", 1)[0]
    listed = re.findall(r"^\| `([a-z_]+)` \|", section, flags=re.M)
    assert listed == [s.value for s in EpochStatus]
