"""A broadcast record whose orbit-and-clock sigma (URA) exceeds 300 m keeps its satellite out of
the solution, as RTKLIB's ``MAX_VAR_EPH`` does (``satellites.csv`` reason ``ephemeris_sigma``).
Weighted instead, such a satellite adds a degree of freedom to the residual test and nothing to
the position (a damaged URA let reflected signals pass the test in the urban canyon)."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import pytest

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import app
from gnss_cli.gnss.broadcast import MAX_EPHEMERIS_SIGMA_M


def _nav_with_ura(src: Path, dst: Path, prn: int, ura_m: float) -> int:
    """Copy the RINEX 2 GPS nav ``src`` with the SV accuracy of every record of ``prn`` set to
    ``ura_m``; the number of records changed."""
    lines = src.read_text().split("\n")
    body = next(i for i, line in enumerate(lines) if "END OF HEADER" in line) + 1
    changed = 0
    for i in range(body, len(lines) - 7):
        if re.match(rf"^ ?{prn} \d\d [ \d]\d", lines[i]):
            row = lines[i + 6]
            lines[i + 6] = row[:3] + f"{ura_m:19.12E}".replace("E", "D") + row[22:]
            changed += 1
    dst.write_text("\n".join(lines))
    return changed


def _run(tmp: Path, name: str, *args: str) -> tuple[list[dict], list[dict]]:
    out = tmp / name
    with pytest.raises(SystemExit) as exit_:
        run_app(app, "gnss-solve", [*args, "--quiet", "--out-dir", str(out)])
    assert exit_.value.code == 0
    with open(out / "positions.csv", newline="") as f:
        positions = list(csv.DictReader(f))
    with open(out / "satellites.csv", newline="") as f:
        satellites = list(csv.DictReader(f))
    return positions, satellites


@pytest.mark.parametrize("ura_m", [384.0, 266340.0])
def test_a_record_beyond_300_m_is_as_if_the_satellite_were_excluded(rinex_dir: Path, tmp_path: Path,
                                                                     ura_m: float) -> None:
    d = rinex_dir / "rtklib-0759"
    obs = str(d / "07590920.05o")
    nav = tmp_path / "07590920.05n"
    assert _nav_with_ura(d / "07590920.05n", nav, 7, ura_m) >= 1
    damaged, sats = _run(tmp_path, "damaged", obs, str(nav))
    excluded, _ = _run(tmp_path, "excluded", obs, str(d / "07590920.05n"), "--exclude", "G07")
    g07 = [r for r in sats if r["satellite"] == "G07"]
    assert g07 and all(r["used"] == "0" for r in g07)
    assert {r["reason"] for r in g07} <= {"ephemeris_sigma", "below_mask"} and \
        any(r["reason"] == "ephemeris_sigma" for r in g07)
    assert ura_m > MAX_EPHEMERIS_SIGMA_M
    # the same rows as a run that leaves G07 out by hand
    keys = ("x_m", "y_m", "z_m", "n_sat", "status", "test_stat", "hpl_m", "vpl_m")
    assert [[r[k] for k in keys] for r in damaged] == [[r[k] for k in keys] for r in excluded]


def test_a_record_at_the_limit_is_used(rinex_dir: Path, tmp_path: Path) -> None:
    """URA 192 m (index 9) is weighted, not excluded: G07 stays in the solution."""
    d = rinex_dir / "rtklib-0759"
    nav = tmp_path / "07590920.05n"
    _nav_with_ura(d / "07590920.05n", nav, 7, 192.0)
    _, sats = _run(tmp_path, "limit", str(d / "07590920.05o"), str(nav))
    assert any(r["satellite"] == "G07" and r["used"] == "1" for r in sats)
