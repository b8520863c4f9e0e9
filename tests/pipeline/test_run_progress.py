"""The progress a :class:`~gnss_cli.pipeline.run.Run` reports: a stage reaches 100 % only when
its last step is done (the multi-epoch methods, one after the other, each an equal share of
the epochs), so a long ``stls`` never shows 100 % while it runs."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from gnss_cli.config import load_config
from gnss_cli.pipeline.run import RESTART, Run

SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"


@pytest.mark.parametrize("chunk", [0, 20], ids=["whole", "parts-of-20"])
def test_multi_epoch_progress_reaches_100_percent_only_when_the_last_method_is_done(chunk: int) -> None:
    calls: list[tuple[str, float]] = []
    config = load_config(None, {"methods": "wls,kf,smoother,stls", "stls.lag": 3})
    run = Run(SAMPLE / "obs.rnx", [SAMPLE / "nav.rnx"], replace(config, chunk_epochs=chunk, stream_above_epochs=chunk),
              lambda stage, fraction: calls.append((stage, fraction)))
    assert sum(p is not RESTART for p in run.parts()) >= 1
    multi = [(stage, fraction) for stage, fraction in calls
             if stage.endswith(": solving") and not stage.startswith("part")]
    # the sample's 121 epochs are one piece of the multi-epoch methods (shorter than their margins)
    assert multi == [("kf: solving", 0.0), ("smoother: solving", pytest.approx(1 / 3)),
                     ("stls: solving", pytest.approx(2 / 3)), ("stls: solving", 1.0)]
    assert [f for _, f in calls].index(1.0) == len(calls) - 1  # 100 % once: after the last step
    for stage in {s for s, _ in calls}:
        fractions = [f for s, f in calls if s == stage]
        assert fractions == sorted(fractions) and all(0.0 <= f <= 1.0 for f in fractions), (stage, fractions)
