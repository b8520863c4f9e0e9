"""The misfit test of the smoother's and the kf's segments (:mod:`gnss_cli.pipeline.segment_misfit`):
its statistic against a loop, and what it does where a motion model holds and where it does not."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gnss_cli.config import load_config
from gnss_cli.pipeline import process
from gnss_cli.pipeline.segment_misfit import MIN_EPOCHS, segment_misfit

INF = float("inf")


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from gnss_cli.cli.exits import run_app
    from gnss_cli.cli.simulate import app

    out = tmp_path_factory.mktemp("segments") / "drive"
    with pytest.raises(SystemExit) as done:
        run_app(app, "gnss-simulate", ["--trajectory", "drive", "--duration", "200", "--interval", "1", "--seed", "5",
                                       "--out-dir", str(out), "-q"])
    assert done.value.code == 0
    return out


def _solve(drive: Path, **over: object):  # type: ignore[no-untyped-def]
    res = process(drive / "obs.rnx", [drive / "nav.rnx"], load_config(None, {"methods": "wls,smoother,kf", **over}))
    truth = pd.read_csv(drive / "truth.csv")[["x_m", "y_m", "z_m"]].to_numpy()
    return res, truth


def _rms(x: np.ndarray, truth: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((x - truth) ** 2, axis=1))))


def test_the_statistic_is_the_used_pseudoranges_misfit_per_degree_of_freedom(drive: Path) -> None:
    """``sum u^2 / sum (n_t - k_t)`` over the segment, one epoch at a time."""
    res, _ = _solve(drive)
    data = res.epochs
    for m in ("smoother", "kf"):
        sol = res.solutions[m]
        seg = np.arange(20, 120)
        total, dof = 0.0, 0
        for t in seg:
            used = np.isfinite(sol.residuals_m[t]) & np.isfinite(sol.sigma_m[t])
            total += float(np.sum((sol.residuals_m[t][used] / sol.sigma_m[t][used]) ** 2))
            dof += int(used.sum()) - len(set(data.system_index[used].tolist()))
        got, got_dof = segment_misfit(data, sol, seg)
        assert got_dof == dof and got == pytest.approx(total / dof, rel=1e-12), m
        assert 0.2 < got < 3.0, m  # a motion that holds, in units of the file's own noise


def test_where_the_models_hold_nothing_changes(drive: Path) -> None:
    """The default motions on an open-sky drive pass: the rows are those without the test."""
    tested, _ = _solve(drive)
    untested, _ = _solve(drive, max_segment_misfit=INF)
    for m in ("smoother", "kf"):
        np.testing.assert_array_equal(tested.solutions[m].x_ecef_m, untested.solutions[m].x_ecef_m)
        np.testing.assert_array_equal(tested.solutions[m].status, untested.solutions[m].status)
    assert not [r for r in tested.models if r.status == "rejected"]


def test_a_model_that_does_not_hold_falls_back_and_says_so(drive: Path) -> None:
    """A static smoother on a moving receiver, and a kf whose process noise forbids the drive's
    turns: their segments fail, are solved again in halves, and the shortest failing ones keep
    the WLS fixes (``fallback_wls``); the model records say so, and the positions come closer."""
    for m, over in (("smoother", {"smoother.motion": "static"}), ("kf", {"kalman.accel_psd_m2_s3": 1e-6})):
        res, truth = _solve(drive, **over)
        wrong, _ = _solve(drive, **over, max_segment_misfit=INF)
        sol = res.solutions[m]
        rejected = [r for r in res.models if r.status == "rejected" and r.method == m]
        assert rejected and "solved again as two segments" in rejected[0].message, m
        assert rejected[0].misfit > 10.0 and rejected[0].n_epochs == sol.status.size, m
        # the rejected solution's own records give way to the halves': none spans the whole file
        whole = [r for r in res.models if r.method == m and r.status != "rejected" and r.n_epochs == sol.status.size]
        assert not whole, m
        assert _rms(sol.x_ecef_m, truth) < 0.5 * _rms(wrong.solutions[m].x_ecef_m, truth), m
        if m == "smoother":  # a static model holds nowhere on a drive: the shortest segments keep WLS
            short = [r for r in rejected if "keep the WLS fix" in r.message]
            assert short and all(r.n_epochs < 2 * MIN_EPOCHS for r in short)
            back = sol.status == "fallback_wls"
            assert back.any()
            np.testing.assert_array_equal(sol.x_ecef_m[back], res.solutions["wls"].x_ecef_m[back])


def test_integrity_off_tests_no_segment(drive: Path) -> None:
    res, _ = _solve(drive, **{"smoother.motion": "static", "integrity": "off"})
    assert not [r for r in res.models if r.status == "rejected"]
