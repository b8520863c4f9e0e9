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
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import xarray
from numpy.typing import NDArray

from gnss_cli.errors import RinexFormatError, UsageError
from gnss_cli.io.fixed_width import (
    SPACE,
    civil2datetime64,
    civil_ranges_ok,
    gather_columns,
    parse_float_fields,
    parse_uint_fields,
    split_lines,
    sv_codes2str,
)
from gnss_cli.io.nav_layout import Layout, layout_v3, layout_v4
from gnss_cli.io.rinex3_header import SYSTEM_CHARS, read_header, read_nav_header, validate_systems

__all__ = ["read_nav3", "record_tocs", "FIELD_NAMES", "drop_identical_records", "records2dataset", "systems_in_order"]

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

_RECORD_START_SPANS = ((1, 3), (4, 8), (9, 11), (12, 14), (15, 17), (18, 20), (21, 23))
"""Columns of the PRN, year, month, day, hour, minute and second on a record's first line."""

_KM_FIELDS = {"X", "dX", "dX2", "Y", "dY", "dY2", "Z", "dZ", "dZ2"}

_FIELD_WIDTH = 19
_N_FIELDS = 31


class _Records:
    """Decoded records of one file: satellite codes, toc, values ``(n, 31)``, in file order."""

    __slots__ = ("sv_code", "toc", "values")

    def __init__(self, sv_code: NDArray[np.int64], toc: NDArray[np.datetime64], values: NDArray[np.float64]):
        self.sv_code = sv_code
        self.toc = toc
        self.values = values


def _parse_d19(chars: NDArray[np.uint8], lineno: NDArray[np.int64], name: str) -> NDArray[np.float64]:
    """Decode ``D19.12`` fields ``(n, 19)``; blank fields give NaN."""
    blank = np.all(chars == SPACE, axis=1)
    out = np.full(chars.shape[0], np.nan)
    filled = np.flatnonzero(~blank)
    if filled.size == 0:
        return out
    sub = chars[filled]
    sub = np.where((sub == ord("D")) | (sub == ord("d")), np.uint8(ord("E")), sub)
    out[filled] = parse_float_fields(sub, lineno[filled], name, "number", strip=True)
    return out


def _read_one(path: str | os.PathLike[str], systems: set[str] | None) -> tuple[_Records, dict[str, Any]]:
    """Decode the records of one navigation file (of the ``systems`` when given) and its header."""
    name, content, hdr_end, header = read_header(path)
    attrs = read_nav_header(header, name)
    attrs["filename"] = name
    n_header_lines = header.count("\n")

    buf, starts, lengths = split_lines(content[hdr_end:])
    lineno = np.arange(starts.size, dtype=np.int64) + n_header_lines + 1
    head = gather_columns(buf, starts, lengths, 0, 14)
    if attrs["version"] >= 4.0:
        layout = layout_v4(buf, starts, lengths, head, lineno, attrs, name)
    else:
        layout = layout_v3(head, lineno, name)
    first_lines = layout[3]
    if first_lines.size == 0:
        raise RinexFormatError(f"{name}: no navigation records")
    fl = gather_columns(buf, starts[first_lines], lengths[first_lines], 0, 23)
    sys_chars = fl[:, 0]
    sv_code, toc = _record_starts(fl, lineno[first_lines], name)
    if attrs["version"] < 4.0:
        _check_record_lengths(head, lineno, layout, sys_chars, name)
    _check_last_line(buf, starts, lengths, lineno, layout, name)
    values = _record_values(buf, starts, lengths, lineno, layout, name)
    keep = np.ones(first_lines.size, dtype=bool)
    if systems is not None:
        keep = np.isin(sys_chars, np.frombuffer("".join(sorted(systems)).encode(), dtype=np.uint8))
    return _Records(sv_code[keep], toc[keep], values[keep]), attrs


_LINES_PER_RECORD_V3 = {ord("R"): (4, 5), ord("S"): (4,)}
"""Lines of a RINEX 3 record: 8 for the Kepler systems, 4 for GLONASS (5 from RINEX 3.05) and SBAS."""


def _check_record_lengths(head: NDArray[np.uint8], lineno: NDArray[np.int64], layout: Layout,
                          sys_chars: NDArray[np.uint8], name: str) -> None:
    """Refuse a record with too few or too many lines: a file cut inside its last record, or
    lines lost or doubled inside one (blank lines after the last record are allowed)."""
    line_idx, _, rec_of_line, first_lines = layout
    filled = np.any(head[line_idx] != SPACE, axis=1)
    n_lines = np.bincount(rec_of_line[filled], minlength=first_lines.size)
    for code in np.unique(sys_chars):
        rows = np.flatnonzero(sys_chars == code)
        allowed = np.asarray(_LINES_PER_RECORD_V3.get(int(code), (8,)))
        bad = rows[~np.isin(n_lines[rows], allowed)]
        if bad.size:
            i = int(bad[0])
            end = "the file ends inside it" if i == first_lines.size - 1 and n_lines[i] < allowed.min() else "a line is missing or extra"
            raise RinexFormatError(
                f"{name}:{int(lineno[first_lines[i]])}: record of {chr(int(code))} has {int(n_lines[i])} lines "
                f"(expected {' or '.join(str(a) for a in allowed)}): {end}"
            )


def _check_last_line(buf: NDArray[np.uint8], starts: NDArray[np.int64], lengths: NDArray[np.int64],
                     lineno: NDArray[np.int64], layout: Layout, name: str) -> None:
    """Refuse a file cut inside the last value: every field of the last record's last line
    ends with its exponent (``D+03``); a cut one would be read as another number."""
    line_idx, ordinal, _, _ = layout
    filled = [int(i) for i in line_idx[::-1][:8] if lengths[i] > 0 and np.any(buf[starts[i]:starts[i] + lengths[i]] != SPACE)]
    if not filled:
        return
    i = filled[0]
    text = buf[starts[i]:starts[i] + lengths[i]].tobytes().decode("ascii", "replace")
    first = 23 if ordinal[np.searchsorted(line_idx, i)] == 0 else 4
    for k in range(first, len(text), _FIELD_WIDTH):
        field = text[k:k + _FIELD_WIDTH].strip()
        if field and not _EXPONENT.search(field):
            raise RinexFormatError(f"{name}:{int(lineno[i])}: the file ends inside a value ({field!r} has no exponent)")


_EXPONENT = re.compile(r"[DEde][+-]?\d{1,3}$")


def _record_starts(
    fl: NDArray[np.uint8], lineno: NDArray[np.int64], name: str
) -> tuple[NDArray[np.int64], NDArray[np.datetime64]]:
    """Satellite codes and toc from the records' first lines ``'G01 2020 06 24 23 15 00'``."""
    sys_chars = fl[:, 0]
    known = np.isin(sys_chars, np.frombuffer(SYSTEM_CHARS.encode(), dtype=np.uint8))
    (prn, year, month, day, hour, minute, sec), ok_fields = parse_uint_fields(fl, _RECORD_START_SPANS)
    ok = known & ok_fields & civil_ranges_ok(month, day, hour, minute, sec)
    if not np.all(ok):
        i = int(np.flatnonzero(~ok)[0])
        text = fl[i].tobytes().decode("ascii", "replace").rstrip()
        raise RinexFormatError(
            f"{name}: bad record start (satellite / epoch) on line {int(lineno[i])}: {text!r}"
        )
    toc = civil2datetime64(year, month, day, ((hour * 60 + minute) * 60 + sec) * 1_000_000_000)
    c1 = (prn // 10) + 48
    c2 = (prn % 10) + 48
    return (sys_chars.astype(np.int64) << 16) | (c1 << 8) | c2, toc


def _record_values(
    buf: NDArray[np.uint8], starts: NDArray[np.int64], lengths: NDArray[np.int64], lineno: NDArray[np.int64],
    layout: Layout, name: str,
) -> NDArray[np.float64]:
    """The ``D19.12`` fields of every record, ``(n_records, 31)`` in file order, NaN where blank."""
    line_idx, ordinal, rec_of_line, first_lines = layout
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
    return values


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


def record_tocs(path: str | os.PathLike[str]) -> NDArray[np.datetime64]:
    """The toc of every record of one RINEX 3/4 navigation file, as :func:`read_nav3` reads them
    (same checks and errors), without building the dataset: what a catalogue of files needs."""
    return _read_one(_validate_paths(path)[0], None)[0].toc


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
    The simulated sample of the repository (run from its root):

    >>> nav = read_nav3(["sample_rinex/static/nav.rnx"])
    >>> float(nav["sqrtA"].sel(sv="G05").dropna("time").values[0])
    5153.472140846
    """
    paths = _validate_paths(path_or_paths)
    systems = validate_systems(systems)
    wanted = set(systems) if systems is not None else None
    parts = [_read_one(p, wanted) for p in paths]
    sv_code = np.concatenate([r.sv_code for r, _ in parts])
    toc = np.concatenate([r.toc for r, _ in parts])
    values = np.concatenate([r.values for r, _ in parts], axis=0)
    if sv_code.size == 0:
        names = ", ".join(Path(p).name for p in paths)
        which = f" of the systems {''.join(systems)}" if systems else ""
        raise RinexFormatError(f"{names}: no navigation records{which}")
    sv_code, toc, values = drop_identical_records(sv_code, toc, values)
    svtype = systems_in_order(sv_code)
    ds = records2dataset(sv_code, toc, values, svtype)
    ds.attrs.update(_merged_attrs([a for _, a in parts], svtype))
    return ds


def drop_identical_records(
    sv_code: NDArray[np.int64], toc: NDArray[np.datetime64], values: NDArray[np.float64]
) -> tuple[NDArray[np.int64], NDArray[np.datetime64], NDArray[np.float64]]:
    """Drop exact duplicate records (same sv, toc and every value, NaN-aware), keeping the first."""
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
    return sv_code[first_idx], toc[first_idx], values[first_idx]


def _sv_labels(sv_code: NDArray[np.int64], toc: NDArray[np.datetime64]) -> NDArray[np.str_]:
    """Satellite ids, with ``'_1'``, ``'_2'`` for the 2nd, 3rd record of a (sv, toc) in file order."""
    pair = np.stack([sv_code, toc.astype(np.int64)], axis=1)
    order = np.lexsort((np.arange(pair.shape[0]), pair[:, 1], pair[:, 0]))
    sp = pair[order]
    new_group = np.ones(order.size, dtype=bool)
    new_group[1:] = np.any(sp[1:] != sp[:-1], axis=1)
    group_start = np.maximum.accumulate(np.where(new_group, np.arange(order.size), 0))
    occurrence = np.empty(order.size, dtype=np.int64)
    occurrence[order] = np.arange(order.size) - group_start
    base = sv_codes2str(sv_code)
    return np.where(occurrence == 0, base, np.char.add(np.char.add(base, "_"), occurrence.astype(str)))


def systems_in_order(sv_code: NDArray[np.int64]) -> list[str]:
    """System letters of the records in order of first appearance."""
    sys_of_rec = (sv_code >> 16).astype(np.uint8)
    svtype: list[str] = []
    for c in sys_of_rec[np.sort(np.unique(sys_of_rec, return_index=True)[1])]:
        svtype.append(chr(c))
    return svtype


def records2dataset(
    sv_code: NDArray[np.int64], toc: NDArray[np.datetime64], values: NDArray[np.float64], svtype: list[str]
) -> xarray.Dataset:
    """The ``(time, sv)`` dataset of navigation records (GLONASS/SBAS km converted to m).

    Parameters
    ----------
    sv_code : numpy.ndarray of int64, shape (n,)
        Satellite codes ``(system << 16) | (tens << 8) | units`` of the records.
    toc : numpy.ndarray of datetime64[ns], shape (n,)
        Time of clock of each record.
    values : numpy.ndarray of float64, shape (n, k)
        The fields of each record in the order of :data:`FIELD_NAMES` (``k`` at least the
        longest list of the systems present); NaN where blank.
    svtype : list of str
        The systems present (:func:`systems_in_order`).

    Returns
    -------
    xarray.Dataset
        One variable per name of :data:`FIELD_NAMES` of the systems present; a second
        record of a satellite at the same toc under ``'G01_1'``.
    """
    sv_values, sv_of_rec = np.unique(_sv_labels(sv_code, toc), return_inverse=True)
    time_values, time_of_rec = np.unique(toc, return_inverse=True)
    n_t, n_sv = time_values.size, sv_values.size
    flat = time_of_rec * n_sv + sv_of_rec

    sys_of_rec = (sv_code >> 16).astype(np.uint8)
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
    return ds


def _merged_attrs(file_attrs: list[dict[str, Any]], svtype: list[str]) -> dict[str, Any]:
    """Header attributes of several files: the first file that has one gives each; names joined."""
    attrs: dict[str, Any] = {}
    for a in reversed(file_attrs):  # the first file wins, but all-zero ionosphere coefficients never mask real ones
        attrs.update({k: v for k, v in a.items() if not (k.startswith("ionospheric_corr_") and not np.any(np.asarray(v)))})
    attrs["version"] = file_attrs[0]["version"]
    attrs["rinextype"] = "nav"
    attrs["svtype"] = svtype
    attrs["filename"] = ", ".join(a["filename"] for a in file_attrs)
    return attrs
