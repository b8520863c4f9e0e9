"""Fast vectorized reader for RINEX 3.0x and 4.0x navigation (broadcast ephemeris) files.

Records are located over the whole decompressed buffer with numpy; the 19-character
``D19.12`` fields of all records are cut out as one ``(n_lines, 4, 19)`` character grid
and converted in one call. The result has the layout of ``georinex.load(nav_path)`` for
RINEX 3 navigation files: dims ``(time, sv)``, ``time`` the time of clock (toc) of each
record, one float64 variable per broadcast parameter with georinex's names (see
:data:`FIELD_NAMES`), NaN where a satellite has no record at that time.

RINEX 4 files hold typed records (``> EPH G01 LNAV``). Read here: EPH records LNAV
(GPS, QZSS, NavIC), INAV / FNAV (Galileo), D1 / D2 (BeiDou), FDMA (GLONASS) and SBAS;
their body has the RINEX 3 layout. Skipped: CNAV / CNV1 / CNV2 / CNV3 / L1NV / ... EPH
records (new civil messages with other layouts), STO (system time offset) and EOP (Earth
orientation) records. ION records of types LNAV (GPS Klobuchar), IFNV (Galileo NeQuick)
and D1D2 (BeiDou Klobuchar) fill the ``ionospheric_corr_*`` attributes.

References
----------
RINEX 3.05 tables A6-A15 and RINEX 4.00 tables A31-A52 (IGS/RTCM-SC104); georinex 1.16
``nav3.py`` for the variable names.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import xarray
from numpy.typing import NDArray

from gnss_cli.errors import RinexFormatError, UsageError
from gnss_cli.io.compression import open_bytes
from gnss_cli.io.rinex3_obs import (
    SYSTEM_CHARS,
    civil2datetime64,
    gather_columns,
    parse_float_fields,
    parse_uint_columns,
    check_rinex34_type,
    split_lines,
    sv_codes2str,
)

__all__ = ["read_nav3", "FIELD_NAMES"]

_KEPLER_GPS = [
    "SVclockBias", "SVclockDrift", "SVclockDriftRate", "IODE", "Crs", "DeltaN", "M0",
    "Cuc", "Eccentricity", "Cus", "sqrtA", "Toe", "Cic", "Omega0", "Cis", "Io", "Crc",
    "omega", "OmegaDot", "IDOT", "CodesL2", "GPSWeek", "L2Pflag", "SVacc", "health",
    "TGD", "IODC", "TransTime", "FitIntvl", "spare0", "spare1",
]  # fmt: skip

FIELD_NAMES: dict[str, list[str]] = {
    "G": _KEPLER_GPS,
    "J": list(_KEPLER_GPS),
    "E": [
        "SVclockBias", "SVclockDrift", "SVclockDriftRate", "IODnav", "Crs", "DeltaN", "M0",
        "Cuc", "Eccentricity", "Cus", "sqrtA", "Toe", "Cic", "Omega0", "Cis", "Io", "Crc",
        "omega", "OmegaDot", "IDOT", "DataSrc", "GALWeek", "spare0", "SISA", "health",
        "BGDe5a", "BGDe5b", "TransTime", "spare1", "spare2", "spare3",
    ],
    "C": [
        "SVclockBias", "SVclockDrift", "SVclockDriftRate", "AODE", "Crs", "DeltaN", "M0",
        "Cuc", "Eccentricity", "Cus", "sqrtA", "Toe", "Cic", "Omega0", "Cis", "Io", "Crc",
        "omega", "OmegaDot", "IDOT", "spare0", "BDTWeek", "spare1", "SVacc", "SatH1",
        "TGD1", "TGD2", "TransTime", "AODC", "spare2", "spare3",
    ],
    "I": [
        "SVclockBias", "SVclockDrift", "SVclockDriftRate", "IODEC", "Crs", "DeltaN", "M0",
        "Cuc", "Eccentricity", "Cus", "sqrtA", "Toe", "Cic", "Omega0", "Cis", "Io", "Crc",
        "omega", "OmegaDot", "IDOT", "spare0", "BDTWeek", "spare1", "URA", "health",
        "TGD", "spare2", "TransTime", "spare3", "spare4", "spare5",
    ],
    "R": [
        "SVclockBias", "SVrelFreqBias", "MessageFrameTime", "X", "dX", "dX2", "health",
        "Y", "dY", "dY2", "FreqNum", "Z", "dZ", "dZ2", "AgeOpInfo",
    ],
    "S": [
        "SVclockBias", "SVrelFreqBias", "MessageFrameTime", "X", "dX", "dX2", "health",
        "Y", "dY", "dY2", "URA", "Z", "dZ", "dZ2", "IODN",
    ],
}  # fmt: skip
"""Variable names per system, in record order, as georinex 1.16 names them.

Units as broadcast (RINEX): s, s/s, s/s^2, m, rad, rad/s, sqrt(m), s of week; GLONASS
and SBAS positions, velocities and accelerations are converted from km, km/s, km/s^2 to
m, m/s, m/s^2 (as georinex does). Fields after the last name (the 4th GLONASS line of
RINEX 3.05 / 4.00) are not read.
"""

_KM_FIELDS = {"X", "dX", "dX2", "Y", "dY", "dY2", "Z", "dZ", "dZ2"}

_RINEX4_EPH_TYPES = {
    "G": {"LNAV"}, "J": {"LNAV"}, "I": {"LNAV"}, "E": {"INAV", "FNAV"},
    "C": {"D1", "D2"}, "R": {"FDMA"}, "S": {"SBAS"},
}  # fmt: skip
"""RINEX 4 EPH message types whose body has the RINEX 3 layout (read); others are skipped."""

_ION_ATTRS = {("G", "LNAV"): "ionospheric_corr_GPS", ("E", "IFNV"): "ionospheric_corr_GAL",
              ("C", "D1D2"): "ionospheric_corr_BDS", ("J", "LNAV"): "ionospheric_corr_QZS",
              ("I", "LNAV"): "ionospheric_corr_IRN"}  # fmt: skip
_ION_COUNTS = {"ionospheric_corr_GAL": 3}  # others: alpha0..3, beta0..3

_FIELD_WIDTH = 19
_N_FIELDS = 31
_SPACE = 32


def _read_nav_header(header: str, name: str) -> dict[str, Any]:
    lines = header.splitlines()
    version, _ = check_rinex34_type(lines[0], name, "N")
    attrs: dict[str, Any] = {"version": version, "rinextype": "nav"}
    iono: dict[str, NDArray[np.float64]] = {}
    for lineno, line in enumerate(lines[1:], start=2):
        if line[60:].strip() != "IONOSPHERIC CORR":
            continue
        kind = line[:4].strip()
        n = 3 if kind == "GAL" else 4
        try:
            iono[kind] = np.array(
                [float(line[5 + 12 * i : 17 + 12 * i].upper().replace("D", "E")) for i in range(n)]
            )
        except ValueError:
            raise RinexFormatError(f"{name}: bad IONOSPHERIC CORR header line {lineno}") from None
    for a, b, key in (("GPSA", "GPSB", "GPS"), ("QZSA", "QZSB", "QZS"), ("BDSA", "BDSB", "BDS"),
                      ("IRNA", "IRNB", "IRN")):  # fmt: skip
        if a in iono and b in iono:
            attrs[f"ionospheric_corr_{key}"] = np.hstack((iono[a], iono[b]))
    if "GAL" in iono:
        attrs["ionospheric_corr_GAL"] = iono["GAL"]
    return attrs


class _Records:
    """Decoded records of one file: satellite codes, toc, values ``(n, 31)``, in file order."""

    __slots__ = ("sv_code", "toc", "values")

    def __init__(self, sv_code: NDArray[np.int64], toc: NDArray[np.datetime64], values: NDArray[np.float64]):
        self.sv_code = sv_code
        self.toc = toc
        self.values = values


def _parse_d19(chars: NDArray[np.uint8], lineno: NDArray[np.int64], name: str) -> NDArray[np.float64]:
    """Decode ``D19.12`` fields ``(n, 19)``; blank fields give NaN."""
    blank = np.all(chars == _SPACE, axis=1)
    out = np.full(chars.shape[0], np.nan)
    filled = np.flatnonzero(~blank)
    if filled.size == 0:
        return out
    sub = chars[filled]
    sub = np.where((sub == ord("D")) | (sub == ord("d")), np.uint8(ord("E")), sub)
    out[filled] = parse_float_fields(sub, lineno[filled], name, "number", strip=True)
    return out


def _read_one(path: str | os.PathLike[str], systems: set[str] | None) -> tuple[_Records, dict[str, Any]]:
    name = Path(path).name
    content = open_bytes(path)
    if not content or content.isspace():
        raise RinexFormatError(f"{name}: empty file")
    pos = content.find(b"END OF HEADER")
    if pos < 0:
        raise RinexFormatError(f"{name}: no 'END OF HEADER' line (not a RINEX file, or truncated)")
    nl = content.find(b"\n", pos)
    hdr_end = len(content) if nl < 0 else nl + 1
    header = content[:hdr_end].decode("ascii", errors="replace")
    attrs = _read_nav_header(header, name)
    attrs["filename"] = name
    n_header_lines = header.count("\n")

    buf, starts, lengths = split_lines(content[hdr_end:])
    lineno = np.arange(starts.size, dtype=np.int64) + n_header_lines + 1
    head = gather_columns(buf, starts, lengths, 0, 14)
    if attrs["version"] >= 4.0:
        layout = _layout_v4(buf, starts, lengths, head, lineno, attrs, name)
    else:
        layout = _layout_v3(head, lineno, name)
    line_idx, ordinal, rec_of_line, first_lines = layout

    if first_lines.size == 0:
        raise RinexFormatError(f"{name}: no navigation records")
    # satellite and toc from each record's first line: 'G01 2020 06 24 23 15 00'
    fl = gather_columns(buf, starts[first_lines], lengths[first_lines], 0, 23)
    sys_chars = fl[:, 0]
    known = np.isin(sys_chars, np.frombuffer(SYSTEM_CHARS.encode(), dtype=np.uint8))
    prn, ok_prn = parse_uint_columns(fl[:, 1:3])
    year, ok_y = parse_uint_columns(fl[:, 4:8])
    month, ok_mo = parse_uint_columns(fl[:, 9:11])
    day, ok_d = parse_uint_columns(fl[:, 12:14])
    hour, ok_h = parse_uint_columns(fl[:, 15:17])
    minute, ok_mi = parse_uint_columns(fl[:, 18:20])
    sec, ok_s = parse_uint_columns(fl[:, 21:23])
    ok = (known & ok_prn & ok_y & ok_mo & ok_d & ok_h & ok_mi & ok_s & (month >= 1) & (month <= 12)
          & (day >= 1) & (day <= 31) & (hour <= 23) & (minute <= 59) & (sec <= 60))  # fmt: skip
    if not np.all(ok):
        i = int(np.flatnonzero(~ok)[0])
        text = fl[i].tobytes().decode("ascii", "replace").rstrip()
        raise RinexFormatError(
            f"{name}: bad record start (satellite / epoch) on line {int(lineno[first_lines[i]])}: {text!r}"
        )
    toc = civil2datetime64(year, month, day, ((hour * 60 + minute) * 60 + sec) * 1_000_000_000)
    c1 = (prn // 10) + 48
    c2 = (prn % 10) + 48
    sv_code = (sys_chars.astype(np.int64) << 16) | (c1 << 8) | c2

    # field grid: first line fields at columns 23, 42, 61; later lines at 4, 23, 42, 61
    n_rec = first_lines.size
    col0 = np.where(ordinal == 0, 23, 4).astype(np.int64)
    l_starts, l_lengths = starts[line_idx], lengths[line_idx]
    grid = np.stack(
        [gather_columns(buf, l_starts, l_lengths, col0 + _FIELD_WIDTH * m, _FIELD_WIDTH) for m in range(4)],
        axis=1,
    )  # (n_lines, 4, 19)
    field_no = np.where(ordinal == 0, 0, 3 + 4 * (ordinal - 1))[:, None] + np.arange(4)
    usable = (field_no < _N_FIELDS) & ~((ordinal == 0)[:, None] & (np.arange(4) == 3))
    li, mi = np.nonzero(usable)
    values_flat = _parse_d19(grid[li, mi], lineno[line_idx[li]], name)
    # record index of each line, renumbered 0..n_rec-1 in file order
    rec_numbers, rec_index = np.unique(rec_of_line, return_inverse=True)
    if rec_numbers.size != n_rec:
        raise RinexFormatError(f"{name}: inconsistent record structure")
    values = np.full((n_rec, _N_FIELDS), np.nan)
    values[rec_index[li], field_no[li, mi]] = values_flat

    keep = np.ones(n_rec, dtype=bool)
    if systems is not None:
        keep = np.isin(sys_chars, np.frombuffer("".join(sorted(systems)).encode(), dtype=np.uint8))
    return _Records(sv_code[keep], toc[keep], values[keep]), attrs


def _stray_check(
    owner: NDArray[np.int64], head: NDArray[np.uint8], lineno: NDArray[np.int64], name: str
) -> None:
    """Refuse non-blank text between the header and the first record."""
    stray = (owner < 0) & np.any(head != _SPACE, axis=1)
    if np.any(stray):
        line = int(lineno[np.flatnonzero(stray)[0]])
        raise RinexFormatError(f"{name}: unexpected text on line {line} before the first record")


_Layout = tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]


def _layout_v3(head: NDArray[np.uint8], lineno: NDArray[np.int64], name: str) -> _Layout:
    """RINEX 3 records: a record starts on each line whose first column is not blank.

    Returns the body lines of the records, their ordinal within the record (0 = the
    satellite / toc line), their record number and the first line of each record.
    """
    is_start = head[:, 0] != _SPACE
    owner = np.cumsum(is_start) - 1
    _stray_check(owner, head, lineno, name)
    line_idx = np.flatnonzero(owner >= 0)
    record_first = np.flatnonzero(is_start)
    ordinal = line_idx - record_first[owner[line_idx]]
    return line_idx, ordinal, owner[line_idx], record_first


def _layout_v4(
    buf: NDArray[np.uint8],
    starts: NDArray[np.int64],
    lengths: NDArray[np.int64],
    head: NDArray[np.uint8],
    lineno: NDArray[np.int64],
    attrs: dict[str, Any],
    name: str,
) -> _Layout:
    """RINEX 4 records: ``> EPH G01 LNAV`` lines open records; keep the readable EPH types.

    ION records of known types are decoded into ``attrs`` on the way. Returns the same
    arrays as :func:`_layout_v3`.
    """
    is_marker = head[:, 0] == ord(">")
    markers = np.flatnonzero(is_marker)
    owner = np.cumsum(is_marker) - 1
    _stray_check(owner, head, lineno, name)
    kinds = [
        (head[m, 2:5].tobytes().decode("ascii", "replace"), chr(head[m, 6]),
         head[m, 10:14].tobytes().decode("ascii", "replace").strip())
        for m in markers
    ]  # fmt: skip
    eph_ok = np.array([t == "EPH" and msg in _RINEX4_EPH_TYPES.get(s, ()) for t, s, msg in kinds], dtype=bool)
    for m_i, (t, s, msg) in enumerate(kinds):
        key = _ION_ATTRS.get((s, msg))
        if t == "ION" and key is not None and key not in attrs:
            attrs[key] = _ion_record(buf, starts, lengths, markers, m_i, starts.size, key, name, lineno)
    if not eph_ok.any():
        found = sorted({f"{t} {msg}" for t, _, msg in kinds})
        raise RinexFormatError(
            f"{name}: no navigation records of a readable type (LNAV, INAV, FNAV, D1, D2, FDMA, SBAS); "
            f"found {found}"
        )
    in_record = (owner >= 0) & ~is_marker
    in_record &= eph_ok[np.maximum(owner, 0)]
    line_idx = np.flatnonzero(in_record)
    ordinal = line_idx - markers[owner[line_idx]] - 1
    return line_idx, ordinal, owner[line_idx], line_idx[ordinal == 0]


def _ion_record(
    buf: NDArray[np.uint8],
    starts: NDArray[np.int64],
    lengths: NDArray[np.int64],
    markers: NDArray[np.int64],
    m_i: int,
    n_lines: int,
    key: str,
    name: str,
    lineno: NDArray[np.int64],
) -> NDArray[np.float64]:
    """Decode one RINEX 4 ION record body into alpha/beta (or a_i0..a_i2) coefficients."""
    first = int(markers[m_i]) + 1
    last = int(markers[m_i + 1]) if m_i + 1 < markers.size else n_lines
    fields: list[str] = []
    for j, li in enumerate(range(first, last)):
        text = buf[starts[li] : starts[li] + lengths[li]].tobytes().decode("ascii", "replace")
        cols = (23, 42, 61) if j == 0 else (4, 23, 42, 61)
        fields += [text[c : c + _FIELD_WIDTH] for c in cols]
    count = _ION_COUNTS.get(key, 8)
    try:
        vals = np.array([float(f.upper().replace("D", "E")) for f in fields[:count]], dtype=np.float64)
    except ValueError:
        raise RinexFormatError(f"{name}: bad ION record on line {int(lineno[first])}") from None
    if vals.size != count:
        raise RinexFormatError(f"{name}: short ION record on line {int(lineno[first])}")
    return vals


def _validate_paths(
    path_or_paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
) -> list[str | os.PathLike[str]]:
    if isinstance(path_or_paths, (str, os.PathLike)):
        return [path_or_paths]
    paths = list(path_or_paths)
    if not paths:
        raise UsageError("path_or_paths: expected at least one navigation file, got an empty list")
    bad = [p for p in paths if not isinstance(p, (str, os.PathLike))]
    if bad:
        raise UsageError(f"path_or_paths: expected file paths, got {bad!r}")
    return paths


def read_nav3(
    path_or_paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    systems: Sequence[str] | None = None,
) -> xarray.Dataset:
    """Read one or several RINEX 3.0x / 4.0x navigation files into a ``(time, sv)`` dataset.

    Parameters
    ----------
    path_or_paths : str, os.PathLike or sequence of them
        Navigation files (mixed or single system; plain or compressed). Several files are
        merged: union of satellites and records, a record repeated identically in several
        files (same satellite, toc and values) kept once.
    systems : sequence of str, optional
        System letters to keep (``"G"``, ``"R"``, ``"E"``, ``"C"``, ``"J"``, ``"S"``,
        ``"I"``); default all.

    Returns
    -------
    xarray.Dataset
        Dims ``(time, sv)``: ``time`` datetime64[ns], the toc of the records as written,
        i.e. in each system's own time scale (GPS/QZSS/Galileo: GPS-aligned system time,
        SBAS: GPS time, BeiDou: BDT, GLONASS: UTC), not converted, as in georinex;
        sorted; ``sv`` ``'<U…'`` ids sorted as strings. Variables: the union of
        :data:`FIELD_NAMES` of the systems present, float64, NaN where a satellite has no record at that toc or a field is blank.
        A satellite with two different records at the same toc (e.g. Galileo I/NAV and
        F/NAV) gets the second one under ``'E01_1'`` (a third under ``'E01_2'``), in file
        order, as georinex does. Attributes: ``version`` (of the first file),
        ``rinextype`` = ``'nav'``, ``svtype`` (systems in order of appearance),
        ``filename`` (names joined with ``', '``), and when present
        ``ionospheric_corr_GPS`` (alpha0..3, beta0..3; s, s/semicircle, ...),
        ``ionospheric_corr_GAL`` (a_i0..a_i2), ``ionospheric_corr_BDS``,
        ``ionospheric_corr_QZS``, ``ionospheric_corr_IRN``; the first file that has one
        provides it.

    Raises
    ------
    InputFileNotFoundError
        A path does not exist.
    RinexFormatError
        Not a RINEX 3/4 navigation file, no records, a bad record start line or an
        undecodable number; the message names the file and the line.
    UsageError
        ``path_or_paths`` or ``systems`` malformed.

    Notes
    -----
    RINEX 4: EPH records LNAV (GPS, QZSS, NavIC), INAV/FNAV (Galileo), D1/D2 (BeiDou),
    FDMA (GLONASS) and SBAS are read; CNAV, CNV1, CNV2, CNV3 and other EPH types are
    skipped, as are STO and EOP records. ION records LNAV / IFNV / D1D2 give the
    ``ionospheric_corr_*`` attributes.

    Differences from georinex 1.16 (which reads only RINEX 3): a blank field is NaN on
    its own, where georinex turns the whole record into NaN (it does so for every
    Galileo and BeiDou record of files whose spare fields are blank); identical
    duplicate records are kept once, where georinex adds an ``_1`` copy.

    Examples
    --------
    >>> nav = read_nav3(["BRDC00IGS_R_20201770000_01D_GN.rnx.gz",
    ...                  "BRDC00IGS_R_20201770000_01D_EN.rnx.gz"])  # doctest: +SKIP
    >>> nav["sqrtA"].sel(sv="G05").dropna("time").values[0]  # doctest: +SKIP
    5153.692346573
    """
    paths = _validate_paths(path_or_paths)
    if systems is not None:
        if isinstance(systems, str):
            systems = [s.strip() for s in systems.replace(",", " ").split()]
        systems = list(systems)
        if not systems or any(not isinstance(s, str) or s not in SYSTEM_CHARS or len(s) != 1
                              for s in systems):  # fmt: skip
            raise UsageError(
                f"systems: expected RINEX system letters from {SYSTEM_CHARS!r}, got {systems!r}"
            )
    wanted = set(systems) if systems is not None else None

    parts = [_read_one(p, wanted) for p in paths]
    sv_code = np.concatenate([r.sv_code for r, _ in parts])
    toc = np.concatenate([r.toc for r, _ in parts])
    values = np.concatenate([r.values for r, _ in parts], axis=0)
    if sv_code.size == 0:
        names = ", ".join(Path(p).name for p in paths)
        which = f" of the systems {''.join(systems)}" if systems else ""
        raise RinexFormatError(f"{names}: no navigation records{which}")

    # drop exact duplicates (same sv, toc and every value, NaN-aware), keep the first
    key = np.concatenate(
        [
            sv_code[:, None].view(np.float64),
            toc.astype(np.int64)[:, None].view(np.float64),
            np.nan_to_num(values, nan=np.inf),
        ],
        axis=1,
    )  # one row of raw bytes per record
    row_bytes = np.ascontiguousarray(key).view(np.dtype((np.void, key.dtype.itemsize * key.shape[1])))
    _, first_idx = np.unique(row_bytes.ravel(), return_index=True)
    first_idx = np.sort(first_idx)
    sv_code, toc, values = sv_code[first_idx], toc[first_idx], values[first_idx]

    # occurrence number of each (sv, toc) in file order -> '_1', '_2' suffixes
    pair = np.stack([sv_code, toc.astype(np.int64)], axis=1)
    order = np.lexsort((np.arange(pair.shape[0]), pair[:, 1], pair[:, 0]))
    sp = pair[order]
    new_group = np.ones(order.size, dtype=bool)
    new_group[1:] = np.any(sp[1:] != sp[:-1], axis=1)
    group_start = np.maximum.accumulate(np.where(new_group, np.arange(order.size), 0))
    occurrence = np.empty(order.size, dtype=np.int64)
    occurrence[order] = np.arange(order.size) - group_start

    base = sv_codes2str(sv_code)
    labels = np.where(occurrence == 0, base, np.char.add(np.char.add(base, "_"), occurrence.astype(str)))
    sv_values, sv_of_rec = np.unique(labels, return_inverse=True)
    time_values, time_of_rec = np.unique(toc, return_inverse=True)
    n_t, n_sv = time_values.size, sv_values.size
    flat = time_of_rec * n_sv + sv_of_rec

    sys_of_rec = (sv_code >> 16).astype(np.uint8)
    svtype: list[str] = []
    for c in sys_of_rec[np.sort(np.unique(sys_of_rec, return_index=True)[1])]:
        svtype.append(chr(c))
    data: dict[str, NDArray[np.float64]] = {}
    for s in svtype:
        rows = np.flatnonzero(sys_of_rec == ord(s))
        for j, field in enumerate(FIELD_NAMES[s]):
            col = values[rows, j]
            if s in {"R", "S"} and field in _KM_FIELDS:
                col = col * 1000.0  # km -> m
            if field not in data:
                data[field] = np.full(n_t * n_sv, np.nan)
            data[field][flat[rows]] = col

    ds = xarray.Dataset(
        {k: (("time", "sv"), v.reshape(n_t, n_sv)) for k, v in data.items()},
        coords={"time": time_values, "sv": sv_values},
    )
    attrs: dict[str, Any] = {}
    for _, a in reversed(parts):
        attrs.update(a)
    attrs["version"] = parts[0][1]["version"]
    attrs["rinextype"] = "nav"
    attrs["svtype"] = svtype
    attrs["filename"] = ", ".join(a["filename"] for _, a in parts)
    ds.attrs.update(attrs)
    return ds
