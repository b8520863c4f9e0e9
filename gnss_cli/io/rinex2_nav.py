"""Vectorized reader for RINEX 2.xx navigation files: GPS (``N``), GLONASS (``G``) and SBAS (``H``).

A RINEX 2 navigation record is a fixed number of lines: GPS 8, GLONASS and SBAS (GEO) 4.
Its first line holds the satellite number (``I2``), the time of clock (toc: two-digit year,
month, day, hour, minute as ``I2`` fields and seconds as ``F5.1``) and three ``D19.12``
fields; each further line holds a 3-column indent and four ``D19.12`` fields. All fields of
all records sit at columns 4, 23, 42 and 61 (1-based), so they are cut out of the whole
file as one ``(n_lines, 4, 19)`` character grid (:mod:`gnss_cli.io.fixed_width`) and
converted in one call, as in :mod:`gnss_cli.io.rinex3_nav`.

The result has the layout of ``georinex.load(path)`` for these files (georinex 1.16; it
does not read SBAS files, which get the RINEX 3 names): dims ``(time, sv)``, ``time`` the
toc, the variables of :data:`FIELD_NAMES_V2`, GLONASS and SBAS positions, velocities and
accelerations converted from km to m, attributes ``version``, ``svtype``, ``rinextype``,
``filename`` and ``ionospheric_corr_GPS`` (ION ALPHA then ION BETA). One difference: the
toc keeps its written seconds exactly (``59.9`` is 59.9 s), where georinex goes through a
binary float and truncates to whole microseconds (59.899999 s).

Validation: every error is one line ``FILE:LINE: what is wrong (expected ..., got ...)``
raised as :class:`~gnss_cli.errors.RinexFormatError` -- a header without ``END OF HEADER``,
a record start that does not parse, a satellite number out of range, an impossible date or
time of day, a record with too few or too many lines (a file cut mid-record), a field that
is not a ``D19.12`` number (``inf``, ``nan``, letters, a number cut short by the end of the
file) or whose magnitude needs a three-digit exponent (``1D+300``). Blank fields are
errors too, except the last one of each record (GPS fit interval, GLONASS age of
information, SBAS IODN), which writers may leave out; it is then NaN. ION ALPHA / ION BETA
lines that do not parse do not stop the file: the coefficients are dropped and the
reason is kept in the attribute ``ionospheric_corr_problem``, so that the run warns once and
falls back to default coefficients. Whether the values are physically plausible is checked
after reading, not here.

References
----------
RINEX 2.11 format description (IGS/RTCM-SC104, 2012), section 6 and tables A3, A4, A10-A12,
A15-A16; georinex 1.16 ``nav2.py`` for the variable names.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import xarray
from numpy.typing import NDArray

from gnss_cli.errors import RinexFormatError
from gnss_cli.io.compression import open_bytes
from gnss_cli.io.fixed_width import (
    DIGIT0, DOT, MINUS, SPACE, civil2datetime64, civil_ranges_ok, days_in_month, gather_columns, parse_decimal_ns,
    parse_uint_fields, split_lines, sv_codes2str,
)  # fmt: skip
from gnss_cli.io.rinex3_header import parse_version_line, validate_systems
from gnss_cli.io.rinex3_nav import FIELD_NAMES, drop_identical_records, records2dataset, systems_in_order

__all__ = ["read_nav2", "FIELD_NAMES_V2", "RECORD_LINES"]

SYSTEM_OF_FILE_TYPE = {"N": "G", "G": "R", "H": "S"}
"""System letter of each RINEX 2 navigation file type read here (column 21 of line 1)."""

RECORD_LINES = {"G": 8, "R": 4, "S": 4}
"""Lines per record of each system."""

FIELD_NAMES_V2: dict[str, list[str]] = {"G": FIELD_NAMES["G"][:29], "R": FIELD_NAMES["R"], "S": FIELD_NAMES["S"]}
"""Variable names per system in record order: georinex's (GPS without the two spares of
the last line, which RINEX 2.11 leaves blank); SBAS as the RINEX 3 reader names them."""

_PRN_RANGE = {"G": (1, 63), "R": (1, 63), "S": (20, 58)}
"""Valid satellite numbers: GPS PRN 1-63 (IS-GPS-200), GLONASS slot 1-63, SBAS PRN - 100."""

_SYSTEM_NAMES = {"G": "GPS PRN", "R": "GLONASS slot", "S": "SBAS PRN - 100"}
_KM_FIELDS = {"X", "dX", "dX2", "Y", "dY", "dY2", "Z", "dZ", "dZ2"}
_FIELD_WIDTH = 19
_FIELD_COLUMNS = (3, 22, 41, 60)
"""0-based first column of the four ``D19.12`` slots of every record line (slot 0 of a
first line is the toc)."""
_START_SPANS = ((0, 2), (2, 5), (5, 8), (8, 11), (11, 14), (14, 17))
"""Columns of the satellite number, year, month, day, hour and minute (with the blank before each)."""
_SECONDS = (17, 22)
_MAX_ABS = 1e100
"""``D19.12`` has a two-digit exponent: a larger magnitude cannot be written in the field."""
_NUMBER_CHARS = np.zeros(256, dtype=bool)
_NUMBER_CHARS[[DIGIT0 + k for k in range(10)] + [DOT, MINUS, ord("+"), ord("D"), ord("d"), ord("E"), ord("e")]] = True


def _error(name: str, line: int, what: str, expected: str, got: str) -> RinexFormatError:
    return RinexFormatError(f"{name}:{line}: {what} (expected {expected}, got {got})")


def _show(chars: NDArray[np.uint8]) -> str:
    return repr(chars.tobytes().decode("ascii", "replace").rstrip())


def _split_header(content: bytes, name: str) -> tuple[list[str], int]:
    """Header lines (through ``END OF HEADER``) and the offset of the first body byte."""
    pos, lines = 0, []
    while pos < len(content):
        nl = content.find(b"\n", pos)
        end = len(content) if nl < 0 else nl + 1
        line = content[pos:end].decode("ascii", "replace").rstrip("\r\n")
        lines.append(line)
        label = line[60:].strip()
        if "END OF HEADER" in line:
            return lines, end
        if lines[1:] and label and not (label[0].isalpha() or label[0] == "#"):  # a number: records began
            raise _error(name, len(lines), "header not terminated", "an 'END OF HEADER' line before the records",
                         f"a line without a header label: {line.rstrip()[:40]!r}")
        pos = end
    raise _error(name, len(lines), "header not terminated", "an 'END OF HEADER' line", "the end of the file")


def _header_attrs(lines: list[str], name: str) -> tuple[dict[str, Any], str]:
    """Attributes from the header and the system letter of the file."""
    version, file_type, _ = parse_version_line(lines[0], f"{name}:1")
    system = SYSTEM_OF_FILE_TYPE.get(file_type.upper())
    if not 2.0 <= version < 3.0 or system is None:
        raise _error(name, 1, "not a RINEX 2 navigation file read here",
                     "version 2.xx and file type N (GPS), G (GLONASS) or H (SBAS) in column 21",
                     f"version {version} and type {file_type!r}")
    attrs: dict[str, Any] = {"version": version, "svtype": [system], "rinextype": "nav", "filename": name}
    iono: dict[str, NDArray[np.float64]] = {}
    problems: list[str] = []
    for lineno, line in enumerate(lines, 1):
        label = line[60:].strip()
        if label not in ("ION ALPHA", "ION BETA"):
            continue
        texts = [line[2 + 12 * i : 14 + 12 * i] for i in range(4)]
        try:
            values = np.array([float(t.upper().replace("D", "E")) for t in texts])
        except ValueError:
            values = np.full(4, np.nan)
        if np.all(np.isfinite(values) & (np.abs(values) < _MAX_ABS)):
            iono[label] = values
        else:
            problems.append(f"{name}:{lineno}: {label} does not parse (expected four D12.4 numbers, "
                            f"got {line[:50].rstrip()!r})")
    if problems:
        attrs["ionospheric_corr_problem"] = problems[0] + "; Klobuchar coefficients not used"
    elif "ION ALPHA" in iono and "ION BETA" in iono:
        attrs["ionospheric_corr_GPS"] = np.hstack((iono["ION ALPHA"], iono["ION BETA"]))
    return attrs, system


def _record_lines(
    head: NDArray[np.uint8], lineno: NDArray[np.int64], n_lines: int, name: str
) -> NDArray[np.int64]:
    """Index of each record's first line; every record must have ``n_lines`` lines.

    A record starts on each line with text in its first three columns (further lines are
    indented by three blanks).
    """
    is_start = np.any(head[:, :3] != SPACE, axis=1)
    first = np.flatnonzero(is_start)
    if first.size == 0 or first[0] != 0:
        raise _error(name, int(lineno[0]), "no record start", "a satellite number and toc in columns 1-22",
                     _show(head[0]))
    count = np.diff(np.append(first, head.shape[0]))
    bad = np.flatnonzero(count != n_lines)
    if bad.size == 0:
        return first
    r = int(bad[0])
    start, got = int(first[r]), int(count[r])
    prn = head[start, :2].tobytes().decode("ascii", "replace").strip()
    where = f"the record of satellite {prn} starting on line {int(lineno[start])}"
    if got > n_lines:
        i = start + n_lines
        raise _error(name, int(lineno[i]), f"record too long: {where} has more than {n_lines} lines",
                     "a new record (satellite number and toc in columns 1-22)", _show(head[i]))
    if r == first.size - 1:
        raise _error(name, int(lineno[-1]), f"truncated record: the file ends inside {where}",
                     f"{n_lines} lines", f"{got}")
    raise _error(name, int(lineno[start + got]), f"incomplete record: {where} is followed by a new record",
                 f"{n_lines} lines", f"{got}")


def _record_starts(
    fl: NDArray[np.uint8], lineno: NDArray[np.int64], system: str, name: str
) -> tuple[NDArray[np.int64], NDArray[np.datetime64]]:
    """Satellite codes and exact toc from the records' first lines ``' 1 19  1  1  0  0  0.0'``."""
    (prn, yy, month, day, hour, minute), ok = parse_uint_fields(fl, _START_SPANS)
    sec_ns, ok_sec = parse_decimal_ns(fl[:, _SECONDS[0] : _SECONDS[1]])
    bad = np.flatnonzero(~(ok & ok_sec))
    if bad.size:
        i = int(bad[0])
        raise _error(name, int(lineno[i]), "bad record start", "'PP YY MM DD HH MM SS.S' in columns 1-22",
                     _show(fl[i]))
    year = yy + np.where(yy < 80, 2000, 1900)  # RINEX 2: 80-99 are 1980-1999
    low, high = _PRN_RANGE[system]
    bad = np.flatnonzero((prn < low) | (prn > high))
    if bad.size:
        i = int(bad[0])
        raise _error(name, int(lineno[i]), "bad satellite number",
                     f"{_SYSTEM_NAMES[system]} {low}-{high} in columns 1-2",
                     _show(fl[i, :2]))
    sec_ok = sec_ns < 61_000_000_000
    valid = civil_ranges_ok(month, day, hour, minute, np.zeros_like(month)) & sec_ok
    valid &= day <= days_in_month(year, month)
    bad = np.flatnonzero(~valid)
    if bad.size:
        i = int(bad[0])
        raise _error(name, int(lineno[i]), "impossible time of clock",
                     "a calendar date, hour 0-23, minute 0-59 and second 0-60.9", _show(fl[i, 2:22]))
    toc = civil2datetime64(year, month, day, (hour * 60 + minute) * 60_000_000_000 + sec_ns)
    return (ord(system) << 16) | ((prn // 10 + DIGIT0) << 8) | (prn % 10 + DIGIT0), toc


def _field_values(
    grid: NDArray[np.uint8], line: NDArray[np.int64], optional: NDArray[np.bool_], describe: Callable[[int], str],
    name: str,
) -> NDArray[np.float64]:
    """Decode the ``D19.12`` fields ``grid`` ``(n, 19)``; blank optional fields give NaN.

    ``line`` is the file line of each field and ``describe(k)`` names field ``k`` in a message.
    """
    blank = np.all(grid == SPACE, axis=1)
    # a number is right-aligned in its field (a field cut short by the end of the file is not)
    # and made of digits, sign, point and exponent letter only ('inf', 'nan' are not)
    bad_text = ~blank & ((grid[:, -1] == SPACE) | ~np.all(_NUMBER_CHARS[grid] | (grid == SPACE), axis=1))
    text = np.where((grid == ord("D")) | (grid == ord("d")), np.uint8(ord("E")), grid)
    values = np.full(grid.shape[0], np.nan)
    ok = ~blank & ~bad_text
    try:
        values[ok] = np.ascontiguousarray(text[ok]).view(f"S{_FIELD_WIDTH}").ravel().astype(np.float64)
    except ValueError:  # characters of a number in an impossible order ('1-2', '..'): find them
        for k in np.flatnonzero(ok):
            try:
                values[k] = float(text[k].tobytes())
            except ValueError:
                bad_text[k] = True
    problems = [
        (blank & ~optional, "is blank", "a D19.12 number"),
        (bad_text, "is not a number", "a D19.12 number such as ' 0.123456789012D+01'"),
        (ok & ~bad_text & ~(np.abs(values) < _MAX_ABS), "is out of range", "a finite D19.12 number, |x| < 1e100"),
    ]
    found = [(int(np.argmax(mask)), what, expected) for mask, what, expected in problems if mask.any()]
    if found:
        k, what, expected = min(found)
        got = _show(grid[k]) if ok[k] or bad_text[k] else "blanks"
        raise _error(name, int(line[k]), f"{describe(k)} {what}", expected, got)
    return values


def _record_values(
    buf: NDArray[np.uint8], starts: NDArray[np.int64], lengths: NDArray[np.int64], lineno: NDArray[np.int64],
    first: NDArray[np.int64], system: str, sv: NDArray[np.str_], name: str,
) -> NDArray[np.float64]:
    """The fields of every record, ``(n_records, len(FIELD_NAMES[system]))`` in file order."""
    names = FIELD_NAMES_V2[system]
    n_lines = RECORD_LINES[system]
    line_idx = (first[:, None] + np.arange(n_lines)).ravel()
    ordinal = np.tile(np.arange(n_lines), first.size)
    record = np.repeat(np.arange(first.size), n_lines)
    field_no = (4 * ordinal - 1)[:, None] + np.arange(4)  # slot 0 of the first line is the toc: field -1
    usable = (field_no >= 0) & (field_no < len(names))
    li, mi = np.nonzero(usable)
    cols = np.asarray(_FIELD_COLUMNS, dtype=np.int64)[mi]
    grid = gather_columns(buf, starts[line_idx[li]], lengths[line_idx[li]], cols, _FIELD_WIDTH)
    fno, rec = field_no[li, mi], record[li]

    def describe(k: int) -> str:
        c = int(cols[k])
        return f"{names[fno[k]]} of {sv[rec[k]]} (columns {c + 1}-{c + _FIELD_WIDTH})"

    values_flat = _field_values(grid, lineno[line_idx[li]], fno == len(names) - 1, describe, name)
    values = np.full((first.size, len(FIELD_NAMES[system])), np.nan)
    values[rec, fno] = values_flat
    return values


def read_nav2(path: str | os.PathLike[str], systems: Sequence[str] | None = None) -> xarray.Dataset:
    """Read a RINEX 2.xx GPS, GLONASS or SBAS navigation file into a ``(time, sv)`` dataset.

    Parameters
    ----------
    path : str or os.PathLike
        Navigation file, plain or compressed (gz, Z, zip, bz2).
    systems : sequence of str, optional
        System letters to keep; a file of another system then has no records (an error).
        Default: keep the file's system.

    Returns
    -------
    xarray.Dataset
        Dims ``(time, sv)``: ``time`` datetime64[ns], the toc as written (GPS time for GPS
        and SBAS, UTC for GLONASS, not converted), exact to the nanosecond, sorted; ``sv``
        ids such as ``'G01'``, ``'R07'``, ``'S20'`` (SBAS PRN 120), sorted. One float64
        variable per name of :data:`FIELD_NAMES_V2` (units as broadcast: s, s/s, m, rad,
        rad/s, sqrt(m); GLONASS and SBAS positions in m, velocities in m/s, accelerations
        in m/s^2), NaN where a satellite has no record at that toc. A satellite with two
        different records at the same toc gets the second under ``'G01_1'``; identical
        repeated records are kept once. Attributes ``version``, ``svtype`` (``['G']``),
        ``rinextype`` (``'nav'``), ``filename``, and ``ionospheric_corr_GPS`` (alpha0..3
        in s, s/semicircle, ...; beta0..3 in s, s/semicircle, ...) when the header has
        both ION ALPHA and ION BETA, or ``ionospheric_corr_problem`` (one line) when one
        of them does not parse.

    Raises
    ------
    InputFileNotFoundError
        ``path`` does not exist.
    RinexFormatError
        See the module docstring; the message is ``FILE:LINE: what (expected ..., got ...)``.
    UsageError
        ``systems`` holds something other than RINEX system letters.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> text = (
    ...     "     2.11           N: GPS NAV DATA                         RINEX VERSION / TYPE\\n"
    ...     "                                                            END OF HEADER\\n"
    ...     " 5 05  4  2  1 59 59.9" + " 0.100000000000D-03" * 3 + "\\n"
    ...     + ("    0.200000000000D+01" + " 0.300000000000D+01" * 3 + "\\n") * 7)
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "x.05n"
    >>> _ = path.write_text(text)
    >>> nav = read_nav2(path)
    >>> str(nav.time.values[0]), float(nav["M0"].sel(sv="G05")[0])
    ('2005-04-02T01:59:59.900000000', 3.0)
    """
    wanted = validate_systems(systems)
    name = Path(path).name
    content = open_bytes(path)
    if not content.strip():
        raise _error(name, 1, "empty file", "a RINEX 2 navigation header", "no text")
    header_lines, hdr_end = _split_header(content, name)
    attrs, system = _header_attrs(header_lines, name)
    buf, starts, lengths = split_lines(content[hdr_end:])
    n_body = starts.size
    while n_body and not buf[starts[n_body - 1] : starts[n_body - 1] + lengths[n_body - 1]].tobytes().strip():
        n_body -= 1  # trailing blank lines are not records
    if n_body == 0:
        raise _error(name, len(header_lines) + 1, "no navigation records", "records after 'END OF HEADER'",
                     "the end of the file")
    starts, lengths = starts[:n_body], lengths[:n_body]
    lineno = np.arange(n_body, dtype=np.int64) + len(header_lines) + 1
    head = gather_columns(buf, starts, lengths, 0, 22)
    first = _record_lines(head, lineno, RECORD_LINES[system], name)
    sv_code, toc = _record_starts(head[first], lineno[first], system, name)
    values = _record_values(buf, starts, lengths, lineno, first, system, sv_codes2str(sv_code), name)
    if wanted is not None and system not in wanted:
        raise RinexFormatError(f"{name}: no navigation records of the systems {''.join(wanted)} "
                               f"(the file holds system {system} only)")
    sv_code, toc, values = drop_identical_records(sv_code, toc, values)
    ds = records2dataset(sv_code, toc, values, systems_in_order(sv_code))
    ds = ds[FIELD_NAMES_V2[system]]
    ds.attrs.update(attrs)
    return ds
