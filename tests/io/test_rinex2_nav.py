"""The RINEX 2 navigation reader: georinex's values, exact toc, GLONASS and SBAS, one-line errors."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import app
from gnss_cli.errors import RinexFormatError
from gnss_cli.io.fixed_width import days_in_month, parse_decimal_ns
from gnss_cli.io.rinex import klobuchar_coefficients, read_nav
from gnss_cli.io.rinex2_nav import FIELD_NAMES_V2, read_nav2

SHARED_NAV2 = [
    "rtklib-0759/07590920.05n",
    "p433-2019/brdc0010.19n",
    "orbits-2021-118/brdc1180.21n",
    "yamatogawa-2010006-kinematic/brdc0060.10n",
]

GPS_HEADER = (
    "     2.11           N: GPS NAV DATA                         RINEX VERSION / TYPE\n"
    "    0.1118D-07  0.1490D-07 -0.5960D-07 -0.5960D-07          ION ALPHA\n"
    "    0.8806D+05  0.1638D+05 -0.1966D+06 -0.1311D+06          ION BETA\n"
    "                                                            END OF HEADER\n"
)
# Table A12 of the RINEX 2.11 format description (GLONASS navigation message file, example)
GLONASS_EXAMPLE = (
    "     2.01           GLONASS NAV DATA                        RINEX VERSION / TYPE\n"
    "ASRINEXG V1.1.0 VM  AIUB                19-FEB-98 10:42     PGM / RUN BY / DATE\n"
    "STATION ZIMMERWALD                                          COMMENT\n"
    "  1998     2    16    0.379979610443D-06                    CORR TO SYSTEM TIME\n"
    "                                                            END OF HEADER\n"
    " 3 98  2 15  0 15  0.0 0.163525342941D-03 0.363797880709D-11 0.108000000000D+05\n"
    "    0.106275903320D+05-0.348924636841D+00 0.931322574615D-09 0.000000000000D+00\n"
    "   -0.944422070313D+04 0.288163375854D+01 0.931322574615D-09 0.210000000000D+02\n"
    "    0.212257280273D+05 0.144599342346D+01-0.186264514923D-08 0.300000000000D+01\n"
    " 4 98  2 15  0 15  0.0 0.179599039257D-03 0.636646291241D-11 0.122400000000D+05\n"
    "    0.562136621094D+04-0.289074897766D+00-0.931322574615D-09 0.000000000000D+00\n"
    "   -0.236819248047D+05 0.102263259888D+01 0.931322574615D-09 0.120000000000D+02\n"
    "    0.324842382812D+04 0.355930233002D+01-0.186264514923D-08 0.300000000000D+01\n"
)


def _georinex(path: Path):
    georinex = pytest.importorskip("georinex")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return georinex.load(path)


def _d19(x: float) -> str:
    return f"{x: .12E}".replace("E", "D")


def _gps_record(prn: int, epoch: str, base: float) -> str:
    """One 8-line GPS record; field k holds ``base + k`` (k = 0..28), the last two slots blank."""
    values = [_d19(base + k) for k in range(29)]
    lines = [f"{prn:2d} {epoch}" + "".join(values[:3])]
    lines += ["   " + "".join(values[3 + 4 * j : 7 + 4 * j]) for j in range(7)]
    return "\n".join(lines) + "\n"


GOOD_BODY = _gps_record(5, "05  4  2  1 59 59.9", 1.0) + _gps_record(12, "05  4  2  2  0  0.0", 100.0)


def _write(tmp_path: Path, text: str, name: str = "t.05n") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


# ---------------------------------------------------------------- georinex as the oracle


@pytest.mark.parametrize("relative", SHARED_NAV2)
def test_every_variable_equals_georinex_and_toc_up_to_its_truncation(rinex_dir: Path, relative: str) -> None:
    path = rinex_dir / relative
    ref = _georinex(path)
    ours = read_nav2(path)
    assert list(ours.data_vars) == list(ref.data_vars) == FIELD_NAMES_V2["G"]
    np.testing.assert_array_equal(ours.sv.values, ref.sv.values)
    lag = ours.time.values - ref.time.values  # georinex truncates the seconds to whole microseconds
    assert np.all((lag >= np.timedelta64(0, "ns")) & (lag < np.timedelta64(1, "us")))
    for name in ref.data_vars:
        np.testing.assert_array_equal(ours[name].values, ref[name].values, err_msg=name)
    for key in ("version", "svtype", "rinextype", "filename"):
        assert ours.attrs[key] == ref.attrs[key], key
    np.testing.assert_array_equal(ours.attrs["ionospheric_corr_GPS"], ref.attrs["ionospheric_corr_GPS"])


def test_read_nav_uses_this_reader_and_keeps_the_toc_exact(tmp_path: Path) -> None:
    path = _write(tmp_path, GPS_HEADER + GOOD_BODY)
    nav = read_nav(path)
    assert nav.time.values[0] == np.datetime64("2005-04-02T01:59:59.900000000")
    ref = _georinex(path)
    assert ref.time.values[0] == np.datetime64("2005-04-02T01:59:59.899999")  # float seconds, truncated
    # the synthetic counting values (M0 = 7 rad, af0 = 1 s, ...) are no possible orbit: read_nav
    # drops them after reading (gnss_cli.io.nav_checks); the reader itself keeps them
    assert "2 GPS navigation record(s) rejected as physically impossible" in nav.attrs["rejected_records"][0]
    raw = read_nav2(path)
    assert raw["M0"].sel(sv="G05").values[0] == 7.0 and raw["FitIntvl"].sel(sv="G12").values[1] == 128.0
    for name in ref.data_vars:
        np.testing.assert_array_equal(raw[name].values, ref[name].values, err_msg=name)
    alpha, beta = klobuchar_coefficients(nav)
    np.testing.assert_array_equal(alpha, [0.1118e-07, 0.1490e-07, -0.5960e-07, -0.5960e-07])
    np.testing.assert_array_equal(beta, [0.8806e05, 0.1638e05, -0.1966e06, -0.1311e06])


def test_glonass_example_of_the_format_description_equals_georinex(tmp_path: Path) -> None:
    path = _write(tmp_path, GLONASS_EXAMPLE, "zimm0460.98g")
    ours = read_nav2(path)
    ref = _georinex(path)
    assert ours.identical(ref)
    assert ours.attrs["svtype"] == ["R"] and "ionospheric_corr_GPS" not in ours.attrs
    assert ours["X"].sel(sv="R03").item() == 0.106275903320e05 * 1000.0  # km -> m
    assert ours["FreqNum"].sel(sv="R04").item() == 12.0
    assert ours.time.values[0] == np.datetime64("1998-02-15T00:15:00")  # UTC, as written


def test_sbas_records_get_the_rinex3_names_in_metres(tmp_path: Path) -> None:
    text = (
        "     2.11           H: GEO NAV MSG DATA                     RINEX VERSION / TYPE\n"
        "                                                            END OF HEADER\n"
        "20 05  4  2  0  1 36.0" + _d19(-1.5e-8) + _d19(0.0) + _d19(518496.0) + "\n"
        "   " + _d19(40000.5) + _d19(0.25) + _d19(0.0) + _d19(0.0) + "\n"
        "   " + _d19(12000.0) + _d19(-0.5) + _d19(1e-6) + _d19(4.0) + "\n"
        "   " + _d19(-100.0) + _d19(0.0) + _d19(0.0) + _d19(7.0) + "\n"
    )
    nav = read_nav2(_write(tmp_path, text, "geo.05h"))
    assert list(nav.sv.values) == ["S20"] and nav.attrs["svtype"] == ["S"]
    assert list(nav.data_vars) == FIELD_NAMES_V2["S"]
    assert nav["X"].item() == 40000500.0 and nav["dY"].item() == -500.0 and nav["dY2"].item() == 1e-3
    assert nav["URA"].item() == 4.0 and nav["IODN"].item() == 7.0 and nav["MessageFrameTime"].item() == 518496.0


def test_gps_and_glonass_files_merge(tmp_path: Path) -> None:
    gps = _write(tmp_path, GPS_HEADER + GOOD_BODY)
    glo = _write(tmp_path, GLONASS_EXAMPLE, "zimm0460.98g")
    nav = read_nav([gps, glo])
    assert list(nav.sv.values) == ["G05", "G12", "R03", "R04"]
    assert nav["dX"].sel(sv="R04").dropna("time").item() == -0.289074897766 * 1000.0
    # a variable both files have keeps each file's values (the GLONASS clocks were once lost)
    assert nav["SVclockBias"].sel(sv="R03").dropna("time").item() == 0.163525342941e-03
    # the GPS records' counting values (af0 = 1 s, 100 s) are dropped as impossible, GLONASS's kept
    assert nav.attrs["rejected_records"] == [r for r in nav.attrs["rejected_records"] if "GPS" in r] != []


def test_repeated_records_kept_once_and_a_different_one_labelled(tmp_path: Path) -> None:
    twin = _gps_record(5, "05  4  2  1 59 59.9", 1.0)
    other = _gps_record(5, "05  4  2  1 59 59.9", 50.0)
    nav = read_nav2(_write(tmp_path, GPS_HEADER + GOOD_BODY + twin + other))
    assert list(nav.sv.values) == ["G05", "G05_1", "G12"]
    assert nav["SVclockBias"].sel(sv="G05_1").dropna("time").item() == 50.0


def test_blank_fit_interval_is_nan_and_trailing_blank_lines_are_ignored(tmp_path: Path) -> None:
    body = GOOD_BODY.rstrip("\n")
    body = body[: body.rfind("\n") + 1] + GOOD_BODY.rstrip("\n").splitlines()[-1][:22] + "\n\n   \n"
    nav = read_nav2(_write(tmp_path, GPS_HEADER + body))
    assert np.isnan(nav["FitIntvl"].sel(sv="G12").values[1])
    assert nav["TransTime"].sel(sv="G12").values[1] == 127.0


def test_crlf_and_gzip_give_the_same_dataset(tmp_path: Path) -> None:
    import gzip

    plain = read_nav2(_write(tmp_path, GPS_HEADER + GOOD_BODY))
    crlf = (GPS_HEADER + GOOD_BODY).replace("\n", "\r\n").encode()
    packed = tmp_path / "t.05n.gz"
    packed.write_bytes(gzip.compress(crlf))
    other = read_nav2(packed)
    assert other.drop_attrs().identical(plain.drop_attrs())
    np.testing.assert_array_equal(other.attrs["ionospheric_corr_GPS"], plain.attrs["ionospheric_corr_GPS"])


# ---------------------------------------------------------------- errors: FILE:LINE: what (expected ..., got ...)

LAST = 4 + 16  # file line of the last record line of GOOD_BODY


def _replace_line(text: str, lineno: int, new: str) -> str:
    lines = text.splitlines(keepends=True)
    lines[lineno - 1] = new
    return "".join(lines)


def _set_field(text: str, lineno: int, slot: int, field: str) -> str:
    line = text.splitlines()[lineno - 1].ljust(79)
    col = 3 + 19 * slot
    return _replace_line(text, lineno, line[:col] + field.rjust(19) + line[col + 19 :] + "\n")


GOOD = GPS_HEADER + GOOD_BODY
ERROR_CASES = {
    "truncated at a line end": ("".join(GOOD.splitlines(keepends=True)[:17]), 17, "truncated record"),
    "cut inside a field": (GOOD[:-30], LAST, "TransTime of G12 (columns 4-22) is not a number"),
    "inf": (_set_field(GOOD, 7, 2, "inf"), 7, "Cus of G05 (columns 42-60) is not a number"),
    "nan": (_set_field(GOOD, 14, 1, "NaN"), 14, "Crs of G12 (columns 23-41) is not a number"),
    "1D+300": (_set_field(GOOD, 8, 3, "0.1000000000D+301"), 8, "Cis of G05 (columns 61-79) is out of range"),
    "letters": (_set_field(GOOD, 6, 0, "0.12x4D+01"), 6, "IODE of G05 (columns 4-22) is not a number"),
    "two signs": (_set_field(GOOD, 6, 0, "1.0-2.0"), 6, "IODE of G05 (columns 4-22) is not a number"),
    "blank field": (_set_field(GOOD, 10, 1, ""), 10, "CodesL2 of G05 (columns 23-41) is blank (expected a D19.12 number, got blanks)"),
    "PRN 0": (_replace_line(GOOD, 13, " 0" + GOOD.splitlines()[12][2:] + "\n"), 13, "bad satellite number"),
    "PRN letters": (_replace_line(GOOD, 5, "G5" + GOOD.splitlines()[4][2:] + "\n"), 5, "bad record start"),
    "February 30": (GOOD.replace(" 5 05  4  2  1 59", " 5 05  2 30  1 59"), 5, "impossible time of clock"),
    "month 13": (GOOD.replace("12 05  4  2  2  0", "12 05 13  2  2  0"), 13, "impossible time of clock"),
    "hour 24": (GOOD.replace("12 05  4  2  2  0", "12 05  4  2 24  0"), 13, "impossible time of clock"),
    "second 61": (GOOD.replace("59 59.9", "59 61.0"), 5, "impossible time of clock"),
    "seconds not a number": (GOOD.replace("59 59.9", "59 5x.9"), 5, "bad record start"),
    "no END OF HEADER": (GOOD.replace("END OF HEADER", "COMMENT      "), 5, "header not terminated"),
    "header only, no END OF HEADER": (GPS_HEADER.replace("END OF HEADER", "COMMENT"), 4, "header not terminated"),
    "missing line mid-file": (_replace_line(GOOD, 11, ""), 12, "incomplete record"),
    "extra line": (_replace_line(GOOD, 12, GOOD.splitlines()[11] + "\n" + GOOD.splitlines()[11] + "\n"), 13,
                   "record too long"),
    "text before the first record": (_replace_line(GOOD, 5, "   junk\n" + GOOD.splitlines()[4] + "\n"), 5,
                                     "no record start"),
    "no records": (GPS_HEADER + "\n", 5, "no navigation records"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(ERROR_CASES))
def test_malformed_file_gives_one_line_naming_file_and_line(tmp_path: Path, case: str) -> None:
    text, line, what = ERROR_CASES[case]
    path = _write(tmp_path, text)
    with pytest.raises(RinexFormatError) as info:
        read_nav(path)
    message = str(info.value)
    assert info.value.exit_code == 4
    assert "\n" not in message and "\r" not in message
    assert message.startswith(f"t.05n:{line}: {what}"), message
    assert "(expected " in message and ", got " in message


def test_truncated_last_record_names_its_start_and_line_count(tmp_path: Path) -> None:
    text = "".join(GOOD.splitlines(keepends=True)[:16])  # the second record keeps 4 of its 8 lines
    with pytest.raises(RinexFormatError, match=r"^t\.05n:16: truncated record: the file ends inside the record of satellite 12 "
                       r"starting on line 13 \(expected 8 lines, got 4\)$"):
        read_nav2(_write(tmp_path, text))


def test_unreadable_ion_alpha_drops_the_coefficients_with_a_reason(tmp_path: Path) -> None:
    text = GOOD.replace("0.1490D-07 -0.5960D-07", "0.1490D-07 -0.59xxD-07", 1)
    nav = read_nav2(_write(tmp_path, text))
    assert "ionospheric_corr_GPS" not in nav.attrs and klobuchar_coefficients(nav) is None
    assert nav.attrs["ionospheric_corr_problem"].startswith("t.05n:2: ION ALPHA does not parse (expected ")
    infinite = read_nav2(_write(tmp_path, GOOD.replace("0.8806D+05", "0.8806D+99").replace("0.1638D+05", "    1D+300")))
    assert infinite.attrs["ionospheric_corr_problem"].startswith("t.05n:3: ION BETA does not parse")
    assert nav["M0"].sel(sv="G05").values[0] == 7.0  # the records are still read


def test_other_rinex2_types_and_versions_are_refused_with_line_one(tmp_path: Path) -> None:
    galileo = GOOD.replace("N: GPS NAV DATA", "L: GALILEO NAV ")
    with pytest.raises(RinexFormatError, match=r"^t\.05n:1: not a RINEX 2 navigation file read here .*got version 2\.11 and type 'L'\)$"):
        read_nav2(_write(tmp_path, galileo))
    with pytest.raises(RinexFormatError, match=r"^t\.05n:1: not a RINEX 2 navigation file read here .*got version 3\.04"):
        read_nav2(_write(tmp_path, GOOD.replace("     2.11", "     3.04")))


def test_systems_filter(tmp_path: Path) -> None:
    path = _write(tmp_path, GOOD)
    assert read_nav2(path, systems=["G", "R"]).sizes["sv"] == 2
    with pytest.raises(RinexFormatError, match="no navigation records of the systems R"):
        read_nav2(path, systems=["R"])


# ---------------------------------------------------------------- decoders


def test_decimal_seconds_are_exact_and_malformed_ones_refused() -> None:
    fields = [b"59.9 ", b" 0.0 ", b"   12", b"1.25 ", b"0.123456789", b" 1 .0", b"-1.0 ", b"1.2.3", b"     "]
    width = max(len(f) for f in fields)
    chars = np.frombuffer(b"".join(f.ljust(width) for f in fields), dtype=np.uint8).reshape(len(fields), width)
    ns, ok = parse_decimal_ns(chars)
    assert ok.tolist() == [True] * 5 + [False] * 4
    assert ns[:5].tolist() == [59_900_000_000, 0, 12_000_000_000, 1_250_000_000, 123_456_789]


def test_days_in_month_follows_the_gregorian_leap_rule() -> None:
    years = np.array([1900, 2000, 2004, 2005, 2005, 2005])
    months = np.array([2, 2, 2, 2, 12, 13])
    assert days_in_month(years, months).tolist() == [28, 29, 29, 28, 31, 0]


# ---------------------------------------------------------------- through the command line


def _solve(args: list[object], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(a) for a in args])
    out, err = capsys.readouterr()
    return int(exc.value.code or 0), out, err


def test_cli_truncated_nav_file_exits_4_naming_the_nav_file(
    rinex_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cut = tmp_path / "07590920.05n"
    cut.write_bytes((rinex_dir / "rtklib-0759" / "07590920.05n").read_bytes()[:3000])  # inside the fourth record
    code, out, err = _solve([rinex_dir / "rtklib-0759" / "07590920.05o", cut, "-q"], capsys)
    assert code == 4 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "07590920.05n:" in lines[0] and "07590920.05o" not in lines[0]
    assert "is not a number" in lines[0] or "truncated record" in lines[0]


def test_cli_bad_ion_alpha_warns_once_and_uses_the_default_coefficients(
    rinex_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    obs = rinex_dir / "rtklib-0759" / "07590920.05o"
    text = (rinex_dir / "rtklib-0759" / "07590920.05n").read_text()
    bad = tmp_path / "07590920.05n"
    bad.write_text(text.replace("1.4900D-08", "1.49ooD-08", 1))
    no_ion = tmp_path / "noion" / "07590920.05n"
    no_ion.parent.mkdir()
    no_ion.write_text("".join(ln for ln in text.splitlines(keepends=True) if "ION ALPHA" not in ln and "ION BETA" not in ln))
    code, out, err = _solve([obs, bad, "--method", "wls"], capsys)
    assert code == 0, err
    warned = [ln for ln in err.splitlines() if "ION ALPHA" in ln]
    assert len(warned) == 1 and "07590920.05n:8: ION ALPHA does not parse" in warned[0]
    assert "using the default coefficients" in warned[0]
    code, out_no_ion, _ = _solve([obs, no_ion, "--method", "wls"], capsys)
    assert code == 0 and out == out_no_ion  # the same fallback as a header without the lines
