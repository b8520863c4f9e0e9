"""The Stanford-diagram regions and the integrity statistics of summary.csv, against
independent computations (a per-epoch rule written out, and the counts from the output files)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import app
from gnss_cli.stanford import REGIONS, integrity_statistics, region_counts, regions

SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"


def _region_of(e: float, pl: float, al: float) -> str:
    """The table of the module docstring, one epoch at a time."""
    if not (np.isfinite(e) and np.isfinite(pl)):
        return ""
    if pl > al:
        return "unavailable" if e <= pl else "unavailable_misleading"
    if e <= pl:
        return "normal"
    return "misleading" if e <= al else "hazardous"


@pytest.mark.parametrize("alert_m", [np.inf, 10.0, 0.5])
def test_regions_equal_the_rule_epoch_by_epoch(alert_m: float) -> None:
    rng = np.random.default_rng(7)
    e = rng.lognormal(0.0, 1.5, 2000) * rng.choice([1.0, -1.0], 2000)  # signed errors: the magnitude counts
    pl = rng.lognormal(0.5, 1.5, 2000)
    e[:5], pl[5:10] = np.nan, np.nan
    pl[10:20] = np.abs(e[10:20])  # on the diagonal: bounded
    labels = regions(e, pl, alert_m)
    assert labels.tolist() == [_region_of(abs(a), b, alert_m) for a, b in zip(e, pl)]
    counts = region_counts(labels)
    assert list(counts) == list(REGIONS) and sum(counts.values()) == 1990
    if np.isinf(alert_m):
        assert counts["hazardous"] == counts["unavailable"] == counts["unavailable_misleading"] == 0


def test_integrity_statistics_count_ok_epochs_outside_their_levels() -> None:
    enu = np.array([[3.0, 4.0, 1.0], [0.1, 0.1, 9.0], [1.0, 0.0, 0.0], [50.0, 0.0, 0.0], [np.nan] * 3])
    ok = np.array([True, True, True, False, True])
    hpl, vpl = np.array([4.0, 1.0, 2.0, 1.0, 1.0]), np.array([2.0, 5.0, 1.0, 1.0, 1.0])
    stats = integrity_statistics(ok, enu, hpl, vpl)
    assert stats["misleading_epochs"] == 2  # epoch 0 (5 m > HPL 4), epoch 1 (9 m > VPL 5); epoch 3 is not ok
    assert stats["misleading_pct"] == pytest.approx(100 * 2 / 3)
    assert stats["availability_pct"] == pytest.approx(80.0)
    err3 = np.linalg.norm(enu[:3], axis=1)
    assert stats["max_3d_m"] == pytest.approx(err3.max()) and stats["p95_3d_m"] == pytest.approx(np.percentile(err3, 95))
    vpl[2] = np.nan  # one ok epoch without a level: the count cannot be made, it is not zero
    assert np.isnan(integrity_statistics(ok, enu, hpl, vpl)["misleading_epochs"])
    assert np.isnan(integrity_statistics(ok, enu, None, None)["misleading_pct"])


def test_summary_counts_equal_the_positions_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """summary.csv's misleading count and availability, recomputed from positions.csv and
    errors.csv of the same run."""
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(SAMPLE / "obs.rnx"), str(SAMPLE / "nav.rnx"), "--method", "ls,wls",
                                    "--reference-csv", str(SAMPLE / "truth.csv"), "--out-dir", str(tmp_path), "-q"])
    assert exc.value.code == 0, capsys.readouterr().err
    summary = pd.read_csv(tmp_path / "summary.csv").set_index("method")
    pos = pd.read_csv(tmp_path / "positions.csv")
    err = pd.read_csv(tmp_path / "errors.csv")
    for method in ("ls", "wls"):
        p = pos[pos["method"] == method].reset_index(drop=True)
        e = err[err["method"] == method].reset_index(drop=True)
        ok = (p["status"] == "ok").to_numpy()
        h = np.hypot(e["e_err_m"], e["n_err_m"]).to_numpy()
        v = e["u_err_m"].abs().to_numpy()
        bad = ok & ((h > p["hpl_m"].to_numpy()) | (v > p["vpl_m"].to_numpy()))
        assert summary.loc[method, "availability_pct"] == pytest.approx(100 * ok.mean())
        assert summary.loc[method, "misleading_epochs"] == bad.sum()
        assert summary.loc[method, "max_3d_m"] == pytest.approx(e["err_3d_m"][ok].max(), abs=1e-3)


def test_multi_epoch_rows_carry_levels_of_their_own(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The smoother is built from the WLS rows but does not carry WLS's levels: its rows have the
    levels of its own positions (from the WLS epochs' subsets), which differ from WLS's, bound its
    errors, and the summary counts its misleading epochs against them, as the positions say."""
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(SAMPLE / "obs.rnx"), str(SAMPLE / "nav.rnx"), "--method", "wls,smoother",
                                    "--reference-csv", str(SAMPLE / "truth.csv"), "--out-dir", str(tmp_path), "-q"])
    assert exc.value.code == 0, capsys.readouterr().err
    pos = pd.read_csv(tmp_path / "positions.csv")
    wls, smo = pos[pos["method"] == "wls"], pos[pos["method"] == "smoother"]
    assert wls["hpl_m"].notna().all() and smo[["hpl_m", "vpl_m"]].notna().all().all()
    assert not np.allclose(smo["hpl_m"].to_numpy(), wls["hpl_m"].to_numpy())
    ok = smo["status"] == "ok"
    h = np.hypot(smo["e_err_m"], smo["n_err_m"])
    mis = (ok & ((h > smo["hpl_m"]) | (smo["u_err_m"].abs() > smo["vpl_m"]))).sum()
    summary = pd.read_csv(tmp_path / "summary.csv").set_index("method")
    assert summary.loc["smoother", "misleading_epochs"] == mis and summary.loc["wls", "misleading_epochs"] >= 0
