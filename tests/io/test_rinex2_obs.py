"""The RINEX 2 observation reader: georinex's values, exact time tags, every epoch flag, errors."""

from __future__ import annotations

import re
import warnings
from decimal import Decimal
from pathlib import Path

import numpy as np
import pytest

from gnss_cli.config import load_config
from gnss_cli.errors import RinexFormatError
from gnss_cli.io.rinex import read_obs
from gnss_cli.io.rinex2_obs import parse_seconds_ns, read_obs2
from gnss_cli.pipeline.epochs import load_epochs

RINEX_DIR = Path(__file__).resolve().parents[2] / ".." / "shared" / "rinex"
SHARED_RINEX2 = [
    RINEX_DIR / "rtklib-0759" / "07590920.05o",
    RINEX_DIR / "smartloc-berlin-2016158-urban-kinematic" / "Berlin_Potsdamer_Platz.obs.gz",
    RINEX_DIR / "yamatogawa-2010006-kinematic" / "yamatogawa_rover.obs",
]
NAV_0759 = RINEX_DIR / "rtklib-0759" / "07590920.05n"

HEADER = (
    "     2.11           OBSERVATION DATA    M (MIXED)           RINEX VERSION / TYPE\n"
    "{types}"
    "                                                            END OF HEADER\n"
)
TYPES2 = "     2    C1    L1                                          # / TYPES OF OBSERV\n"


def _need(path: Path) -> Path:
    if not path.is_file():
        pytest.skip(f"shared RINEX data not found: {path}")
    return path


def _write(tmp_path: Path, body: str, types: str = TYPES2, name: str = "t.10o") -> Path:
    path = tmp_path / name
    path.write_text(HEADER.format(types=types) + body)
    return path


def _epoch(sec: str, sats: list[str], flag: int = 0) -> str:
    ids = "".join(sats[:12])
    line = f" 10  3  5  0  0{sec:>11}  {flag}{len(sats):3d}{ids}\n"
    for k in range(12, len(sats), 12):
        line += " " * 32 + "".join(sats[k:k + 12]) + "\n"
    return line


def _record(*values: float) -> str:
    fields = [f"{v:14.3f}  " for v in values]
    return "".join("".join(fields[k:k + 5]).rstrip() + "\n" for k in range(0, len(fields), 5))


# ---------------------------------------------------------------- georinex as the oracle


def _epoch_texts(path: Path) -> list[str]:
    """Decimal text of every ordinary epoch's time tag, read with a regular expression."""
    from gnss_cli.io.compression import open_text

    pattern = re.compile(r"^ (\d\d) (..) (..) (..) (..)(.{11})  [01](...)", re.M)
    body = open_text(path).split("END OF HEADER", 1)[1]
    return [m.groups() for m in pattern.finditer(body) if int(m[7]) > 0]


@pytest.mark.parametrize("path", SHARED_RINEX2, ids=lambda p: p.name)
def test_values_equal_georinex_and_times_equal_the_text(path: Path) -> None:
    georinex = pytest.importorskip("georinex")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = georinex.load(_need(path))
    ours = read_obs2(path)
    np.testing.assert_array_equal(ours.sv.values, ref.sv.values.astype("<U3"))
    assert list(ours.data_vars) == list(ref.data_vars)
    for code in ref.data_vars:
        np.testing.assert_array_equal(ours[code].values, ref[code].values)
    # georinex truncates to whole milliseconds: at most 1 ms early, never late
    lag = (ours.time.values - ref.time.values.astype("datetime64[ns]")).astype(np.int64)
    assert np.all((lag >= 0) & (lag <= 1_000_000))
    expected = []
    for yy, mo, dd, hh, mi, ss, _ in _epoch_texts(path):
        day = np.datetime64(f"20{yy}-{int(mo):02d}-{int(dd):02d}T{int(hh):02d}:{int(mi):02d}", "ns")
        expected.append(day + np.timedelta64(int(Decimal(ss) * 10**9), "ns"))
    np.testing.assert_array_equal(ours.time.values, np.unique(np.array(expected)))


def test_filters_equal_georinex_use_and_meas() -> None:
    georinex = pytest.importorskip("georinex")
    path = _need(SHARED_RINEX2[1])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = georinex.load(path, use={"G"}, meas=["C1"])
    ours = read_obs(path, systems=["G"], codes=["C1"])
    np.testing.assert_array_equal(ours.sv.values, ref.sv.values.astype("<U3"))
    np.testing.assert_array_equal(ours["C1"].values, ref["C1"].values)


# ---------------------------------------------------------------- exact time tags


def test_seconds_text_to_nanoseconds() -> None:
    assert parse_seconds_ns(" 29.9990000") == 29_999_000_000
    assert parse_seconds_ns("  0.0000001") == 100
    assert parse_seconds_ns(" 41.7") == 41_700_000_000
    for bad in (" 4x.7000000", "  ", " -1.0000000", " 1.2.3"):
        with pytest.raises(ValueError, match="seconds"):
            parse_seconds_ns(bad)


def test_sub_millisecond_tag_is_exact(tmp_path: Path) -> None:
    path = _write(tmp_path, _epoch("29.9999999", ["G01"]) + _record(2.2e7, 1.0))
    t = read_obs2(path).time.values[0]
    assert t == np.datetime64("2010-03-05T00:00:29.999999900", "ns")


def test_satellites_are_evaluated_at_the_exact_time(tmp_path: Path) -> None:
    """Same pseudoranges tagged 29.998, 29.999 and 30.000 s: the middle satellite positions
    lie halfway between the others (a 1 ms tag error would move them by metres)."""
    nav = _need(NAV_0759)
    sats = ["G01", "G03", "G07", "G11", "G14", "G20"]
    prs = [2.25e7, 2.3e7, 2.1e7, 2.4e7, 2.2e7, 2.35e7]
    out = {}
    for sec in ("29.9980000", "29.9990000", "30.0000000"):
        body = (" 05  4  2  0  0" + f"{sec:>11}" + f"  0{len(sats):3d}" + "".join(sats) + "\n"
                + "".join(_record(p, 0.0) for p in prs))
        path = _write(tmp_path, body, name=f"e{sec}.05o")
        out[sec] = load_epochs(path, [nav], load_config(overrides={"methods": "wls", "systems": ["G"]}))
    t = {k: v.time_gps_s[0] for k, v in out.items()}
    # float64 GPS seconds since 1980 resolve 0.12 us; the reader itself is exact to 1 ns
    assert abs((t["29.9990000"] - t["29.9980000"]) - 1e-3) < 2.5e-7
    assert abs((t["30.0000000"] - t["29.9990000"]) - 1e-3) < 2.5e-7
    a, b, c = (out[k].sat_ecef_m[0] for k in ("29.9980000", "29.9990000", "30.0000000"))
    assert np.count_nonzero(np.isfinite(b[:, 0])) >= 4  # the satellites the nav file has
    assert np.nanmax(np.abs(c - a)) > 1.0  # the satellites move metres per millisecond
    np.testing.assert_allclose(b, (a + c) / 2, atol=1e-5, equal_nan=True)


# ---------------------------------------------------------------- record structure


def test_continuation_lines_for_many_satellites_and_types(tmp_path: Path) -> None:
    types = ("     7    C1    L1    P1    P2    L2    S1    S2            # / TYPES OF OBSERV\n")
    sats = [f"G{k:02d}" for k in range(1, 15)]  # 14 satellites: two id lines
    body = _epoch("30.0000000", sats)
    for k in range(14):
        body += _record(*(1000.0 * k + j for j in range(7)))
    ds = read_obs2(_write(tmp_path, body, types=types))
    assert list(ds.sv.values) == sats
    assert float(ds["S2"].sel(sv="G14").values[0]) == 13006.0
    assert float(ds["C1"].sel(sv="G13").values[0]) == 12000.0


def test_event_flags_are_skipped_and_empty_epochs_do_not_hang(tmp_path: Path) -> None:
    body = (
        _epoch("30.0000000", ["G01"]) + _record(1.0, 2.0)
        + "                           4  2\n"  # flag 4: two header lines follow, no time
        + "  comment                                                   COMMENT\n"
        + "     2    C1    L1                                          # / TYPES OF OBSERV\n"
        + _epoch("45.0000000", ["G01"], flag=6) + _record(9.0, 9.0)  # cycle-slip records
        + _epoch("50.0000000", [], flag=0)  # an epoch with no satellite
        + _epoch("55.0000000", ["G01"], flag=5) + "  a special record                                           COMMENT\n"
        + _epoch("59.0000000", ["G02"], flag=1) + _record(3.0, 4.0)
    )
    ds = read_obs2(_write(tmp_path, body))
    assert list(ds.time.values.astype("datetime64[s]").astype(str)) == ["2010-03-05T00:00:30", "2010-03-05T00:00:59"]
    assert float(ds["C1"].sel(sv="G02").values[1]) == 3.0


def test_truncated_record_names_the_line(tmp_path: Path) -> None:
    body = _epoch("30.0000000", ["G01", "G02"]) + _record(1.0, 2.0)
    with pytest.raises(RinexFormatError, match=r"t\.10o: line 4: record cut short"):
        read_obs2(_write(tmp_path, body))


def test_more_fields_than_the_header_names_the_line(tmp_path: Path) -> None:
    body = _epoch("30.0000000", ["G01", "G02"]) + _record(1.0, 2.0) + _record(1.0, 2.0, 3.0)
    with pytest.raises(RinexFormatError, match=r"t\.10o: line 6: more observations than the 2"):
        read_obs2(_write(tmp_path, body))


def test_fewer_record_lines_than_the_header_needs_names_the_line(tmp_path: Path) -> None:
    types = "     6    C1    L1    P1    P2    L2    S1                  # / TYPES OF OBSERV\n"
    body = _epoch("30.0000000", ["G01"]) + _record(1.0, 2.0) + _epoch("31.0000000", ["G01"]) + _record(1.0)
    with pytest.raises(RinexFormatError, match=r"t\.10o: bad epoch line 7"):
        read_obs2(_write(tmp_path, body, types=types))


def test_shared_malformed_rinex2_files_name_file_and_problem() -> None:
    mal = RINEX_DIR / "malformed"
    with pytest.raises(RinexFormatError, match=r"badtime\.10o: bad epoch line 5"):
        read_obs2(_need(mal / "badtime.10o"))
    with pytest.raises(RinexFormatError, match=r"wrong_obs2_count\.10o: line \d+: header declares 6 observation types but lists 7"):
        read_obs2(_need(mal / "wrong_obs2_count.10o"))


def test_impossible_date_bad_satellite_id_and_no_records_are_one_line_errors(tmp_path: Path) -> None:
    bad_date = _epoch("30.0000000", ["G01"]).replace(" 10  3  5", " 10  2 31") + _record(1.0, 2.0)
    with pytest.raises(RinexFormatError, match=r"t\.10o: bad epoch line 4"):
        read_obs2(_write(tmp_path, bad_date))
    sats = [f"G{k:02d}" for k in range(1, 13)] + ["X01"]
    bad_id = _epoch("30.0000000", sats) + _record(1.0, 2.0) * 13
    with pytest.raises(RinexFormatError, match=r"t\.10o: bad satellite id 'X01' on line 5"):
        read_obs2(_write(tmp_path, bad_id))
    with pytest.raises(RinexFormatError, match=r"t\.10o: no observation records"):
        read_obs2(_write(tmp_path, _epoch("30.0000000", []) + _epoch("31.0000000", [])))


# ---------------------------------------------------------------- epochs strictly increasing


@pytest.mark.parametrize(
    ("body", "lines", "times"),
    [
        (_epoch("30.0000000", ["G01"]) + _record(1.0, 2.0) + _epoch("30.0000000", ["G02"]) + _record(3.0, 4.0),
         (6, 4), ("2010-03-05T00:00:30", "2010-03-05T00:00:30")),  # the same epoch twice
        (_epoch("30.0000000", ["G01"]) + _record(1.0, 2.0) + _epoch("59.0000000", ["G01"]) + _record(1.0, 2.0)
         + _epoch("59.0000000", ["G01"]) + _record(1.0, 2.0), (8, 6), ("2010-03-05T00:00:59", "2010-03-05T00:00:59")),
        (_epoch("30.0000000", ["G01"]) + _record(1.0, 2.0) + _epoch("29.9990000", ["G01"]) + _record(1.0, 2.0),
         (6, 4), ("2010-03-05T00:00:29.999", "2010-03-05T00:00:30")),  # back by 1 ms
    ],
    ids=["duplicate", "restamped", "backwards"],
)
def test_an_epoch_not_later_than_the_one_before_is_rejected_with_both_lines(
        tmp_path: Path, body: str, lines: tuple[int, int], times: tuple[str, str]) -> None:
    with pytest.raises(RinexFormatError) as info:
        read_obs2(_write(tmp_path, body))
    assert str(info.value) == (f"t.10o: line {lines[0]}: epoch {times[0]} is not later than the epoch {times[1]} "
                               f"on line {lines[1]} (repeated or out-of-order epoch)")


def test_a_body_written_twice_is_rejected_where_the_copy_starts(tmp_path: Path) -> None:
    body = "".join(_epoch(f"{s}.0000000", ["G01", "G02"]) + _record(1.0, 2.0) * 2 for s in (0, 30))
    with pytest.raises(RinexFormatError, match=r"t\.10o: line 10: epoch 2010-03-05T00:00:00 is not later than "
                                               r"the epoch 2010-03-05T00:00:30 on line 7"):
        read_obs2(_write(tmp_path, body * 2))


def test_cycle_slip_records_may_repeat_the_time_of_their_epoch(tmp_path: Path) -> None:
    body = (_epoch("30.0000000", ["G01"]) + _record(1.0, 2.0) + _epoch("30.0000000", ["G01"], flag=6)
            + _record(0.0, 1.0) + _epoch("59.0000000", ["G01"]) + _record(3.0, 4.0))
    assert read_obs2(_write(tmp_path, body))["C1"].values.ravel().tolist() == [1.0, 3.0]


@pytest.mark.parametrize("count", ["-1", " -1", "-99", "  x"])
def test_a_negative_or_garbage_satellite_count_is_a_bad_epoch_line(tmp_path: Path, count: str) -> None:
    line = _epoch("30.0000000", ["G01"])
    body = line[:29] + count.rjust(3) + line[32:] + _record(1.0, 2.0)
    with pytest.raises(RinexFormatError, match=r"t\.10o: bad epoch line 4"):
        read_obs2(_write(tmp_path, body))


def test_a_file_cut_inside_a_record_names_the_line(tmp_path: Path) -> None:
    epoch = _epoch("30.0000000", ["G01", "G02"])
    body = epoch + _record(1000.0, 2.0) + _record(24767686.375, 4.0)
    with pytest.raises(RinexFormatError, match=r"t\.10o: line 4: record cut short"):
        read_obs2(_write(tmp_path, epoch + _record(1000.0, 2.0)))
    cut = body.rindex("24767686.375") + len("24767686")  # the last value loses its decimals
    with pytest.raises(RinexFormatError, match=r"t\.10o: line 6: the file ends inside observation 1 of the line"):
        read_obs2(_write(tmp_path, body[:cut]))
    whole = body.rstrip("\n").rsplit("\n", 1)[0] + "\n" + _record(24767686.375).rstrip("\n")  # no line end, no cut
    assert read_obs2(_write(tmp_path, whole))["C1"].values.ravel().tolist() == [1000.0, 24767686.375]
