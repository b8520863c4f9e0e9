"""gnss-batch's local workers: forked on Linux (with the parent's modules) or spawned, the same
results; and a worker reads a network's shared navigation files once while they are unchanged."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import gnss_cli.cli.batch_runner as batch_runner
import gnss_cli.io.navigation as navigation
from gnss_cli.cli.batch_task import BatchSettings
from gnss_cli.config import load_config
from gnss_cli.io.catalog import nav_toc_span
from gnss_cli.parallel import can_fork
from gnss_cli.pipeline import process

NUMPY_2 = int(np.__version__.split(".")[0]) >= 2
SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"


@pytest.fixture
def network(tmp_path: Path) -> tuple[list[str], Path]:
    obs = []
    for k in range(3):
        path = tmp_path / f"ST{k:02d}00DNK_R_20200010000_01H_01S_MO.rnx"
        shutil.copy(SAMPLE / "obs.rnx", path)
        obs.append(str(path))
    nav = tmp_path / "nav.rnx"
    shutil.copy(SAMPLE / "nav.rnx", nav)
    return obs, nav


def _results(obs: list[str], nav: Path, forked: bool, monkeypatch: pytest.MonkeyPatch) -> list[object]:
    monkeypatch.setattr(batch_runner, "forks_workers", lambda: forked)
    settings = BatchSettings(load_config(None), navs=((str(nav), *nav_toc_span(nav)),))
    runner = batch_runner.LocalRunner(2, len(obs))
    try:
        results = sorted(runner.results(obs, settings), key=lambda r: r.index)
    finally:
        runner.close(True)
    assert [r.status for r in results] == ["ok"] * len(obs), [r.error for r in results]
    return results


@pytest.mark.skipif(not can_fork(), reason="forked workers: Linux only")
def test_forked_and_spawned_workers_give_the_same_rows(network, monkeypatch: pytest.MonkeyPatch) -> None:
    obs, nav = network
    forked = _results(obs, nav, True, monkeypatch)
    spawned = _results(obs, nav, False, monkeypatch)
    for a, b in zip(forked, spawned):
        if NUMPY_2:
            assert a.positions.equals(b.positions)
        else:  # numpy 1.x's sums change their last bits with the arrays' memory alignment
            pd.testing.assert_frame_equal(a.positions, b.positions, rtol=1e-12, atol=1e-9)
        assert a.station == b.station and a.solved == b.solved > 0


def test_kept_navigation_is_read_once_while_unchanged(network, monkeypatch: pytest.MonkeyPatch) -> None:
    obs, nav = network
    cfg = load_config(None)
    fresh = process(obs[0], [nav], cfg)  # nothing kept: the reference
    reads: list[object] = []
    real = navigation.read_nav
    monkeypatch.setattr(navigation, "read_nav", lambda *a, **k: reads.append(a) or real(*a, **k))
    monkeypatch.setattr(navigation, "_KEPT", None)
    navigation.keep_navigation()
    runs = [process(o, [nav], cfg) for o in obs]
    assert len(reads) == 1  # three stations, one reading
    for run in runs:
        for m, s in run.solutions.items():
            if NUMPY_2:
                assert np.array_equal(s.x_ecef_m, fresh.solutions[m].x_ecef_m, equal_nan=True)
            else:
                np.testing.assert_allclose(s.x_ecef_m, fresh.solutions[m].x_ecef_m, rtol=1e-12, atol=1e-9)
    st = os.stat(nav)
    os.utime(nav, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))  # the file changed: read again
    process(obs[0], [nav], cfg)
    assert len(reads) == 2
    process(obs[0], [nav], load_config(None, {"systems": "G"}))  # other systems: another reading
    assert len(reads) == 3
