"""Physically impossible navigation records are rejected, named, and never used; real records
of every shared file pass."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import app
from gnss_cli.gnss.ephemeris import KeplerEphemeris
from gnss_cli.gnss.orbits import broadcast_states
from gnss_cli.io.nav_checks import KEPLER_LIMITS, STATE_LIMITS, klobuchar_problem, reject_implausible_records
from gnss_cli.io.rinex import klobuchar_coefficients, read_nav

NAV_FILES = [
    "rtklib-0759/07590920.05n",
    "p433-2019/brdc0010.19n",
    "orbits-2021-118/brdc1180.21n",
    "yamatogawa-2010006-kinematic/brdc0060.10n",
    "esbc-2020177/ESBC00DNK_R_20201770000_01D_MN.rnx.gz",
    "kms3-2022159-rinex4/KMS300DNK_R_20221591000_01H_MN.rnx.gz",
    "smartloc-berlin-2016158-urban-kinematic/BRDC00WRD_U_20161580000_01D_MN.rnx.gz",
    "tst2-2020155-urban-static/hksc155d.20b",
    "tst2-2020155-urban-static/hksc155d.20g",
    "tst2-2020155-urban-static/hksc155d.20l",
    "tst2-2020155-urban-static/hksc155d.20n",
]


@pytest.mark.parametrize("name", NAV_FILES)
def test_every_real_record_passes(rinex_dir: Path, name: str) -> None:
    """The limits are not tighter than what satellites really broadcast (Galileo clocks of
    several ms, SBAS accelerations of 1e-4 m/s^2, QZSS eccentricity 0.075 included)."""
    nav = read_nav(rinex_dir / name)
    assert nav.attrs["rejected_records"] == []
    assert klobuchar_problem(nav.attrs["ionospheric_corr_GPS"]) is None if "ionospheric_corr_GPS" in nav.attrs else True


@pytest.fixture(scope="module")
def nav0759(rinex_dir: Path) -> xr.Dataset:
    return read_nav(rinex_dir / "rtklib-0759" / "07590920.05n")


def _cell(nav: xr.Dataset) -> tuple[int, int]:
    ti, si = np.argwhere(np.isfinite(nav["sqrtA"].values))[0]
    return int(ti), int(si)


@pytest.mark.parametrize("field", sorted(KEPLER_LIMITS))
@pytest.mark.parametrize("value", [np.inf, np.nan, 1e300, -1e300])
def test_an_absurd_value_in_any_orbit_or_clock_field_rejects_that_record_only(nav0759, field, value) -> None:  # type: ignore[no-untyped-def]
    bad = nav0759.copy(deep=True)
    ti, si = _cell(bad)
    bad[field].values[ti, si] = value
    out, messages = reject_implausible_records(bad, "x.05n")
    assert len(messages) == 1 and "1 GPS navigation record(s) rejected" in messages[0]
    assert field in messages[0] and str(bad["sv"].values[si]) in messages[0] and "x.05n" in messages[0]
    kept = np.isfinite(out["sqrtA"].values)
    assert not kept[ti, si]
    assert kept.sum() == np.isfinite(nav0759["sqrtA"].values).sum() - 1


@pytest.mark.parametrize("field", ["Cic", "Cis", "Cuc", "Cus", "Crs", "SVclockBias", "IDOT", "DeltaN", "OmegaDot"])
def test_each_limit_sits_between_the_largest_real_value_and_a_value_just_beyond_it(nav0759, field) -> None:  # type: ignore[no-untyped-def]
    low, high = KEPLER_LIMITS[field]
    real = np.nanmax(np.abs(nav0759[field].values))
    assert real < high and -real > low
    for value, rejected in ((high * 0.999, False), (high * 1.001, True), (low * 1.001, True)):
        bad = nav0759.copy(deep=True)
        ti, si = _cell(bad)
        bad[field].values[ti, si] = value
        if field in ("Crs",):  # the radius bound must not be what rejects it
            bad["Crc"].values[ti, si] = 0.0
        assert bool(reject_implausible_records(bad)[1]) is rejected, (field, value)


def test_the_radius_bound_holds_over_real_orbits_and_rejects_a_shrunk_orbit(nav0759) -> None:  # type: ignore[no-untyped-def]
    """An independent propagation over the fit interval stays inside the closed-form bound
    the check uses, and an orbit with sqrtA 10 % low (radius 21,500 km: still inside the
    shell) passes while one 30 % low (13,000 km) is rejected."""
    eph = KeplerEphemeris.from_dataset(nav0759)
    idx = np.repeat(np.arange(len(eph)), 25)
    t = eph.toe_gps_s[idx] + np.tile(np.linspace(-7200, 7200, 25), len(eph))
    radius = np.linalg.norm(broadcast_states(eph, idx, t).pos_ecef_m, axis=-1)
    a = eph.sqrt_a_sqrt_m**2
    harmonic = np.abs(eph.crs_m) + np.abs(eph.crc_m)
    assert np.all(radius >= (a * (1 - eph.e) - harmonic)[idx]) and np.all(radius <= (a * (1 + eph.e) + harmonic)[idx])
    for scale, rejected in ((0.9, False), (0.7, True), (1.4, True)):
        bad = nav0759.copy(deep=True)
        ti, si = _cell(bad)
        bad["sqrtA"].values[ti, si] *= scale
        messages = reject_implausible_records(bad)[1]
        assert bool(messages) is rejected
        assert not rejected or "orbit radius outside 15,000-50,000 km" in messages[0]


def test_glonass_state_vectors_are_checked_by_radius_speed_and_clock(rinex_dir: Path) -> None:
    nav = read_nav(rinex_dir / "tst2-2020155-urban-static" / "hksc155d.20g")
    ti, si = np.argwhere(np.isfinite(nav["X"].values))[0]
    for field, value, reason in (("X", 1e9, "orbit radius"), ("dY", 9000.0, "dY outside"),
                                 ("SVclockBias", 3e-3, "SVclockBias outside"), ("dZ2", -np.inf, "dZ2 outside")):
        bad = nav.copy(deep=True)
        bad[field].values[ti, si] = value
        out, messages = reject_implausible_records(bad, "g")
        assert len(messages) == 1 and "GLONASS" in messages[0] and reason in messages[0]
        assert np.isnan(out["X"].values[ti, si])
    assert set(STATE_LIMITS) <= set(nav.data_vars)


def test_a_record_before_its_system_began_is_rejected(nav0759) -> None:  # type: ignore[no-untyped-def]
    early = nav0759.isel(time=[0]).assign_coords(time=[np.datetime64("1979-12-31T00:00", "ns")])
    messages = reject_implausible_records(early)[1]
    assert messages and "before the system's start" in messages[0]


def test_klobuchar_coefficients_beyond_their_broadcast_range_are_dropped_with_a_reason(nav0759) -> None:  # type: ignore[no-untyped-def]
    alpha_beta = np.asarray(nav0759.attrs["ionospheric_corr_GPS"], dtype=float)
    assert klobuchar_coefficients(nav0759) is not None
    for i, value in ((0, 1e300), (5, np.nan), (7, -1e9)):
        bad = alpha_beta.copy()
        bad[i] = value
        assert klobuchar_problem(bad) is not None
        assert klobuchar_coefficients(nav0759.assign_attrs(ionospheric_corr_GPS=bad)) is None


def _mutate_nav(src: Path, dst: Path, record: int, line: int, field: int, text: str) -> None:
    """Write ``src`` with field ``field`` (0-3) of line ``line`` (0-7) of GPS record ``record`` replaced."""
    lines = src.read_text().splitlines()
    start = next(i for i, x in enumerate(lines) if "END OF HEADER" in x) + 1 + 8 * record + line
    cols = (3 + 19 * field, 3 + 19 * (field + 1)) if line else (22 + 19 * (field - 1), 22 + 19 * field)
    old = lines[start].ljust(80)
    lines[start] = old[: cols[0]] + text.rjust(19) + old[cols[1]:]
    dst.write_text("\n".join(lines) + "\n")


def _solve(args: list[object], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(a) for a in args])
    return int(exc.value.code or 0), capsys.readouterr().err


def test_a_corrupt_record_on_the_command_line_is_named_and_the_fix_equals_the_run_without_it(
    rinex_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Cic = 1.5 rad on one record (the fuzz case that moved a fix 277 km): the run warns with
    the record and gives the same positions as a nav file without that record at all."""
    obs, nav = rinex_dir / "rtklib-0759" / "07590920.05o", rinex_dir / "rtklib-0759" / "07590920.05n"
    corrupt = tmp_path / "cic.05n"
    _mutate_nav(nav, corrupt, record=0, line=3, field=1, text="1.500000000000D+00")
    lines = nav.read_text().splitlines()
    start = next(i for i, x in enumerate(lines) if "END OF HEADER" in x) + 1
    without = tmp_path / "without.05n"
    without.write_text("\n".join(lines[:start] + lines[start + 8:]) + "\n")
    code, err = _solve([obs, corrupt, "-o", tmp_path / "a.csv", "--method", "wls"], capsys)
    assert code == 0
    assert "cic.05n: 1 GPS navigation record(s) rejected as physically impossible" in err and "Cic outside" in err
    code, _ = _solve([obs, without, "-o", tmp_path / "b.csv", "--method", "wls"], capsys)
    a, b = pd.read_csv(tmp_path / "a.csv"), pd.read_csv(tmp_path / "b.csv")
    assert code == 0 and len(a) == len(b) == 120
    assert np.abs(a[["x_m", "y_m", "z_m"]].to_numpy() - b[["x_m", "y_m", "z_m"]].to_numpy()).max() < 1e-4


def test_absurd_klobuchar_coefficients_fall_back_to_the_defaults_with_a_warning(
    rinex_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    obs, nav = rinex_dir / "rtklib-0759" / "07590920.05o", rinex_dir / "rtklib-0759" / "07590920.05n"
    text = nav.read_text().splitlines()
    i = next(k for k, x in enumerate(text) if "ION ALPHA" in x)
    text[i] = "    1.0000D+10" + text[i][14:]  # alpha0 (2X, D12.4) = 1e10 s: parses, far beyond +-1.2e-7 s
    bad = tmp_path / "ion.05n"
    bad.write_text("\n".join(text) + "\n")
    code, err = _solve([obs, bad, "-o", tmp_path / "a.csv", "--method", "wls"], capsys)
    assert code == 0, err
    assert "Klobuchar coefficients not used: alpha0" in err and "default coefficients" in err
    assert "Warning" not in err and "RuntimeWarning" not in err
    assert (pd.read_csv(tmp_path / "a.csv")["status"] == "ok").all()


def test_a_record_whose_date_was_damaged_is_rejected_by_its_week_and_toe(nav0759) -> None:  # type: ignore[no-untyped-def]
    """The fuzz case of a GPS record re-dated 1980 (still after GPS began): its week and Toe
    say 2005, so it is rejected; a week rolled over by 1024 is accepted."""
    ti, si = _cell(nav0759)
    redated = nav0759.isel(time=[ti]).assign_coords(time=[np.datetime64("1985-04-02T02:00", "ns")])
    messages = reject_implausible_records(redated)[1]
    assert messages and "week and Toe more than 6 h from the time of clock" in messages[0]
    rolled = nav0759.copy(deep=True)
    rolled["GPSWeek"].values[:] = rolled["GPSWeek"].values - 1024
    assert reject_implausible_records(rolled)[1] == []
    shifted = nav0759.copy(deep=True)
    shifted["Toe"].values[ti, si] += 7 * 3600.0
    assert "week and Toe" in reject_implausible_records(shifted)[1][0]


def test_a_corrupt_deflate_stream_is_a_format_error_naming_the_file(rinex_dir: Path, tmp_path: Path) -> None:
    """zlib.error is no OSError: a gzip whose deflate data are damaged was an internal error."""
    import gzip
    import zlib

    from gnss_cli.errors import RinexFormatError

    raw = gzip.compress((rinex_dir / "rtklib-0759" / "07590920.05n").read_bytes())
    for pos in range(300, len(raw) - 8, 61):
        bad = bytearray(raw)
        bad[pos] ^= 0xFF
        try:
            gzip.decompress(bytes(bad))
        except zlib.error:
            break
        except (OSError, EOFError):
            continue
    else:
        pytest.skip("no single-byte flip gave a zlib error")
    path = tmp_path / "bad.05n.gz"
    path.write_bytes(bytes(bad))
    with pytest.raises(RinexFormatError, match=r"bad\.05n\.gz: cannot read file"):
        read_nav(path)
