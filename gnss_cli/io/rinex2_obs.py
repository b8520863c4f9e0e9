"""Reader for RINEX 2.10 / 2.11 observation files with exact time tags.

The epoch records are walked once, one Python step per epoch (an epoch's length depends
on its satellite count, so the walk is sequential); the observation values are then cut
out of all records at once with the fixed-width primitives of
:mod:`gnss_cli.io.fixed_width`, as in the RINEX 3/4 reader. The result has the layout of
``georinex.load(path, use=systems, meas=codes)``, which the tests use as the reference.

The epoch seconds (``F11.7``) are read as decimal text into integer nanoseconds, so
``29.9990000`` is 29.999 s exactly (georinex keeps only whole milliseconds, truncated
from a binary float, and reads it as 29.998 s).

Epoch flags (RINEX 2.11, table A2): 0 and 1 carry observations; 2-5 are events followed
by as many special records (header lines) as the satellite field announces, skipped; 6
holds cycle-slip records in the observation format, skipped.

References
----------
RINEX 2.11 format description (IGS/RTCM-SC104, 2012), section 7 and tables A1-A2.
"""

from __future__ import annotations

import functools
import os
import re
from collections.abc import Sequence
from typing import Any

import numpy as np
import xarray
from numpy.typing import NDArray

from gnss_cli.errors import RinexFormatError
from gnss_cli.io.fixed_width import (DIGIT0, SPACE, gather_columns, lli_name, parse_f14_3, parse_float_fields, parse_lli,
                                      split_lines, sv_codes2str, wants_lli)
from gnss_cli.io.obs_checks import check_epochs_increasing, check_last_value_complete
from gnss_cli.io.rinex3_header import read_header

__all__ = ["read_obs2", "parse_obs2", "parse_seconds_ns", "record_line_count", "obs_type_count"]

OBS_CODE2 = re.compile(r"[CPLDS][1-9][A-Z]?")
"""A RINEX 2 observation code (RINEX 2.11 section 5.1: type C, P, L, D or S and the band digit;
the third letter of 2.12-style codes such as ``C1C`` is accepted)."""

_FIELD_WIDTH = 16
_VALUE_WIDTH = 14
_PER_LINE = 5
"""Observation fields per record line."""
_SATS_PER_LINE = 12


def parse_seconds_ns(text: str) -> int:
    """Decimal seconds text (``' 29.9990000'``) as integer nanoseconds.

    Digits beyond the ninth decimal are dropped (RINEX 2 writes seven).

    Raises
    ------
    ValueError
        ``text`` is not an unsigned decimal number.

    >>> parse_seconds_ns(" 29.9990000")  # a binary float would give 29.998999...
    29999000000
    """
    whole, _, frac = text.strip().partition(".")
    if not (whole or frac) or not (whole or "0").isdigit() or (frac and not frac.isdigit()):
        raise ValueError(f"seconds: expected a decimal number such as '29.9990000', got {text!r}")
    return int(whole or "0") * 1_000_000_000 + int((frac + "000000000")[:9])


def _obs_header(header: str, name: str) -> tuple[dict[str, Any], list[str], str]:
    """Header attributes, the observation types and the file's system letter."""
    lines = header.splitlines()
    first = lines[0] if lines else ""
    try:
        version = float(first[:9])
    except ValueError:
        raise RinexFormatError(f"{name}: line 1: bad RINEX version {first[:9].strip()!r}") from None
    system = first[40:41].strip().upper() or "G"
    attrs: dict[str, Any] = {"version": version, "rinextype": "obs", "time_system": "GPS" if system in "GM" else system}
    n_types, types, count_line = None, [], 0
    for lineno, line in enumerate(lines, 1):
        label = line[60:80].strip()
        if label == "# / TYPES OF OBSERV":
            if line[:6].strip():
                if not line[:6].strip().isdigit():
                    raise RinexFormatError(f"{name}: line {lineno}: bad '# / TYPES OF OBSERV' count {line[:6]!r}")
                n_types, count_line = int(line[:6]), lineno
            codes = line[6:60].split()
            bad = [c for c in codes if not OBS_CODE2.fullmatch(c)]
            if bad:
                raise RinexFormatError(
                    f"{name}: line {lineno}: {bad[0]!r} is not a RINEX 2 observation code "
                    f"(a type C, P, L, D or S and a band digit, such as C1)"
                )
            types += codes
        elif label == "APPROX POSITION XYZ":
            try:
                attrs["position"] = [float(line[i:i + 14]) for i in (0, 14, 28)]
            except ValueError:
                raise RinexFormatError(f"{name}: line {lineno}: bad APPROX POSITION XYZ") from None
        elif label == "MARKER NAME":
            attrs["marker_name"] = line[:60].strip()
        elif label == "REC # / TYPE / VERS":
            attrs["rxmodel"] = line[20:40].strip()
        elif label == "INTERVAL":
            try:
                attrs["interval"] = float(line[:10])
            except ValueError:
                pass
        elif label == "TIME OF FIRST OBS" and line[48:51].strip():
            attrs["time_system"] = line[48:51].strip()
    if n_types is None:
        raise RinexFormatError(f"{name}: header has no '# / TYPES OF OBSERV' line (lines 1-{len(lines)})")
    if n_types != len(types):
        raise RinexFormatError(
            f"{name}: line {count_line}: header declares {n_types} observation types but lists {len(types)} "
            f"({' '.join(types)})"
        )
    attrs.setdefault("marker_name", "")
    attrs.setdefault("rxmodel", "")
    return attrs, types, system


def _sv_codes(ids: bytes, file_system: str) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Satellite ids ``'G 7'``, ``' 12'`` (3 characters each) as codes ``(system << 16) | (tens << 8) | units``.

    A blank system letter is GPS (the file's system in single-system files).
    """
    chars = np.frombuffer(ids, dtype=np.uint8).reshape(-1, 3)
    blank_sys = ord("G") if file_system == "M" else ord(file_system)
    c0 = np.where(chars[:, 0] == SPACE, blank_sys, chars[:, 0]).astype(np.int64)
    c1 = np.where(chars[:, 1] == SPACE, DIGIT0, chars[:, 1]).astype(np.int64)
    c2 = chars[:, 2].astype(np.int64)
    known = np.isin(c0, np.frombuffer(b"GRESJCI", dtype=np.uint8))
    ok = known & (c1 >= DIGIT0) & (c1 <= DIGIT0 + 9) & (c2 >= DIGIT0) & (c2 <= DIGIT0 + 9)
    return (c0 << 16) | (c1 << 8) | c2, ok


class _Walk:
    """The epochs with observations found by :func:`_walk`."""

    def __init__(self) -> None:
        self.epoch_line: list[int] = []
        self.first_line: list[int] = []
        self.nsat: list[int] = []
        self.ids: list[str] = []
        self.times_ns: list[int] = []


@functools.lru_cache(maxsize=4096)
def _days_since_1970(year: int, month: int, day: int) -> int | None:
    try:
        return int(np.datetime64(f"{year:04d}-{month:02d}-{day:02d}", "D").astype(np.int64))
    except ValueError:
        return None


def _epoch_time_ns(line: str) -> int | None:
    """Nanoseconds since 1970 of an epoch line's time tag, None if it does not parse or is out of range."""
    fields = [line[1:3], line[4:6], line[7:9], line[10:12], line[13:15]]
    if not all(f.strip().isdigit() for f in fields):
        return None
    yy, mo, dd, hh, mi = (int(f) for f in fields)
    try:
        ns = parse_seconds_ns(line[15:26])
    except ValueError:
        return None
    if not (1 <= mo <= 12 and 1 <= dd <= 31 and hh < 24 and mi < 60 and ns <= 60_999_999_999):
        return None
    day = _days_since_1970(yy + (2000 if yy < 80 else 1900), mo, dd)
    if day is None:
        return None
    return ((day * 24 + hh) * 60 + mi) * 60 * 1_000_000_000 + ns


def obs_type_count(header: str, name: str) -> int:
    """Number of observation types of the header's ``# / TYPES OF OBSERV`` lines."""
    return len(_obs_header(header, name)[1])


def record_line_count(line: str, n_types: int) -> int | None:
    """Lines of the epoch record that starts with ``line`` (the epoch line, its satellite-id
    continuation lines and the observation lines; an event's special records), 1 for a blank
    line, None when ``line`` is not an epoch line (the readers then report it)."""
    if not line.strip():
        return 1
    flag_text, nsat_text = line[26:29].strip(), line[29:32].strip()
    if not flag_text.isdigit() or int(flag_text) > 6 or not (nsat_text.isdigit() or not nsat_text):
        return None
    flag, nsat = int(flag_text), int(nsat_text or 0)
    if 2 <= flag <= 5:
        return 1 + nsat
    lines_per_sat = (n_types + _PER_LINE - 1) // _PER_LINE
    return max(1, (nsat + _SATS_PER_LINE - 1) // _SATS_PER_LINE) + nsat * lines_per_sat


def _walk(text_lines: list[str], n_types: int, name: str, offset: int) -> _Walk:
    """Find the epoch records; ``offset`` is the file line number of ``text_lines[0]`` minus one."""
    lines_per_sat = (n_types + _PER_LINE - 1) // _PER_LINE
    out = _Walk()
    i, n = 0, len(text_lines)
    while i < n:
        line = text_lines[i]
        if not line.strip():
            i += 1
            continue
        lineno = offset + i + 1
        flag_text, nsat_text = line[26:29].strip(), line[29:32].strip()
        if not flag_text.isdigit() or int(flag_text) > 6 or not (nsat_text.isdigit() or not nsat_text):
            raise RinexFormatError(f"{name}: bad epoch line {lineno}: {line.rstrip()[:40]!r}")
        flag, nsat = int(flag_text), int(nsat_text or 0)
        if 2 <= flag <= 5:  # event: nsat special records (header lines) follow
            if i + 1 + nsat > n:
                raise RinexFormatError(f"{name}: line {lineno}: event record announces {nsat} lines, the file ends first")
            i += 1 + nsat
            continue
        t_ns = _epoch_time_ns(line)
        if t_ns is None:
            raise RinexFormatError(f"{name}: bad epoch line {lineno}: {line.rstrip()[:40]!r}")
        n_id_lines = max(1, (nsat + _SATS_PER_LINE - 1) // _SATS_PER_LINE)
        end = i + n_id_lines + nsat * lines_per_sat
        if end > n:
            raise RinexFormatError(
                f"{name}: line {lineno}: record cut short (announces {nsat} satellites of "
                f"{lines_per_sat} line(s) each, the file ends at line {offset + n})"
            )
        if flag <= 1 and nsat:  # flag 6 (cycle slips) has the same layout and is skipped
            out.epoch_line.append(i)
            out.first_line.append(i + n_id_lines)
            out.nsat.append(nsat)
            out.ids.append("".join(text_lines[i + k][32:68].ljust(36) for k in range(n_id_lines))[: 3 * nsat])
            out.times_ns.append(t_ns)
        i = end
    return out


def _records(walk: _Walk, n_types: int, file_system: str, name: str, offset: int
             ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Per satellite record: its first line, satellite code and epoch."""
    nsat = np.asarray(walk.nsat, dtype=np.int64)
    epoch = np.repeat(np.arange(nsat.size), nsat)
    k = np.arange(epoch.size) - np.repeat(np.cumsum(nsat) - nsat, nsat)  # position in the epoch's list
    lines_per_sat = (n_types + _PER_LINE - 1) // _PER_LINE
    first = np.repeat(np.asarray(walk.first_line, dtype=np.int64), nsat) + k * lines_per_sat
    sv, ok = _sv_codes("".join(walk.ids).encode("ascii", "replace"), file_system)
    if not np.all(ok):
        r = int(np.flatnonzero(~ok)[0])
        text = "".join(walk.ids)[3 * r:3 * r + 3]
        line = offset + walk.epoch_line[epoch[r]] + 1 + int(k[r]) // _SATS_PER_LINE
        raise RinexFormatError(f"{name}: bad satellite id {text!r} on line {line}")
    return first, sv, epoch


def _check_record_lines(buf: NDArray[np.uint8], starts: NDArray[np.int64], lengths: NDArray[np.int64],
                        first: NDArray[np.int64], n_types: int, name: str, offset: int) -> None:
    """A record line holding more fields than the header lists (wrong observation count) is an error."""
    for k in range((n_types + _PER_LINE - 1) // _PER_LINE):
        idx = first + k
        used = min(_PER_LINE, n_types - k * _PER_LINE) * _FIELD_WIDTH
        long_idx = idx[lengths[idx] > used]
        if long_idx.size == 0:
            continue
        tail = gather_columns(buf, starts[long_idx], lengths[long_idx], used, 80)
        bad = np.flatnonzero(np.any(tail != ord(" "), axis=1))
        if bad.size:
            raise RinexFormatError(
                f"{name}: line {offset + int(long_idx[bad[0]]) + 1}: more observations than the "
                f"{n_types} of the header's '# / TYPES OF OBSERV'"
            )


def _chosen(types: list[str], codes: Sequence[str] | None) -> list[tuple[int, str]]:
    """(field index, code) pairs to decode: every type, or those starting with one of ``codes``."""
    return [(k, c) for k, c in enumerate(types) if codes is None or any(c.startswith(p) for p in codes)]


def read_obs2(
    path: str | os.PathLike[str], systems: Sequence[str] | None = None, codes: Sequence[str] | None = None
) -> xarray.Dataset:
    """Read a RINEX 2.10 / 2.11 observation file into an ``(time, sv)`` dataset.

    Parameters
    ----------
    path : str or os.PathLike
        Observation file: plain or compressed (gz, Z, zip, bz2, Hatanaka).
    systems : sequence of str, optional
        System letters to keep; default all.
    codes : sequence of str, optional
        Observation codes to keep, as prefixes (``"C1"`` keeps ``C1``); default all.

    Returns
    -------
    xarray.Dataset
        Dims ``(time, sv)``: ``time`` datetime64[ns] exactly as written (file time
        scale), the epochs with at least one satellite of ``systems``; ``sv`` the
        satellites of ``systems`` that appear, sorted. One float64 variable per chosen
        code, NaN where blank. Attributes ``version``, ``rinextype``, ``time_system``,
        ``interval``, ``position`` (when in the header), ``marker_name``, ``rxmodel``,
        ``filename``.

    Raises
    ------
    InputFileNotFoundError
        ``path`` does not exist.
    RinexFormatError
        Bad header, bad epoch line, a record cut short by the end of the file, a record
        with more fields than the header's observation types, a bad satellite id or
        value, an epoch not later than the one before it (repeated, re-stamped, a body
        written twice), no records; the message names the file and the line.
    """
    name, content, hdr_end, header = read_header(path)
    return parse_obs2(name, header, content[hdr_end:], systems, codes)


def parse_obs2(name: str, header: str, body: bytes, systems: Sequence[str] | None = None,
               codes: Sequence[str] | None = None, lines_before: int | None = None) -> xarray.Dataset:
    """:func:`read_obs2` of a header text and a body of whole epoch records (the file, or a run
    of its epochs: :mod:`gnss_cli.io.obs_chunks`). ``lines_before``: file lines before
    ``body`` (default: the header's), so that error messages name the file's line numbers."""
    attrs, types, file_system = _obs_header(header, name)
    offset = header.count("\n") if lines_before is None else lines_before
    buf, starts, lengths = split_lines(body)
    text_lines = body.decode("ascii", errors="replace").replace("\r", "").split("\n")
    if text_lines and text_lines[-1] == "":
        text_lines.pop()
    walk = _walk(text_lines, len(types), name, offset)
    check_epochs_increasing(np.asarray(walk.times_ns, dtype=np.int64), offset + np.asarray(walk.epoch_line) + 1, name)
    if not body.endswith(b"\n") and walk.first_line and len(text_lines) > walk.first_line[-1] and text_lines[-1].strip():
        check_last_value_complete(len(text_lines[-1]), 0, offset + len(text_lines), name)
    first, sv, epoch = _records(walk, len(types), file_system, name, offset)
    if first.size:
        _check_record_lines(buf, starts, lengths, first, len(types), name, offset)
    if systems is not None:
        keep = np.isin(sv >> 16, [ord(s) for s in systems])
        first, sv, epoch = first[keep], sv[keep], epoch[keep]
    if first.size == 0:
        raise RinexFormatError(f"{name}: no observation records" + (f" of the systems {''.join(systems)}" if systems else ""))
    times = np.asarray(walk.times_ns, dtype=np.int64)[epoch]
    time_values, time_of_rec = np.unique(times, return_inverse=True)
    sv_values, sv_of_rec = np.unique(sv, return_inverse=True)
    flat = time_of_rec * sv_values.size + sv_of_rec
    size = time_values.size * sv_values.size
    data_vars = {}
    for k, code in _chosen(types, codes):
        idx = first + k // _PER_LINE
        chars = gather_columns(buf, starts[idx], lengths[idx], (k % _PER_LINE) * _FIELD_WIDTH, _VALUE_WIDTH)
        values, odd = parse_f14_3(chars)
        if np.any(odd):
            values[odd] = parse_float_fields(chars[odd], offset + idx[odd] + 1, name, f"{code} value")
        grid = np.full(size, np.nan)
        grid[flat] = values
        data_vars[code] = (("time", "sv"), grid.reshape(time_values.size, sv_values.size))
        if wants_lli(code, codes):  # carrier phase: its loss-of-lock indicator, NaN where no phase
            lli = gather_columns(buf, starts[idx], lengths[idx], (k % _PER_LINE) * _FIELD_WIDTH + _VALUE_WIDTH, 1)
            grid = np.full(size, np.nan)
            grid[flat] = np.where(np.isfinite(values), parse_lli(lli), np.nan)
            data_vars[lli_name(code)] = (("time", "sv"), grid.reshape(time_values.size, sv_values.size))
    ds = xarray.Dataset(data_vars, coords={"time": time_values.astype("datetime64[ns]"), "sv": sv_codes2str(sv_values)})
    if "interval" not in attrs and time_values.size > 1:
        attrs["interval"] = float(np.median(np.diff(time_values)) / 1e9)
    attrs["filename"] = name
    ds.attrs.update(attrs)
    return ds
