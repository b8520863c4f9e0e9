"""DOP with one receiver clock per system: the reference clock's TDOP and per-system TDOP columns.

The covariance is recomputed here from the satellite positions and the solution alone:
line-of-sight unit vectors, a 10 deg elevation mask from the geodetic up direction, one
clock column per system with satellites (QZSS in GPS's unless it has its own), ``(A^T A)^-1`` (LS: the noise gain ``J J^T`` is
this matrix).
"""

from __future__ import annotations

import numpy as np
import pymap3d
import pytest

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import app
from gnss_cli.config import load_config
from gnss_cli.pipeline import EpochStatus, RunResult, load_epochs, solve_method
from gnss_cli.report import dop_table, positions_table

KMS3 = "kms3-2022159-rinex4"
KMS3_OBS = "KMS300DNK_R_20221591000_01H_30S_MO.crx"
KMS3_NAV = "KMS300DNK_R_20221591000_01H_MN.rnx.gz"


@pytest.fixture(scope="module")
def kms3_ls(rinex_dir):
    d = rinex_dir / KMS3
    cfg = load_config(overrides={"methods": "ls"})  # systems: all (G, E, C, J, R in this file)
    data = load_epochs(d / KMS3_OBS, [d / KMS3_NAV], cfg)
    return data, solve_method(data, "ls", cfg)


def _independent_cov(data, x_ecef_m: np.ndarray, t: int) -> tuple[np.ndarray, list[str], int]:
    """(A^T A)^-1 at epoch t over the systems with satellites above 10 deg, those systems, and
    the number of satellites."""
    lat, lon, _ = pymap3d.ecef2geodetic(*x_ecef_m[t], deg=False)
    up = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    rows, systems = [], []
    for j in np.flatnonzero(data.usable[t]):
        d = data.sat_ecef_m[t, j] - x_ecef_m[t]
        u = d / np.linalg.norm(d)
        if np.degrees(np.arcsin(u @ up)) < 10.0:
            continue
        clock = "G" if data.sv[j][0] == "J" and "J" not in data.systems else data.sv[j][0]  # QZSS on GPS time
        rows.append((u, clock))
        if clock not in systems:
            systems.append(clock)
    systems = [s for s in data.systems if s in systems]
    A = np.array([np.concatenate([-u, [1.0 if s == sy else 0.0 for sy in systems]]) for u, s in rows])
    return np.linalg.inv(A.T @ A), systems, len(rows)


def test_per_system_tdop_is_the_clock_diagonal_of_the_independent_covariance(kms3_ls):
    data, sol = kms3_ls
    assert len(data.systems) >= 4 and data.systems[0] == "G"
    assert "J" not in data.systems and data.usable[:, np.char.startswith(data.sv, "J")].any()  # QZSS on GPS's clock
    assert sol.tdops is not None and sol.tdops.shape == (data.time_gps_s.size, len(data.systems))
    checked = 0
    for t in np.flatnonzero(sol.status == EpochStatus.OK):
        cov, present, n_sat = _independent_cov(data, sol.x_ecef_m, t)
        assert sol.n_sat[t] == n_sat
        for j, system in enumerate(data.systems):
            if system in present:
                expected = np.sqrt(cov[3 + present.index(system), 3 + present.index(system)])
                assert sol.tdops[t, j] == pytest.approx(expected, rel=1e-6), (t, system)
                checked += 1
            else:  # no satellite of the system: its clock is fixed by a constraint, no TDOP
                assert np.isnan(sol.tdops[t, j])
        # the reference clock is the first system; GDOP includes every clock
        assert sol.tdop[t] == sol.tdops[t, 0]
        assert sol.gdop[t] == pytest.approx(np.sqrt(np.trace(cov)), rel=1e-6)
    assert checked >= 19 * 3


def test_dop_table_has_a_tdop_column_per_system_and_tdop_is_the_first(kms3_ls):
    data, sol = kms3_ls
    dop = dop_table(positions_table(RunResult(data, {"ls": sol})))
    per_system = [f"tdop_{s}" for s in data.systems]
    assert list(dop.columns) == ["time", "gps_week", "tow_s", "method", "n_sat", "gdop", "pdop", "hdop", "vdop",
                                 "tdop", *per_system, "status"]
    assert np.array_equal(dop["tdop"].to_numpy(), dop[per_system[0]].to_numpy(), equal_nan=True)


def test_systems_order_sets_the_reference_clock(rinex_dir, capsys):
    d = rinex_dir / KMS3
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(d / KMS3_OBS), str(d / KMS3_NAV), "--systems", "E,G", "-q"])
    assert exc.value.code == 0
    lines = capsys.readouterr().out.splitlines()
    header = lines[0].split(",")
    assert header[header.index("tdop") + 1: header.index("status")] == ["tdop_E", "tdop_G"]
    for line in lines[1:]:
        cells = line.split(",")
        assert cells[header.index("tdop")] == cells[header.index("tdop_E")] != ""


def test_single_system_run_keeps_the_five_dop_columns(rinex_dir, capsys):
    d = rinex_dir / "rtklib-0759"
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(d / "07590920.05o"), str(d / "07590920.05n"), "-q"])
    assert exc.value.code == 0
    header = capsys.readouterr().out.splitlines()[0].split(",")
    assert not [c for c in header if c.startswith("tdop_")]
